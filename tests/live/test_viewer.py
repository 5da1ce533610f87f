"""The live view in Rerun: ``optitact.live.viewer`` logs what a stream yields, read back from ``.rrd`` files."""

from __future__ import annotations

import socket
import sys
import urllib.request
from collections import defaultdict

import numpy as np
import pytest

import optitact._optional
from optitact.calib.document import CalibrationMismatchError
from optitact.calib.shipped import default_calibration
from optitact.errors import InputError, MissingExtraError, ShapeError
from optitact.live.stream import stream
from optitact.live.viewer import VIEW_TARGETS, LiveView, default_elements, open_view
from optitact.optics.camera import FisheyeCamera
from optitact.optics.force_frames import frame_totals
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.uncertainty import Z90

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

#: Elements pressed in the test frames -> spot centre (mm, element-local x, y).
SPOTS = {0: (0.3, -0.2), 12: (-0.3, 0.2)}
SCALE = 10.0  # the default mm/N


class Frames:
    """A capture object (read() and release()) over a list of frames."""

    def __init__(self, frames):
        self.frames = list(frames)

    def read(self):
        return (True, self.frames.pop(0)) if self.frames else (False, None)

    def release(self):
        pass


@pytest.fixture(scope="module")
def cal():
    return default_calibration()


@pytest.fixture(scope="module")
def frames(cal):
    """A no-load frame, then four frames of growing spots on elements 0 and 12 (640x480, uint8)."""
    s, cam = cal.sensor, cal.camera
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    pts = cam.unproject(np.stack([rows, cols], -1).astype(float), s, outside="nan")
    spots = sum(np.nan_to_num(np.exp(-0.5 * ((s.tangent_offset(np.full(cam.shape, e), pts) - c) ** 2).sum(-1)
                                     / 0.35**2)) for e, c in SPOTS.items())
    out = [np.full(cam.shape, 4, np.uint8)]
    out += [np.clip(np.rint(4 + amp * spots), 0, 255).astype(np.uint8) for amp in (60, 110, 160, 210)]
    return out


@pytest.fixture(scope="module")
def live(cal, frames):
    """The stream's LiveFrames with forces (the first frame is the no-load baseline)."""
    lfs = list(stream(Frames(frames), calibration=cal))
    assert [lf.index for lf in lfs] == [0, 1, 2, 3, 4]
    assert all(lf.forces.local[list(SPOTS), 2].min() > 0 for lf in lfs[1:])  # forces that show
    return lfs


@pytest.fixture(scope="module")
def bare(frames):
    """The same frames' LiveFrames without a calibration (readings only)."""
    return list(stream(Frames(frames), pipeline=default_calibration().pipeline()))


def read_rrd(path):
    """``{entity: {"static": [record batches], "frames": {frame index: {column: value}}}}`` of a file."""
    out = defaultdict(lambda: {"static": [], "frames": {}})
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        entry = out[chunk.entity_path.lstrip("/")]
        if chunk.is_static:
            entry["static"].append(rb)
            continue
        cols = {name: rb.column(name).to_pylist() for name in rb.schema.names if ":" in name
                or name in ("frame", "capture_time", "wall_time")}
        for row, index in enumerate(cols["frame"]):
            assert index not in entry["frames"], f"{chunk.entity_path}: frame {index} logged twice"
            entry["frames"][index] = {k: v[row] for k, v in cols.items()}
    return out


def arr(value):
    return np.array(value, dtype=float)


