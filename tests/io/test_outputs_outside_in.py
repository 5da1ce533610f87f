"""Outputs written whole or named partial, run as a user runs ``optitact process``: a new process each time.

Two runs writing one ``--out`` (the second is refused, naming the first's pid), a full disk (a
file-size limit on the process: writes past it fail with EFBIG, as on a full disk with ENOSPC),
hidden partial files that killed runs left, the capture time of live rows, and an ``--out`` that
names an input file.
"""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from outside_in import optitact_executable

cv2 = pytest.importorskip("cv2")

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and resource limits")

H, W = 60, 80
N_EL = 41  # elements of the default dome


def _frames(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 60, (n, H, W)).astype(np.uint8)


def _video(path, n: int, seed: int = 0) -> None:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30, (W, H), False)
    for f in _frames(n, seed):
        vw.write(f)
    vw.release()


def _rows(path) -> list[list[str]]:
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


def _ends_on_a_whole_frame(path) -> list[list[str]]:
    """The table's rows, checked to end with a final newline on the last element of its last frame."""
    data = path.read_bytes()
    assert data.endswith(b"\r\n"), data[-80:]
    rows = _rows(path)
    header, body = rows[0], rows[1:]
    assert body and all(len(r) == len(header) for r in body)
    assert len(body) % N_EL == 0
    frames = [int(r[0]) for r in body]
    assert frames == [k for k in range(len(body) // N_EL) for _ in range(N_EL)]
    assert [int(r[2]) for r in body] == list(range(N_EL)) * (len(body) // N_EL)
    return rows


def _error_line(r) -> str:
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("optitact: error:")]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def _dead_pid() -> int:
    """The pid of a process that has ended."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _wait_for_rows(path, frames: int, proc, timeout: float = 60) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and path.read_bytes().count(b"\n") > 1 + frames * N_EL:
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.002)
    raise AssertionError(f"{path} got no rows in {timeout} s")


def test_a_second_run_writing_the_same_out_is_refused_naming_the_first(user):
    _video(user.path("first.avi"), 1000, seed=1)
    _video(user.path("second.avi"), 5, seed=2)
    np.save(user.path("rec.npy"), _frames(3))
    first = subprocess.Popen([str(optitact_executable()), "process", "--camera", "first.avi", "--out", "f.csv"],
                             cwd=user.folder, env=user.env(cached=True), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_rows(user.path("f.partial.csv"), 2, first)
        os.kill(first.pid, signal.SIGSTOP)  # holds the output, mid-stream, for as long as the test needs
        for source in (("--camera", "second.avi"), ("rec.npy",)):
            r = user.run("process", *source, "--out", "f.csv", cached=True)
            assert r.returncode == 2, r.stderr
            line = _error_line(r)
            assert re.search(rf"f\.csv is being written by another run \(pid {first.pid}\b", line), line
        os.kill(first.pid, signal.SIGCONT)
        os.kill(first.pid, signal.SIGINT)  # Ctrl-C: a clean stop after this frame
        _, err = first.communicate(timeout=60)
    finally:
        if first.poll() is None:
            os.kill(first.pid, signal.SIGCONT)
            first.kill()
            first.wait()
    assert first.returncode == 0, err
    rows = _ends_on_a_whole_frame(user.path("f.csv"))  # whole, and the first run's video alone
    assert {r[1].split("#")[0] for r in rows[1:]} == {"first.avi"}
    assert sorted(p.name for p in user.folder.iterdir()) == ["f.csv", "first.avi", "rec.npy", "second.avi"]
    # the lock went with the run: the next one writes
    r = user.run("process", "rec.npy", "--out", "f.csv")
    assert r.returncode == 0, r.stderr
    assert {r[1].split("#")[0] for r in _rows(user.path("f.csv"))[1:]} == {"rec.npy"}


def test_the_lock_of_a_killed_run_is_taken_over(user):
    np.save(user.path("rec.npy"), _frames(3))
    user.path(".f.csv.lock").write_text(f"{_dead_pid()}\n")
    r = user.run("process", "rec.npy", "--out", "f.csv")
    assert r.returncode == 0, r.stderr
    assert len(_ends_on_a_whole_frame(user.path("f.csv"))) == 1 + 3 * N_EL
    assert sorted(p.name for p in user.folder.iterdir()) == ["f.csv", "rec.npy"]


def _run_on_a_full_disk(user, *args: str, limit: int) -> subprocess.CompletedProcess:
    """``optitact ARGS`` with files limited to ``limit`` bytes: writes past it fail as on a full disk.

    The session's cache (``cached=True``), whose compiled kernels are already there: the run writes its table.
    """
    setup = ("import os, resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]),) * 2); "
             "os.execv(sys.argv[2], sys.argv[2:])")
    return subprocess.run([sys.executable, "-c", setup, str(limit), str(optitact_executable()), *args],
                          cwd=user.folder, env=user.env(cached=True), capture_output=True, text=True,
                          timeout=120)


def test_a_full_disk_names_the_file_and_the_partial_table_ends_on_a_whole_frame(user):
    np.save(user.path("rec.npy"), _frames(12))
    r = _run_on_a_full_disk(user, "process", "rec.npy", "--out", "f.csv", "--batch", "1", limit=6000)
    assert r.returncode == 2, r.stderr
    line = _error_line(r)
    assert line.startswith("optitact: error: writing f.csv: File too large"), line
    rows = _ends_on_a_whole_frame(user.path("f.partial.csv"))
    n = (len(rows) - 1) // N_EL
    assert 1 <= n < 12 and f"{n} frames were written before this error: their rows are in f.partial.csv" in line
    assert not user.path("f.csv").exists()


def test_a_full_disk_mid_stream_keeps_whole_frames_of_a_live_table(user):
    _video(user.path("clip.avi"), 30)
    warm = user.run("process", "--camera", "clip.avi", "--out", "warm.csv", "--max-frames", "2", cached=True)
    assert warm.returncode == 0, warm.stderr  # compiled kernels cached: the limited run writes only its table
    r = _run_on_a_full_disk(user, "process", "--camera", "clip.avi", "--out", "live.csv", limit=8000)
    assert r.returncode == 2, r.stderr
    line = _error_line(r)
    assert line.startswith("optitact: error: writing live.partial.csv: File too large"), line
    rows = _ends_on_a_whole_frame(user.path("live.partial.csv"))
    assert rows[0][-7:-5] == ["time_s", "wall_time"] and rows[0][-1] == "drift_flag"
    assert 1 <= (len(rows) - 1) // N_EL < 30
    assert not user.path("live.csv").exists()


def test_a_complete_run_removes_the_partial_files_of_killed_runs(user):
    np.save(user.path("rec.npy"), _frames(3))
    dead, alive = _dead_pid(), os.getpid()
    for pid in (dead, alive):
        user.path(f".f.csv.{pid}.partial").write_text("frame,source\r\n0,rec.npy#0")
    user.path(f".other.csv.{dead}.partial").write_text("not this output's")
    r = user.run("process", "rec.npy", "--out", "f.csv")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in user.folder.iterdir()) == sorted(
        [f".f.csv.{alive}.partial", f".other.csv.{dead}.partial", "f.csv", "rec.npy"])


def test_live_rows_carry_the_capture_time(user):
    pd = pytest.importorskip("pandas")
    _video(user.path("clip.avi"), 6)
    before = datetime.now(timezone.utc)
    r = user.run("process", "--camera", "clip.avi", "--out", "live.csv", cached=True)
    assert r.returncode == 0, r.stderr
    table = pd.read_csv(user.path("live.csv"))
    assert list(table.columns[-7:]) == ["time_s", "wall_time", "drift_gain", "drift_offset", "drift_shift_x",
                                        "drift_shift_y", "drift_flag"] and len(table) == 6 * N_EL
    per_frame = table.groupby("frame")
    assert (per_frame["time_s"].nunique() == 1).all() and (per_frame["wall_time"].nunique() == 1).all()
    t = per_frame["time_s"].first().to_numpy()
    assert t[0] >= 0 and np.all(np.diff(t) >= 0)
    wall = [datetime.fromisoformat(w) for w in per_frame["wall_time"].first()]
    assert all(w.utcoffset() == timedelta(0) for w in wall)
    assert before - timedelta(seconds=1) <= wall[0] <= datetime.now(timezone.utc)
    # the same clock: wall-time steps are the time_s steps (to the microsecond the ISO time keeps)
    steps = np.array([(w - wall[0]).total_seconds() for w in wall])
    np.testing.assert_allclose(steps, t - t[0], rtol=0, atol=2e-6)
    assert pd.to_datetime(table["wall_time"]).dt.tz is not None


def test_a_new_stream_keeps_the_rows_a_killed_one_left(user):
    """The visible partial table of a stream that did not finish is moved aside, not written over."""
    _video(user.path("clip.avi"), 3)
    earlier = "frame,source,element\r\n0,cam,0\r\n"
    user.path("live.partial.csv").write_text(earlier, newline="")
    r = user.run("process", "--camera", "clip.avi", "--out", "live.csv", cached=True)
    assert r.returncode == 0, r.stderr
    kept = list(user.folder.glob("live.partial.earlier-*.csv"))
    assert len(kept) == 1 and kept[0].read_bytes().decode() == earlier
    assert f"kept as {kept[0].name}" in r.stderr and "optitact: warning:" in r.stderr
    assert len(_rows(user.path("live.csv"))) == 1 + 3 * N_EL and not user.path("live.partial.csv").exists()


def _png(path, seed: int) -> bytes:
    assert cv2.imwrite(str(path), _frames(1, seed)[0])
    return path.read_bytes()


@pytest.mark.parametrize(("frames", "out", "what"), [
    (("a.png", "b.png"), "b.png", "--out b.png"),
    (("a.png", "b.png"), "./sub/../b.png", "--out sub/../b.png"),
    (("a.png", "b.partial.png"), "b.png", "--out's partial table b.partial.png"),
])
def test_an_out_that_is_an_input_frame_is_refused(user, frames, out, what):
    (user.folder / "sub").mkdir()
    data = {name: _png(user.path(name), seed) for seed, name in enumerate(frames)}
    r = user.run("process", *frames, "--out", out)
    assert r.returncode == 2, r.stderr
    line = _error_line(r)
    assert what in line and "is an input file" in line and "choose another output name" in line, line
    assert {name: user.path(name).read_bytes() for name in frames} == data  # the frames are untouched
    assert sorted(p.name for p in user.folder.iterdir()) == sorted([*frames, "sub"])


# ----------------------------------------------------------------------------- the library beneath
def test_a_failed_per_frame_write_cuts_both_tables_back_to_the_same_whole_frame(tmp_path, monkeypatch):
    """In process: the per-frame table's write fails after the element table's: both end on frame 1."""
    import errno

    from optitact.io.partial import PartialCSV
    from optitact.io.tables import ReadingsWriter
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.sensor import DomeSensor
    from optitact.pipeline.frame_pipeline import Pipeline

    sensor = DomeSensor.default()
    readings = Pipeline(sensor, FisheyeCamera(width=W, height=H), baseline=_frames(1)[0]).process(_frames(4))
    real, calls = PartialCSV.write, []

    class Full:
        """The open file of a disk that fills part-way through the next write."""

        def __init__(self, fh):
            self.fh, self.room = fh, 10

        def write(self, data):
            if not self.room:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            n, self.room = self.fh.write(bytes(data[:self.room])), 0
            return n

        def __getattr__(self, name):
            return getattr(self.fh, name)

    def full_on_the_second_per_frame_block(self, text):
        calls.append(self.path.name)
        if calls.count("f.per_frame.csv") == 3:  # the header, frames 0-1, then frames 2-3
            self.fh = Full(self.fh)
        return real(self, text)

    monkeypatch.setattr(PartialCSV, "write", full_on_the_second_per_frame_block)
    forces, clamped = np.zeros((4, N_EL, 3)), np.zeros((4, N_EL), bool)
    with pytest.raises(OSError, match=r"^writing .*f\.per_frame\.csv: No space left on device \[2 frames were "
                                      r"written") as err:
        with ReadingsWriter(tmp_path / "f.csv", forces=True, sensor=sensor) as w:
            for k in (0, 2):
                w.write(readings[k:k + 2], [f"x#{k}", f"x#{k + 1}"], forces[k:k + 2], clamped[k:k + 2])
    assert err.value.errno == errno.ENOSPC
    assert len(_ends_on_a_whole_frame(tmp_path / "f.partial.csv")) == 1 + 2 * N_EL
    per_frame = tmp_path / "f.per_frame.partial.csv"
    assert [r[0] for r in _rows(per_frame)[1:]] == ["0", "1"] and per_frame.read_bytes().endswith(b"\r\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.partial.csv", "f.per_frame.partial.csv"]


def test_two_writers_of_one_table_in_one_process(tmp_path):
    from optitact.errors import InputError
    from optitact.io.tables import ReadingsWriter

    with ReadingsWriter(tmp_path / "f.csv"):
        with pytest.raises(InputError, match=rf"f\.csv is being written by another run \(pid {os.getpid()};"):
            ReadingsWriter(tmp_path / "f.csv")
        with ReadingsWriter(tmp_path / "g.csv"):  # another table: no conflict
            pass
    with ReadingsWriter(tmp_path / "f.csv"):  # released
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv", "g.csv"]
