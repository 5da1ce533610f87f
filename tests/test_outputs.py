"""Outputs are whole or clearly partial: a failed or killed run never leaves a half table under the real name.

Crash points are injected deterministically: a NaN frame part-way through the
input, a write function that raises, a subprocess that ``os._exit``\\ s after a
chosen batch.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import optitact
from optitact.batch import process_files
from optitact.cli import main
from optitact.errors import InputError

SENSOR = optitact.DomeSensor.default()
CAM = optitact.FisheyeCamera(width=80, height=60)
HEADER = "frame,source,element,G,ux,uy,contact,saturated"


def _frames(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 40, (n, *CAM.shape)).astype(np.float32)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _previous_run(tmp_path):
    """A complete table from an earlier run, at the path the failing run writes to."""
    np.save(tmp_path / "good.npy", _frames(4))
    out = tmp_path / "out.csv"
    process_files([tmp_path / "good.npy"], pipeline=optitact.Pipeline(SENSOR, CAM), out=out)
    return out, out.read_bytes()


def test_an_error_mid_stream_keeps_the_complete_file_and_names_the_partial_one(tmp_path):
    out, before = _previous_run(tmp_path)
    frames = _frames(7, seed=1)
    frames[5, 3, 4] = np.nan  # batches: the baseline frame 0, then 1-2, 3-4 are written, 5-6 fails
    np.save(tmp_path / "rec.npy", frames)
    with pytest.raises(InputError) as err:
        process_files([tmp_path / "rec.npy"], pipeline=optitact.Pipeline(SENSOR, CAM), out=out, batch=2)
    msg = str(err.value)
    partial = tmp_path / "out.partial.csv"
    assert msg.startswith("rec.npy, frame 5: the frame must be finite")
    assert f"5 frames were written before this error: their rows are in {partial}, a partial table" in msg
    assert out.read_bytes() == before  # the earlier complete table is untouched
    rows = _rows(partial)
    assert len(rows) == 5 * 41 and rows[-1]["source"] == "rec.npy#4" and rows[-1]["element"] == "40"
    want = optitact.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[:5])
    got = np.array([float(r["G"]) for r in rows]).reshape(5, 41)
    np.testing.assert_allclose(got, want.G, rtol=1e-12, atol=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.npy", "out.csv", "out.partial.csv", "rec.npy"]


def test_an_error_before_any_frame_is_written_leaves_nothing(tmp_path):
    out, before = _previous_run(tmp_path)
    frames = _frames(3, seed=2)
    frames[0, 0, 0] = np.nan  # in the baseline frame: no row is written
    np.save(tmp_path / "rec.npy", frames)
    with pytest.raises(InputError, match=r"^rec\.npy, frame 0: .*finite.*pixel \(row 0, col 0\)$"):
        process_files([tmp_path / "rec.npy"], pipeline=optitact.Pipeline(SENSOR, CAM), out=out)
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.npy", "out.csv", "rec.npy"]


def test_the_command_says_where_the_partial_rows_are(tmp_path, capsys):
    frames = _frames(40, seed=3)
    frames[35, 10, 10] = np.inf
    np.save(tmp_path / "rec.npy", frames)
    out = tmp_path / "r.csv"
    assert main(["process", str(tmp_path / "rec.npy"), "--out", str(out), "--batch", "8"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("optitact: error: rec.npy, frame 35: the frame must be finite, got inf")
    assert f"33 frames were written before this error: their rows are in {tmp_path / 'r.partial.csv'}" in err
    assert not out.exists() and len(_rows(tmp_path / "r.partial.csv")) == 33 * 41


def test_a_writer_that_fails_part_way_keeps_both_tables_partial(tmp_path, monkeypatch):
    """With forces: both tables (per element, per frame) are kept as .partial, neither under the real name."""
    from optitact.calib import DEFAULT_CALIBRATION, Calibration, fingerprint
    from optitact.io import ReadingsWriter

    shipped = json.loads(DEFAULT_CALIBRATION.read_text())
    shipped.update(camera=CAM.to_dict(), pipeline={}, fingerprint=fingerprint(SENSOR, CAM, {}))
    cal = Calibration.from_dict(shipped)
    np.save(tmp_path / "rec.npy", _frames(6, seed=4))
    real = ReadingsWriter.write
    calls = []

    def failing(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(ReadingsWriter, "write", failing)
    with pytest.raises(OSError) as err:
        process_files([tmp_path / "rec.npy"], calibration=cal, out=tmp_path / "f.csv", batch=2)
    assert "No space left on device" in str(err.value) and "f.partial.csv" in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.partial.csv", "f.per_frame.partial.csv", "rec.npy"]
    assert len(_rows(tmp_path / "f.partial.csv")) == 3 * 41  # the baseline frame, then a batch of 2
    assert [r["frame"] for r in _rows(tmp_path / "f.per_frame.partial.csv")] == ["0", "1", "2"]


KILLED = textwrap.dedent("""
    import os, sys
    import optitact
    from optitact.batch import process_files
    from optitact.io import ReadingsWriter

    real, calls = ReadingsWriter.write, []

    def write_then_die(self, *args, **kwargs):
        real(self, *args, **kwargs)
        calls.append(1)
        if len(calls) == int(sys.argv[2]):
            self._fh.flush()           # the rows so far reach the disk, half a table
            os._exit(9)                # killed: no cleanup, no exception handler

    ReadingsWriter.write = write_then_die
    pipe = optitact.Pipeline(optitact.DomeSensor.default(), optitact.FisheyeCamera(width=80, height=60))
    process_files([sys.argv[1]], pipeline=pipe, out=sys.argv[3], batch=3)