def test_every_frame_is_in_the_file_as_logged(tmp_path, cal, live):
    """Image bit for bit, one force arrow per element, 2-D arrows, time series and static geometry."""
    path = tmp_path / "live.rrd"
    latency = [0.002 + 0.001 * k for k in range(len(live))]
    with open_view(path, calibration=cal) as view:
        assert view.target == str(path) and view.url is None and view.elements == (0, 1, 9, 25)
        for lf, lat in zip(live, latency, strict=True):
            view.log(lf, latency_s=lat)
    assert view.frames == len(live)
    data = read_rrd(path)
    s, cam = cal.sensor, cal.camera
    centres = cam.project(s.element_positions, s)[:, ::-1]
    for k, lf in enumerate(live):
        f = lf.forces
        image = data["camera/image"]["frames"][lf.index]
        fmt = image["Image:format"][0]
        assert (fmt["width"], fmt["height"]) == (640, 480)
        assert np.array_equal(np.frombuffer(bytes(image["Image:buffer"][0]), np.uint8).reshape(480, 640),
                              lf.frame)
        assert image["capture_time"].total_seconds() == pytest.approx(lf.timestamp, abs=1e-6)

        arrows = data["dome/forces"]["frames"][lf.index]
        assert len(arrows["Arrows3D:vectors"]) == s.n_elements
        tol = dict(rtol=1e-6, atol=1e-6)  # Rerun stores float32
        np.testing.assert_allclose(arr(arrows["Arrows3D:vectors"]), f.global_forces * SCALE, **tol)
        np.testing.assert_allclose(arr(arrows["Arrows3D:origins"]), s.element_positions, **tol)

        ci = data["dome/interval"]["frames"][lf.index]
        idx = np.flatnonzero(f.contact)
        assert len(ci["Ellipsoids3D:centers"]) == len(idx)
        if len(idx):
            np.testing.assert_allclose(arr(ci["Ellipsoids3D:half_sizes"]), Z90 * f.stderr[idx] * SCALE, **tol)
            np.testing.assert_allclose(arr(ci["Ellipsoids3D:centers"]),
                                       s.element_positions[idx] + f.global_forces[idx] * SCALE, **tol)

        shear = data["camera/shear"]["frames"][lf.index]
        np.testing.assert_allclose(arr(shear["Arrows2D:origins"]), centres, atol=1e-3)
        vec = arr(shear["Arrows2D:vectors"])
        offset = f.local[:, :2] * SCALE  # the shear laid onto the dome, then seen by the camera
        moving = np.hypot(*offset.T) > 0.05
        assert k == 0 or moving[list(SPOTS)].all()  # the pressed elements' shear shows
        exact = cam.project(s.dome_point(np.flatnonzero(moving), offset[moving]), s)[:, ::-1] - centres[moving]
        np.testing.assert_allclose(vec[moving], exact, rtol=0.06, atol=0.05)  # linearised at the centre
        assert np.abs(vec[~moving]).max(initial=0.0) < 1.0

        totals = frame_totals(s, f.local[None], f.contact[None])
        res = arr(data["forces/resultant"]["frames"][lf.index]["Scalars:scalars"])
        np.testing.assert_allclose(res, totals["resultant"][0], rtol=1e-12, atol=1e-12)
        assert res[2] == pytest.approx(f.global_forces[f.contact, 2].sum(), abs=1e-12)
        fz = arr(data["forces/elements"]["frames"][lf.index]["Scalars:scalars"])
        np.testing.assert_array_equal(fz, f.local[[0, 1, 9, 25], 2])
        stats = arr(data["stats/frames"]["frames"][lf.index]["Scalars:scalars"])
        np.testing.assert_array_equal(stats, [k + 1, lf.dropped])
        ms = data["stats/latency_ms"]["frames"][lf.index]["Scalars:scalars"]
        assert ms == pytest.approx([1e3 * latency[k]])
        contact = arr(data["camera/contact"]["frames"][lf.index]["Points2D:positions"]).reshape(-1, 2)
        np.testing.assert_allclose(contact, centres[f.contact | f.clamped | lf.readings.saturated], atol=1e-3)

    for entity in ("camera/regions", "camera/centres", "dome/surface", "dome/elements", "dome/camera"):
        assert len(data[entity]["static"]) == 1 and data[entity]["static"][0].num_rows == 1, entity
        assert not data[entity]["frames"], entity
    assert "readings/G" not in data
    outlines = data["camera/regions"]["static"][0].column("LineStrips2D:strips").to_pylist()[0]
    assert len(outlines) == s.n_elements
    for e in (0, 12, 40):  # each outline lies at the region radius (the calibration's 2.2 mm) around its centre
        back = cam.unproject(np.array(outlines[e])[:, ::-1], s)
        np.testing.assert_allclose(np.linalg.norm(s.tangent_offset(np.full(len(back), e), back), axis=1), 2.2,
                                   rtol=1e-5)  # pixels stored as float32

    reader = RrdReader(path)
    (blueprint,) = reader.blueprints()
    views = {}
    for chunk in reader.stream(store=blueprint):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in rb.schema.names:
            views[rb.column("ViewBlueprint:space_origin").to_pylist()[0][0]] = \
                rb.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
    series = ("forces/resultant", "forces/elements", "stats/frames", "stats/latency_ms")
    assert views == {"camera": "2D", "dome": "3D", **dict.fromkeys(series, "TimeSeries")}


