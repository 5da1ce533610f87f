"""Bad inputs typed at the command line: each refused with a clear one-line message (exit 2), or read right.

Outside-in (``tests/outside_in.py``): every command is the installed ``optitact`` entry point run
in a fresh folder with a fresh cache; the test process only writes the input files.
"""

from __future__ import annotations

import csv
import json
import math

import cv2
import numpy as np
import pytest
from test_outputs import loaded_frames  # tests/ is on sys.path

import optitact

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAM = optitact.optics.camera.FisheyeCamera(width=80, height=60)


def _refused(r, *fragments: str) -> None:
    """Exit 2, one ``optitact: error:`` line holding every fragment, no traceback."""
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("optitact: error:")]
    assert len(errors) == 1, r.stderr
    for fragment in fragments:
        assert fragment in errors[0], errors[0]


def _photon_stacks(gain: float, top: float, n: int = 40, seed: int = 3):
    """8-bit no-load and pressed stacks of a camera with shot noise of ``gain`` (DN per electron).

    The pressed signal ramps from 0 to ``top`` grey levels across the frame; above 255 it clips.
    """
    rng = np.random.default_rng(seed)
    signal = np.tile(np.linspace(0.0, top, CAM.shape[1]), (CAM.shape[0], 1))
    dark = 10.0 + rng.normal(0.0, 1.5, (n, *CAM.shape))
    pressed = 10.0 + gain * rng.poisson(signal / gain, (n, *CAM.shape)) + rng.normal(0.0, 1.5, (n, *CAM.shape))
    return tuple(np.clip(np.rint(s), 0, 255).astype(np.uint8) for s in (dark, pressed))


def _calibration(path):
    """The shipped curves on the 80x60 camera (a calibration file for small test frames)."""
    from optitact.calib.document import fingerprint
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import DEFAULT_CALIBRATION

    doc = json.loads(DEFAULT_CALIBRATION.read_text())
    doc.update(camera=CAM.to_dict(), pipeline={}, fingerprint=fingerprint(SENSOR, CAM, {}))
    Calibration.from_dict(doc).save(path)


