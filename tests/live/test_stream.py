"""Live streams: ``optitact.live.stream.stream`` and ``optitact process --camera`` (issue 18)."""

from __future__ import annotations

import gc
import os
import re
import signal
import threading

import cv2
import numpy as np
import pytest
import test_process as test_process_cli
from test_process import CAM, SENSOR, SPOTS, read_csv, spot_frame

import optitact
import optitact.live.stream as live
from optitact.cli import main
from optitact.io.tables import ReadingsWriter
from optitact.live.stream import LiveWriter, source_label, stream

WAIT = 30.0  # seconds a test waits for an event before failing (never reached when the code is right)


@pytest.fixture(scope="module")
def frames():
    """No load, then three loads of growing brightness (distinct frames: distinct readings)."""
    return np.stack([spot_frame(0), spot_frame(90), spot_frame(150), spot_frame(200), spot_frame(120)])


#: The shipped calibration's curves for the 160x120 test camera: ``(calibration, its file)``.
cal = test_process_cli.small_cal


@pytest.fixture(scope="module")
def video(tmp_path_factory, frames):
    """The frames as a lossless FFV1 video, written with cv2.VideoWriter."""
    path = tmp_path_factory.mktemp("video") / "clip.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (CAM.width, CAM.height), False)
    for f in frames:
        vw.write(f)
    vw.release()
    return path


class FakeCapture:
    """A capture whose read() the test controls: ``hooks[k]()`` runs when frame k is read."""

    def __init__(self, frames, hooks=None, *, endless=False):
        self.frames, self.hooks, self.endless = list(frames), dict(hooks or {}), endless
        self.reads = 0
        self.released = threading.Event()

    def read(self):
        k = self.reads
        self.reads += 1
        if k in self.hooks:
            self.hooks[k]()
        if self.endless:
            return True, self.frames[k % len(self.frames)]
        return (True, self.frames[k]) if k < len(self.frames) else (False, None)

    def release(self):
        self.released.set()


def fake_camera(monkeypatch, capture):
    """``--camera 0`` opens ``capture``."""
    monkeypatch.setattr(live, "open_capture", lambda source, size=None: capture)


def columns(rows, names, n):
    return np.array([[float(r[k]) for k in names] for r in rows]).reshape(n, 41, len(names))


def test_camera_file_gives_the_same_forces_as_process(tmp_path, frames, cal, video, capsys):
    """--camera FILE goes through cv2.VideoCapture and writes the same tables as process FILE."""
    c, cal_path = cal
    a, b = tmp_path / "process.csv", tmp_path / "camera.csv"
    assert main(["process", str(video), "--calibration", str(cal_path), "--out", str(a)]) == 0
    assert main(["process", "--camera", str(video), "--calibration", str(cal_path), "--out", str(b)]) == 0
    err = capsys.readouterr().err
    assert "reading clip.avi (every frame)" in err
    assert "the stream ended: 5 frames processed (1 of them baseline), 0 dropped" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera.csv", "camera.per_frame.csv", "process.csv",
                                                         "process.per_frame.csv"]
    got, want = read_csv(b), read_csv(a)
    assert list(got[0]) == [*want[0], "time_s", "wall_time", *ReadingsWriter.DRIFT_COLUMNS]
    assert len(got) == len(want) == 5 * 41
    assert [r["source"] for r in got] == [r["source"] for r in want]  # clip.avi#k in both
    names = ("G", "ux", "uy", "fx", "fy", "fz", "fx_global", "fy_global", "fz_global")
    np.testing.assert_allclose(columns(got, names, 5), columns(want, names, 5), rtol=1e-9, atol=1e-12)
    assert [r["contact"] for r in got] == [r["contact"] for r in want]
    got_pf, want_pf = read_csv(tmp_path / "camera.per_frame.csv"), read_csv(tmp_path / "process.per_frame.csv")
    assert [r["n_contact"] for r in got_pf] == [r["n_contact"] for r in want_pf]
    np.testing.assert_allclose([float(r["total_normal"]) for r in got_pf],
                               [float(r["total_normal"]) for r in want_pf], rtol=1e-9, atol=1e-12)
    # the independent truth: the calibration applied to the frames themselves
    fields = c.apply(c.pipeline(baseline=frames[0]).process(frames))
    np.testing.assert_allclose(columns(got, ("fx", "fy", "fz"), 5), [ff.local for ff in fields],
                               rtol=1e-9, atol=1e-12)
    assert (np.array([ff.local[list(SPOTS), 2] for ff in fields[1:]]) > 0).all()
    # and from Python: the generator yields the same force fields
    got_py = list(stream(video, calibration=c))
    assert [f.index for f in got_py] == [0, 1, 2, 3, 4] and [f.baseline for f in got_py] == [True] + [False] * 4
    assert [f.source for f in got_py] == [f"clip.avi#{k}" for k in range(5)]
    np.testing.assert_allclose([f.forces.local for f in got_py], [ff.local for ff in fields],
                               rtol=1e-9, atol=1e-12)
    assert all(f.dropped == 0 for f in got_py) and np.array_equal(got_py[3].frame, frames[3])