def test_without_a_calibration_the_readings_are_shown(tmp_path, cal, bare):
    """u arrows, contact and G of the chosen elements; no force arrows."""
    path = tmp_path / "bare.rrd"
    with open_view(path, camera=cal.camera, elements=[12, 0]) as view:
        for lf in bare:
            view.log(lf)
    data = read_rrd(path)
    s, cam = cal.sensor, cal.camera
    assert not {"dome/forces", "dome/interval", "forces/resultant", "forces/elements"} & set(data)
    assert "stats/latency_ms" not in {k for k, v in data.items() if v["frames"]}
    for lf in bare:
        g = arr(data["readings/G"]["frames"][lf.index]["Scalars:scalars"])
        np.testing.assert_array_equal(g, lf.readings.G[[12, 0]])
        vec = arr(data["camera/shear"]["frames"][lf.index]["Arrows2D:vectors"])
        assert vec.shape == (s.n_elements, 2)
        assert np.array_equal(np.hypot(*vec.T) > 0, np.hypot(*lf.readings.u.T) > 0)
        points = arr(data["dome/contact"]["frames"][lf.index]["Points3D:positions"]).reshape(-1, 3)
        np.testing.assert_allclose(points, s.element_positions[lf.readings.contact], rtol=1e-6, atol=1e-6)
        assert np.array_equal(np.frombuffer(bytes(data["camera/image"]["frames"][lf.index]["Image:buffer"][0]),
                                            np.uint8).reshape(cam.shape), lf.frame)
    assert any(lf.readings.contact[list(SPOTS)].all() for lf in bare)


def test_image_every_logs_every_nth_image_and_all_the_rest(tmp_path, cal, live):
    path = tmp_path / "thin.rrd"
    with open_view(path, calibration=cal, image_every=2) as view:
        for lf in live:
            view.log(lf)
    data = read_rrd(path)
    assert sorted(data["camera/image"]["frames"]) == [0, 2, 4]
    assert sorted(data["dome/forces"]["frames"]) == [0, 1, 2, 3, 4]


def test_two_views_coexist_and_leave_rerun_global_recording_alone(tmp_path, cal, live):
    before = rr.get_global_data_recording()
    a = open_view(tmp_path / "a.rrd", calibration=cal, name="a")
    b = open_view(tmp_path / "b.rrd", calibration=cal)
    assert a.recording is not b.recording
    for lf in live:
        (a if lf.index % 2 else b).log(lf)
    a.close(), b.close()
    a.close()  # again: nothing
    assert rr.get_global_data_recording() is before
    assert sorted(read_rrd(tmp_path / "a.rrd")["camera/image"]["frames"]) == [1, 3]
    assert sorted(read_rrd(tmp_path / "b.rrd")["camera/image"]["frames"]) == [0, 2, 4]
    with pytest.raises(RuntimeError, match="closed"):
        a.log(live[0])