def _video(path, n: int, shape) -> None:
    """A lossless grey video of ``n`` dark frames (skips the test where OpenCV cannot write FFV1)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (shape[1], shape[0]), False)
    if not writer.isOpened():
        pytest.skip("this OpenCV cannot write FFV1 videos")
    for _ in range(n):
        writer.write(np.zeros(shape, np.uint8))
    writer.release()


# ----------------------------------------------------------------------------- calibrate noise
def test_calibrate_noise_leaves_out_saturated_pixels_and_refuses_when_all_are(user):
    """Clipped pixels carry no noise: left out of the fit (gain still right), refused when no other is lit."""
    noload, pressed = _photon_stacks(gain=0.5, top=330.0)  # the brightest quarter of the ramp clips at 255
    np.save(user.path("noload.npy"), noload)
    np.save(user.path("pressed.npy"), pressed)
    r = user.run("calibrate", "noise", "--noload", "noload.npy", "--pressed", "pressed.npy", "--out", "n.json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(user.path("n.json").read_text())
    assert doc["pixel_noise"]["dn_per_electron"] == pytest.approx(0.5, rel=0.1)
    assert doc["measured"]["pixels_saturated"] > 0.15 * noload[0].size
    assert "saturated pixels left out" in r.stderr

    np.save(user.path("white.npy"), np.full_like(pressed, 255))
    r = user.run("calibrate", "noise", "--noload", "noload.npy", "--pressed", "white.npy", "--out", "w.json")
    _refused(r, "saturated", "255, the uint8 maximum", "lower the exposure")
    assert not user.path("w.json").exists()


@pytest.mark.parametrize("case, fragments", [
    ("depths", ["--noload frames (noload.npy) are uint8 (8-bit)",
                "--pressed frames (pressed.npy) uint16 (16-bit)"]),
    ("same file", ["is given as --pressed and as --noload"]),
    ("bool", ["holds bool values", "uint8, uint16 or float"]),
])
def test_calibrate_noise_refuses_stacks_that_cannot_measure_noise(user, case, fragments):
    noload, pressed = _photon_stacks(gain=0.5, top=200.0, n=4)
    np.save(user.path("noload.npy"), noload.astype(bool) if case == "bool" else noload)
    np.save(user.path("pressed.npy"), pressed.astype(np.uint16) * 257 if case == "depths" else pressed)
    other = "./noload.npy" if case == "same file" else "pressed.npy"
    r = user.run("calibrate", "noise", "--noload", "noload.npy", "--pressed", other, "--out", "n.json")
    _refused(r, *fragments)
    assert not user.path("n.json").exists()


def test_pixel_noise_refuses_what_the_command_refuses():
    """The Python API: bool stacks, two bit depths, saturation and impossible gains, each by name."""
    from optitact.errors import InputError, KindError
    from optitact.pipeline.uncertainty import MAX_DN_PER_ELECTRON, PixelNoise

    noload, pressed = _photon_stacks(gain=0.5, top=200.0, n=4)
    with pytest.raises(KindError, match="got bool"):
        PixelNoise.estimate(noload.astype(bool), pressed)
    with pytest.raises(InputError, match=r"uint8 \(8-bit\) and pressed frames uint16 \(16-bit\)"):
        PixelNoise.estimate(noload, pressed.astype(np.uint16))
    with pytest.raises(InputError, match="saturated"):
        PixelNoise.estimate(noload, np.full_like(pressed, 255))
    for bad in (1e308, MAX_DN_PER_ELECTRON * 1.01):
        with pytest.raises(InputError, match="dn_per_electron must be at most 65535"):
            PixelNoise(bad)
    assert PixelNoise(MAX_DN_PER_ELECTRON).dn_per_electron == MAX_DN_PER_ELECTRON


# ----------------------------------------------------------------------------- process options
def test_process_refuses_a_gain_no_camera_has_and_writes_every_standard_error(user):
    """--dn-per-electron 1e308 overflowed into empty standard errors; now refused before any frame is read."""
    _calibration(user.path("cal.json"))
    np.save(user.path("rec.npy"), loaded_frames(4, seed=4))
    common = ("process", "rec.npy", "--calibration", "cal.json", "--stderr")
    r = user.run(*common, "--dn-per-electron", "1e308", "--out", "se.csv")
    _refused(r, "--dn-per-electron", "at most 65535 grey levels per electron", "1e+308")
    assert "processing" not in r.stderr and not user.path("se.csv").exists()

    r = user.run(*common, "--dn-per-electron", "65535", "--out", "se.csv")
    assert r.returncode == 0, r.stderr
    with open(user.path("se.csv"), newline="") as fh:
        rows = [row for row in csv.DictReader(fh) if row["contact"] == "1"]
    assert rows
    assert all(math.isfinite(float(row[k])) for row in rows for k in ("fx_se", "fy_se", "fz_se"))


@pytest.mark.parametrize("flt, size, fragments", [
    ("gaussian", "1e9", ["a gaussian of sigma 1e+09 px", "must fit in the frame", "sigma at most 9.66 px"]),
    ("median", "999999999", ["a median window of 999999999 px", "must fit in the frame"]),
    ("gaussian", "nan", ["--filter-size must be a finite number of pixels > 0, got nan"]),
])
def test_process_refuses_a_filter_that_does_not_fit_in_the_frame(user, flt, size, fragments):
    np.save(user.path("rec.npy"), loaded_frames(3, seed=4))
    r = user.run("process", "rec.npy", "--filter", flt, "--filter-size", size, "--out", "r.csv")
    _refused(r, *fragments)
    assert not user.path("r.csv").exists()


@pytest.mark.parametrize("option, key", [("--setup", None), ("--noise", "pixel_noise")])
def test_a_json_file_nested_too_deeply_is_refused_naming_it(user, option, key):
    deep = "[" * 100_000 + "]" * 100_000
    user.path("deep.json").write_text(deep if key is None else f'{{"{key}": {deep}}}')
    np.save(user.path("rec.npy"), loaded_frames(3, seed=4))
    extra = ["--setup", "deep.json"] if option == "--setup" else \
        ["--calibration", "cal.json", "--stderr", "--noise", "deep.json"]
    if option == "--noise":
        _calibration(user.path("cal.json"))
    r = user.run("process", "rec.npy", *extra, "--out", "r.csv")
    _refused(r, "deep.json: not a", "nested too deeply")


def test_shipped_calibration_on_frames_of_another_camera_says_how_to_use_them(user):
    """320x240 frames with --calibration default: the message names the 640x480 frames and register/--setup."""
    rng = np.random.default_rng(0)
    np.save(user.path("small.npy"), rng.integers(0, 20, (3, 240, 320)).astype(np.uint8))
    r = user.run("process", "small.npy", "--calibration", "default", "--out", "r.csv")
    _refused(r, "small.npy#0: the frames are 320x240", "is for the default camera's 640x480 frames",
             "optitact register", "--setup setup.json", "transferred")
    # a live stream's --baseline is checked the same way before the stream starts
    np.save(user.path("base.npy"), rng.integers(0, 20, (2, 240, 320)).astype(np.uint8))
    _video(user.path("clip.avi"), 3, (240, 320))
    r = user.run("process", "--camera", "clip.avi", "--baseline", "base.npy", "--calibration", "default",
                 "--out", "r.csv")
    _refused(r, "base.npy: the frames are 320x240", "640x480", "optitact register", "--setup setup.json")


def test_plot_without_matplotlib_is_refused_before_any_frame_is_processed(user, tmp_path):
    """The plot extra is checked first: no table is written and then refused."""
    fake = tmp_path / "no-matplotlib" / "matplotlib"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise ModuleNotFoundError("No module named \'matplotlib\'", '
                                      'name="matplotlib")\n')
    _calibration(user.path("cal.json"))
    np.save(user.path("rec.npy"), loaded_frames(4, seed=4))
    r = user.run("process", "rec.npy", "--calibration", "cal.json", "--plot", "forces.png", "--out", "f.csv",
                 env={"PYTHONPATH": str(fake.parent)})
    _refused(r, "matplotlib is needed for --plot", "pip install 'optitact[plot]'")
    assert "processing" not in r.stderr
    assert sorted(p.name for p in user.folder.iterdir()) == ["cal.json", "rec.npy"]


@pytest.mark.parametrize("module, extra, option", [("rerun", "live", "--view"), ("mcap", "record", "--record")])
def test_view_and_record_without_their_extra_are_refused_before_any_frame(user, tmp_path, module, extra,
                                                                         option):
    """The live view needs rerun-sdk, a recording mcap: one line naming the extra, no table written."""
    fake = tmp_path / f"no-{module}" / module
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(f'raise ModuleNotFoundError("No module named \'{module}\'", '
                                      f'name="{module}")\n')
    _video(user.path("clip.avi"), 3, CAM.shape)
    value = "v.rrd" if option == "--view" else "run.mcap"
    r = user.run("process", "--camera", "clip.avi", option, value, "--out", "r.csv",
                 env={"PYTHONPATH": str(fake.parent)})
    _refused(r, f"pip install 'optitact[{extra}]'")
    assert sorted(p.name for p in user.folder.iterdir()) == ["clip.avi"]


# ----------------------------------------------------------------------------- render and demo
def test_a_header_only_forces_file_is_no_load():
    """``element,fx,fy,fz`` and no row: every element unloaded; without the element column still refused."""
    import tempfile
    from pathlib import Path

    from optitact.errors import ShapeError
    from optitact.io.tables import read_forces_csv

    path = Path(tempfile.mkdtemp()) / "none.csv"
    path.write_text("element,fx,fy,fz\n")
    np.testing.assert_array_equal(read_forces_csv(path, SENSOR.n_elements), np.zeros((SENSOR.n_elements, 3)))
    path.write_text("fx,fy,fz\n")
    with pytest.raises(ShapeError, match="expected 41 rows"):
        read_forces_csv(path, SENSOR.n_elements)


@pytest.mark.render
def test_render_takes_a_header_only_forces_file(user):
    user.path("none.csv").write_text("element,fx,fy,fz\n")
    r = user.run("render", "--forces", "none.csv", "--out", "frame.npy", "--spp", "1", "--width", "64",
                 "--height", "48")
    assert r.returncode == 0, r.stderr
    assert np.load(user.path("frame.npy")).shape == (48, 64)


@pytest.mark.render
def test_render_converts_the_units_a_forces_file_names(user):
    """The same load in mN and in N renders the same frame; a unit that is no force is refused by name."""
    user.path("n.csv").write_text("element,Fx (N),Fy (N),Fz (N)\n0,0.05,0,0.6\n")
    user.path("mn.csv").write_text("element;Fz [mN];fy (mN);FX (mN)\n0;600;0;50\n")
    for name in ("n", "mn"):
        r = user.run("render", "--forces", f"{name}.csv", "--out", f"{name}.npy", "--spp", "2", "--width", "64",
                     "--height", "48")
        assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(np.load(user.path("n.npy")), np.load(user.path("mn.npy")))
    user.path("g.csv").write_text("element,fx,fy,Fz (g)\n0,0,0,60\n")
    r = user.run("render", "--forces", "g.csv", "--out", "g.npy", "--spp", "1", "--width", "64",
                 "--height", "48")
    _refused(r, "g.csv", "'g' is a mass", "write gf")
    assert not user.path("g.npy").exists()


@pytest.mark.render
def test_demo_announces_only_the_renders_it_will_make(user, monkeypatch):
    """With the no-load renders cached (as a first run leaves them) the demo says it reads them."""
    from optitact.render.cache import cached_render

    user.path("setup.json").write_text(json.dumps({"sensor": SENSOR.to_dict(), "camera": CAM.to_dict()}))
    monkeypatch.setenv("OPTITACT_CACHE_DIR", str(user.cache))
    for k in range(4):  # the demo's no-load frames: seeds 1 + k after the default --seed 0
        cached_render(SENSOR, np.zeros((SENSOR.n_elements, 3)), camera=CAM, spp=4, seed=1 + k)
    r = user.run("demo", "--setup", "setup.json", "--spp", "4", "--out", "demo")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stderr.splitlines() if x.startswith("optitact: no-load baseline:"))
    assert "4 renders at 4 spp, read from the cache" in line and "about" not in line
    assert user.path("demo/estimated_forces.csv").is_file()


def test_a_filter_size_without_a_filter_is_refused(user):
    np.save(user.path("f.npy"), np.zeros((2, 48, 64), np.uint8))
    r = user.run("process", "f.npy", "--filter-size", "2", "--out", "r.csv")
    assert r.returncode == 2 and "--filter-size 2 sizes a filter: add --filter gaussian" in r.stderr
    assert not user.path("r.csv").exists()


def test_a_bad_noise_file_is_named_before_any_frame_is_read(user):
    """The frames do not exist: a run that read them first would name them, not the noise file."""
    user.path("noise.json").write_text('{"dn_per_electron": -1}')
    r = user.run("process", "missing.npy", "--calibration", "default", "--stderr", "--noise", "noise.json",
                 "--out", "r.csv")
    assert r.returncode == 2 and "noise.json" in r.stderr and "missing.npy" not in r.stderr, r.stderr


def test_calibrate_test_on_frames_of_another_camera_says_how_to_use_them(user):
    np.save(user.path("f.npy"), np.zeros((3, 240, 320), np.uint8))
    user.path("g.csv").write_text("frame,element,fx,fy,fz\n1,0,0,0,0.5\n")
    r = user.run("calibrate", "test", "--frames", "f.npy", "--forces", "g.csv", "--calibration", "default")
    assert r.returncode == 2
    assert "320x240" in r.stderr and "640x480" in r.stderr and "--setup setup.json" in r.stderr, r.stderr


@pytest.mark.parametrize("method, size", [("gaussian", 1e9), ("median", 999_999_999)])
def test_the_pipeline_refuses_a_filter_wider_than_the_frames(method, size):
    with pytest.raises(optitact.errors.InputError, match="wider than the 80x60 frames' shorter side"):
        optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, filter=method, filter_size=size)