def test_camera_with_a_baseline_file_max_frames_and_a_plot(tmp_path, frames, cal, video, capsys):
    pytest.importorskip("matplotlib")
    c, cal_path = cal
    np.save(tmp_path / "base.npy", frames[0])
    out, plot = tmp_path / "f.csv", tmp_path / "p.png"
    assert main(["process", "--camera", str(video), "--baseline", str(tmp_path / "base.npy"),
                 "--max-frames", "2", "--calibration", str(cal_path), "--out", str(out),
                 "--plot", str(plot)]) == 0
    err = capsys.readouterr().err
    assert "--max-frames 2 reached: 2 frames processed (0 of them baseline), 0 dropped" in err
    assert plot.stat().st_size > 0
    want = c.apply(c.pipeline(baseline=frames[0]).process(frames[:2]))
    np.testing.assert_allclose(columns(read_csv(out), ("fx", "fy", "fz"), 2), [ff.local for ff in want],
                               rtol=1e-9, atol=1e-12)


def test_newest_policy_drops_frames_when_the_consumer_is_slow(tmp_path, frames, cal, monkeypatch, capsys):
    """Deterministic: the consumer's first write waits until the reader has read three more frames."""
    _, cal_path = cal
    first_taken, reader_ahead, second_taken = threading.Event(), threading.Event(), threading.Event()
    # frame 1 is read once the consumer has frame 0; reading frame 4 starts when frames 1, 2, 3 are
    # stored (1 and 2 overwritten: dropped) and ends once the consumer has taken frame 3
    capture = FakeCapture(frames, hooks={1: lambda: first_taken.wait(WAIT),
                                         4: lambda: (reader_ahead.set(), second_taken.wait(WAIT))})
    fake_camera(monkeypatch, capture)
    write, calls = LiveWriter.write, []

    def slow_write(self, lf):
        calls.append(lf.index)
        if len(calls) == 1:  # the slow consumer: busy with frame 0 until the reader is ahead
            first_taken.set()
            assert reader_ahead.wait(WAIT)
        if len(calls) == 2:
            second_taken.set()
        write(self, lf)

    monkeypatch.setattr(LiveWriter, "write", slow_write)
    out = tmp_path / "f.csv"
    assert main(["process", "--camera", "0", "--calibration", str(cal_path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "reading camera 0 (the newest frame, dropping the others when behind)" in err
    assert "the stream ended: 3 frames processed (1 of them baseline), 2 dropped" in err
    assert calls == [0, 3, 4] and capture.released.is_set()
    rows = read_csv(out)
    assert [rows[41 * k]["source"] for k in range(3)] == ["camera 0#0", "camera 0#3", "camera 0#4"]
    c, _ = cal
    want = c.apply(c.pipeline(baseline=frames[0]).process(frames[[0, 3, 4]]))
    np.testing.assert_allclose(columns(rows, ("fx", "fy", "fz"), 3), [ff.local for ff in want],
                               rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("how", ["exception", "signal"])
def test_ctrl_c_stops_cleanly_with_the_rows_so_far(tmp_path, frames, cal, monkeypatch, capsys, how):
    """KeyboardInterrupt from the source at frame k: k frames' rows, under the final names.

    A SIGINT while frame k is read lets that frame finish (the first Ctrl-C stops after the frame): k + 1.
    """
    _, cal_path = cal
    k = 3

    def interrupt():
        if how == "exception":
            raise KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGINT)

    capture = FakeCapture(frames, hooks={k: interrupt})
    fake_camera(monkeypatch, capture)
    out = tmp_path / "f.csv"
    before = signal.getsignal(signal.SIGINT)
    assert main(["process", "--camera", "0", "--policy", "all", "--calibration", str(cal_path),
                 "--out", str(out)]) == 0
    assert signal.getsignal(signal.SIGINT) is before
    n = k if how == "exception" else k + 1
    err = capsys.readouterr().err
    assert f"stopped by Ctrl-C: {n} frames processed (1 of them baseline), 0 dropped" in err
    assert f"wrote forces of {n} frames to {out}" in err
    assert len(read_csv(out)) == n * 41 and len(read_csv(tmp_path / "f.per_frame.csv")) == n
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv", "f.per_frame.csv"]
    assert capture.released.is_set()


def test_rows_are_on_disk_as_they_come_and_an_error_keeps_them(tmp_path, frames, monkeypatch, capsys):
    """Each frame's rows are flushed to NAME.partial.csv; a bad frame mid-stream keeps them there."""
    seen = []
    partial = tmp_path / "r.partial.csv"
    capture = FakeCapture([*frames[:3], frames[3][:60, :80]],
                          hooks={2: lambda: seen.append(len(read_csv(partial)))})
    fake_camera(monkeypatch, capture)
    out = tmp_path / "r.csv"
    assert main(["process", "--camera", "0", "--policy", "all", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert seen == [2 * 41]  # frames 0 and 1 were on disk while frame 2 was read
    assert "camera 0#3: the camera model is for 160x120 frames, got 80x60" in err
    assert "3 frames were written before this error" in err and str(partial) in err
    assert not out.exists() and len(read_csv(partial)) == 3 * 41
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.partial.csv"]


@pytest.mark.parametrize("env, target", [({}, "web"), ({"DISPLAY": ":0"}, "native"),
                                         ({"WAYLAND_DISPLAY": "wayland-0"}, "native")])
def test_view_without_a_target_is_native_with_a_display_else_web(monkeypatch, env, target):
    from optitact.cli.process import view_target

    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert view_target("auto") == target
    assert view_target("v.rrd") == "v.rrd" and view_target("web") == "web"


def test_stream_releases_the_capture_when_closed_or_collected(frames):
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    for policy in ("all", "newest"):  # a camera that never ends: closed while its reader runs
        capture = FakeCapture(frames, endless=True)
        gen = stream(capture, pipeline=pipe, policy=policy, baseline_frames=0)
        first = next(gen)
        assert first.index == 0 if policy == "all" else first.index >= 0
        gen.close()
        assert capture.released.wait(WAIT)
        reads = capture.reads
        assert capture.reads == reads  # nothing reads it any more
    capture = FakeCapture(frames)
    gen = stream(capture, pipeline=pipe)
    next(gen)
    del gen
    gc.collect()
    assert capture.released.is_set()


def test_stream_limits_baseline_and_colour(frames):
    """max_frames, a baseline argument, and colour frames read as OpenCV's BGR2GRAY grey."""
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    got = list(stream(FakeCapture(frames), pipeline=pipe, max_frames=2, baseline_frames=3))
    assert [(f.index, f.baseline) for f in got] == [(0, True), (1, True)]
    # a colour camera: B, G, R planes of different brightness
    bgr = np.stack([frames[2], frames[2] // 2, frames[2] // 4], axis=-1)
    got = list(stream(FakeCapture([bgr]), pipeline=pipe, baseline=frames[0]))
    assert len(got) == 1 and not got[0].baseline
    weights = 0.114 * bgr[..., 0] + 0.587 * bgr[..., 1] + 0.299 * bgr[..., 2]
    np.testing.assert_allclose(got[0].frame, weights, rtol=0, atol=0.5 + 1e-9)
    want = pipe.with_baseline(frames[0]).process(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(got[0].readings.G, want.G)


def test_source_labels_hide_passwords():
    assert source_label(3) == "camera 3" and source_label("2") == "camera 2"
    assert source_label("rtsp://me:pw@cam.local:554/s") == "rtsp://cam.local:554/s"
    assert source_label("videotestsrc ! appsink") == "videotestsrc ! appsink"


@pytest.mark.parametrize("case, match", [
    (["--camera", "7"], r"could not open camera 7 \(cv2.VideoCapture\): no such device, or OpenCV lacks "
                        r"the backend"),
    (["--camera", "missing.avi"], r"camera source not found: missing.avi is neither a device index"),
    (["--camera", "FAKE", "--policy", "all", "--baseline-frames", "9"],
     r"the stream ended after 5 frame\(s\), before the 9 baseline frame\(s\)"),
    (["--camera", "SMALL", "--calibration", "CAL"], r"camera 0#\d+: the calibration \(fingerprint \w+\) was "
                                                    r"made for 160x120 frames, got 80x60"),
    (["--camera", "FAKE", "frames.npy"], "give FRAMES or --camera, not both"),
    (["frames.npy", "--view"], "--policy, --view, --record, --max-frames and --seconds are options of a "
                               "--camera"),
    ([], r"no frames given: .* or --camera INDEX\|URL"),
])
def test_live_errors_exit_2_and_leave_no_file(tmp_path, frames, cal, monkeypatch, capsys, case, match):
    if "FAKE" in case or "SMALL" in case:
        fake_camera(monkeypatch, FakeCapture(frames if "FAKE" in case else frames[:, :60, :80]))
    case = ["0" if a in ("FAKE", "SMALL") else str(cal[1]) if a == "CAL" else a for a in case]
    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "frames.npy", frames)
    assert main(["process", *case, "--out", "f.csv"]) == 2
    assert re.search(match, capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames.npy"]


def test_a_lossy_recording_read_as_a_stream_warns_like_process(tmp_path, frames, cal):
    from optitact.io.frames import FramesWarning

    path = tmp_path / "mjpg.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (CAM.width, CAM.height), False)
    for f in frames:
        vw.write(f)
    vw.release()
    c, _ = cal
    with pytest.warns(FramesWarning, match=r"mjpg\.avi: video codec 'MJPG' is lossy"):
        got = list(stream(path, calibration=c))
    assert len(got) == len(frames)