@pytest.mark.parametrize("target", ["nativ", "Web", "out.csv", "", 3, None])
def test_a_bad_target_names_the_accepted_ones(target):
    with pytest.raises(InputError, match=r"'native'.*'web'.*\.rrd") as err:
        open_view(target, camera=FisheyeCamera())
    assert repr(target) in str(err.value)
    assert VIEW_TARGETS == ("native", "web", "FILE.rrd")


def test_a_file_target_in_a_missing_folder_or_a_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        open_view(tmp_path / "nope" / "x.rrd", camera=FisheyeCamera())
    (tmp_path / "d.rrd").mkdir()
    with pytest.raises(InputError, match="folder"):
        open_view(tmp_path / "d.rrd", camera=FisheyeCamera())


def test_missing_rerun_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(optitact._optional.EXTRAS, "rerun", ("live", "rerun-sdk"))
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun fails as if it were not installed
    with pytest.raises(MissingExtraError, match=r"rerun-sdk is needed for the live view.*optitact\[live\]"):
        open_view(tmp_path / "x.rrd", camera=FisheyeCamera())
    assert not (tmp_path / "x.rrd").exists()


def test_options_and_frames_are_checked(tmp_path, cal, live):
    cam = cal.camera
    with pytest.raises(InputError, match="from 0 to 40"):
        open_view(tmp_path / "x.rrd", camera=cam, elements=[0, 41])
    with pytest.raises(InputError, match="repeat"):
        open_view(tmp_path / "x.rrd", camera=cam, elements=[3, 3])
    with pytest.raises(InputError, match="force_range"):
        open_view(tmp_path / "x.rrd", camera=cam, force_range=(1.0, 1.0))
    with pytest.raises(InputError, match="image_every"):
        open_view(tmp_path / "x.rrd", camera=cam, image_every=0)
    with pytest.raises(TypeError, match="camera"):
        open_view(tmp_path / "x.rrd")
    with pytest.raises(CalibrationMismatchError):
        open_view(tmp_path / "x.rrd", calibration=cal, camera=FisheyeCamera(width=320, height=240))
    with open_view(tmp_path / "small.rrd", camera=FisheyeCamera(width=320, height=240)) as view:
        with pytest.raises(ShapeError, match="320x240"):
            view.log(live[1])
        assert view.frames == 0


def test_default_elements_one_per_ring():
    assert default_elements(DomeSensor.default()) == (0, 1, 9, 25)
    assert default_elements(DomeSensor(ring_counts=(1, 6), ring_polar_deg=(0.0, 30.0))) == (0, 1)


def test_native_spawns_the_viewer(monkeypatch, cal, live):
    calls = []
    monkeypatch.setattr(rr.RecordingStream, "spawn", lambda self, **kw: calls.append(kw))
    view = open_view("native", calibration=cal, grpc_port=9999)
    assert isinstance(view, LiveView) and view.target == "native" and view.url is None
    assert calls == [{"port": 9999, "connect": True, "hide_welcome_screen": True}]
    view.log(live[1])
    view.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_web_serves_the_viewer_and_the_data_on_localhost(cal, live):
    web, grpc = _free_port(), _free_port()
    with open_view("web", calibration=cal, web_port=web, grpc_port=grpc) as view:
        assert view.url == f"http://localhost:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy"
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read(2000).lower()
        with socket.create_connection(("127.0.0.1", grpc), timeout=10):
            pass
        view.log(live[1], latency_s=0.001)


def test_web_ports_in_use_are_named(cal):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=rf"port {port} \(grpc_port\) is not free"):
            open_view("web", calibration=cal, grpc_port=port, web_port=_free_port())
        with pytest.raises(InputError, match=rf"web viewer cannot listen on port {port}"):
            open_view("web", calibration=cal, web_port=port, grpc_port=_free_port())
    with pytest.raises(InputError, match="65535"):
        open_view("web", calibration=cal, web_port=70000)