""")


def test_a_killed_run_never_leaves_half_a_table_under_the_real_name(tmp_path):
    out, before = _previous_run(tmp_path)
    np.save(tmp_path / "rec.npy", _frames(10, seed=5))
    r = subprocess.run([sys.executable, "-c", KILLED, str(tmp_path / "rec.npy"), "2", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 9, r.stderr
    assert out.read_bytes() == before  # the complete table of the earlier run, not half of the new one
    # what the killed run left is hidden and says it is partial; no visible CSV but the complete one
    left = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("good.npy", "rec.npy", "out.csv"))
    assert len(left) == 1 and left[0].startswith(".out.csv.") and left[0].endswith(".partial"), left
    held = (tmp_path / left[0]).read_text().splitlines()
    assert held[0].startswith(HEADER) and len(held) == 1 + 4 * 41  # the baseline frame and a batch of 3
    assert sorted(p.name for p in tmp_path.glob("*.csv")) == ["out.csv"]
    # the next run to the same path completes and replaces the old table with the whole new one
    process_files([tmp_path / "rec.npy"], pipeline=optitact.Pipeline(SENSOR, CAM), out=out)
    assert len(_rows(out)) == 10 * 41 and out.read_text().startswith(HEADER)


def test_force_field_to_csv_is_atomic(tmp_path, monkeypatch):
    """ForceField.to_csv: a failure part-way leaves the previous file as it was (it used to truncate it)."""
    import optitact.forces as forces_module
    from optitact.forces import ForceField

    f = np.zeros((41, 3))
    f[0] = (0.1, 0.0, 0.5)
    path = ForceField(SENSOR, f).to_csv(tmp_path / "ff.csv")
    before = path.read_bytes()
    real = csv.writer

    class Failing:
        def __init__(self, fh):
            self.w, self.n = real(fh), 0

        def writerow(self, row):
            self.n += 1
            if self.n == 10:
                raise OSError(28, "No space left on device")
            return self.w.writerow(row)

    monkeypatch.setattr(forces_module.csv, "writer", Failing)
    with pytest.raises(OSError, match="No space left"):
        ForceField(SENSOR, 2 * f).to_csv(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ff.csv"]
