"""Outputs are whole or clearly partial: a failed or killed run never leaves a half table under the real name.

Crash points are injected deterministically: a NaN frame part-way through the
input, a write function that raises, a subprocess that ``os._exit``\\ s after a
chosen batch.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import optitact
from optitact.cli import main
from optitact.errors import InputError
from optitact.pipeline.batch import process_files
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.readings import Readings

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAM = optitact.optics.camera.FisheyeCamera(width=80, height=60)
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
    process_files([tmp_path / "good.npy"], pipeline=Pipeline(SENSOR, CAM), out=out)
    return out, out.read_bytes()


def test_an_error_mid_stream_keeps_the_complete_file_and_names_the_partial_one(tmp_path):
    out, before = _previous_run(tmp_path)
    frames = _frames(7, seed=1)
    frames[5, 3, 4] = np.nan  # batches: the baseline frame 0, then 1-2, 3-4 are written, 5-6 fails
    np.save(tmp_path / "rec.npy", frames)
    with pytest.raises(InputError) as err:
        process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=out, batch=2)
    msg = str(err.value)
    partial = tmp_path / "out.partial.csv"
    assert msg.startswith("rec.npy, frame 5: the frame must be finite")
    assert f"5 frames were written before this error: their rows are in {partial}, a partial table" in msg
    assert out.read_bytes() == before  # the earlier complete table is untouched
    rows = _rows(partial)
    assert len(rows) == 5 * 41 and rows[-1]["source"] == "rec.npy#4" and rows[-1]["element"] == "40"
    want = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[:5])
    got = np.array([float(r["G"]) for r in rows]).reshape(5, 41)
    np.testing.assert_allclose(got, want.G, rtol=1e-12, atol=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.npy", "out.csv", "out.partial.csv", "rec.npy"]


def test_an_error_before_any_frame_is_written_leaves_nothing(tmp_path):
    out, before = _previous_run(tmp_path)
    frames = _frames(3, seed=2)
    frames[0, 0, 0] = np.nan  # in the baseline frame: no row is written
    np.save(tmp_path / "rec.npy", frames)
    with pytest.raises(InputError, match=r"^rec\.npy, frame 0: .*finite.*pixel \(row 0, col 0\)$"):
        process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=out)
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
    from optitact.calib.document import fingerprint
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import DEFAULT_CALIBRATION

    from optitact.io.tables import ReadingsWriter

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
    from optitact.pipeline.batch import process_files
    from optitact.io.tables import ReadingsWriter
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.sensor import DomeSensor
    from optitact.pipeline.frame_pipeline import Pipeline

    real, calls = ReadingsWriter.write, []

    def write_then_die(self, *args, **kwargs):
        real(self, *args, **kwargs)
        calls.append(1)
        if len(calls) == int(sys.argv[2]):
            self._fh.flush()           # the rows so far reach the disk, half a table
            os._exit(9)                # killed: no cleanup, no exception handler

    ReadingsWriter.write = write_then_die
    pipe = Pipeline(DomeSensor.default(), FisheyeCamera(width=80, height=60))
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
    left = sorted(p.name for p in tmp_path.iterdir()
                  if p.name not in ("good.npy", "rec.npy", "out.csv", ".out.csv.lock"))  # the lock: taken over
    assert len(left) == 1 and left[0].startswith(".out.csv.") and left[0].endswith(".partial"), left
    held = (tmp_path / left[0]).read_text().splitlines()
    assert held[0].startswith(HEADER) and len(held) == 1 + 4 * 41  # the baseline frame and a batch of 3
    assert sorted(p.name for p in tmp_path.glob("*.csv")) == ["out.csv"]
    # the next run to the same path completes and replaces the old table with the whole new one
    process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=out)
    assert len(_rows(out)) == 10 * 41 and out.read_text().startswith(HEADER)
    # ... and removes what the killed run left (its process is gone): the hidden rows and the lock
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.npy", "out.csv", "rec.npy"]


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


# ---------------------------------------------------------------------------- Parquet and the CSV's numbers
def _calibration():
    from optitact.calib.document import fingerprint
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import DEFAULT_CALIBRATION

    shipped = json.loads(DEFAULT_CALIBRATION.read_text())
    shipped.update(camera=CAM.to_dict(), pipeline={}, fingerprint=fingerprint(SENSOR, CAM, {}))
    return Calibration.from_dict(shipped)


def loaded_frames(n: int, seed: int) -> np.ndarray:
    """Frames with bright spots on a few regions (contacts, forces), the first one unloaded."""
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 3, (n, *CAM.shape)).astype(np.uint8)
    for t in range(1, n):
        for _ in range(3):
            r, c = rng.integers(10, 50), rng.integers(10, 70)
            frames[t, r:r + 3, c:c + 3] = rng.integers(30, 255)
    return frames


def test_parquet_table_equals_the_csv_of_the_same_run(tmp_path, monkeypatch):
    pd = pytest.importorskip("pandas")
    pq = pytest.importorskip("pyarrow.parquet")
    from optitact.io import tables

    monkeypatch.setattr(tables, "PARQUET_ROW_GROUP", 41)  # a row group per write: several in a short run
    np.save(tmp_path / "rec.npy", loaded_frames(9, seed=6))
    cal = _calibration()
    for name in ("t.csv", "t.parquet"):
        process_files([tmp_path / "rec.npy"], calibration=cal, out=tmp_path / name, batch=4)
    assert pq.ParquetFile(tmp_path / "t.parquet").metadata.num_row_groups >= 3
    for csv_name, pq_name in (("t.csv", "t.parquet"), ("t.per_frame.csv", "t.per_frame.parquet")):
        a, b = pd.read_csv(tmp_path / csv_name), pd.read_parquet(tmp_path / pq_name)
        assert list(a.columns) == list(b.columns) and len(a) == len(b) > 0
        for col in a.columns:
            x, y = a[col].to_numpy(), b[col].to_numpy()
            if y.dtype == bool:
                y = y.astype(np.int64)
            if x.dtype.kind == "f":
                np.testing.assert_array_equal(x, y, err_msg=col)  # bit for bit, NaN where the CSV is empty
            else:
                assert (x == y).all(), col
    table = pd.read_parquet(tmp_path / "t.parquet")
    assert table["contact"].dtype == bool and table["contact"].any() and table["fz"].abs().max() > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npy", "t.csv", "t.parquet", "t.per_frame.csv",
                                                         "t.per_frame.parquet"]


KILLED_PARQUET = textwrap.dedent("""
    import os, sys
    import optitact
    from optitact.io import tables
    from optitact.pipeline.batch import process_files
    from optitact.io.tables import ReadingsWriter
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.sensor import DomeSensor
    from optitact.pipeline.frame_pipeline import Pipeline

    tables.PARQUET_ROW_GROUP = 41   # a row group per frame: some reach the disk before the kill
    real, calls = ReadingsWriter.write, []

    def write_then_die(self, *args, **kwargs):
        real(self, *args, **kwargs)
        calls.append(1)
        if len(calls) == 2:
            os._exit(9)

    ReadingsWriter.write = write_then_die
    pipe = Pipeline(DomeSensor.default(), FisheyeCamera(width=80, height=60))
    process_files([sys.argv[1]], pipeline=pipe, out=sys.argv[2], batch=3)
""")


def test_a_killed_parquet_run_leaves_no_file_under_the_real_name(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    np.save(tmp_path / "rec.npy", _frames(10, seed=7))
    out = tmp_path / "out.parquet"
    r = subprocess.run([sys.executable, "-c", KILLED_PARQUET, str(tmp_path / "rec.npy"), str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 9, r.stderr
    left = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("rec.npy", ".out.parquet.lock"))
    assert len(left) == 1 and left[0].startswith(".out.parquet.") and left[0].endswith(".partial"), left
    assert (tmp_path / left[0]).stat().st_size > 0  # row groups were written, but no footer: not a table
    with pytest.raises(Exception, match="(?i)parquet"):
        pq.read_table(tmp_path / left[0])
    process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=out)
    assert pq.read_table(out).num_rows == 10 * 41


def test_a_failed_parquet_run_keeps_a_readable_partial_table(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    frames = _frames(7, seed=1)
    frames[5, 3, 4] = np.nan
    np.save(tmp_path / "rec.npy", frames)
    out = tmp_path / "out.parquet"
    with pytest.raises(InputError, match="out.partial.parquet, a partial table"):
        process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=out, batch=2)
    table = pq.read_table(tmp_path / "out.partial.parquet")
    assert table.num_rows == 5 * 41 and table.column("source")[-1].as_py() == "rec.npy#4"
    assert not out.exists()


def test_parquet_without_pyarrow_is_one_line_naming_the_extra(tmp_path, monkeypatch, capsys):
    from optitact.errors import MissingExtraError
    from optitact.io.tables import ReadingsWriter

    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'optitact\[columnar\]'"):
        ReadingsWriter(tmp_path / "r.parquet")
    np.save(tmp_path / "rec.npy", _frames(3))
    assert main(["process", str(tmp_path / "rec.npy"), "--out", str(tmp_path / "r.parquet")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("optitact: error: pyarrow is needed for Parquet tables")
    assert [line for line in err if "error" in line or "Traceback" in line] == err[-1:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npy"]
    with pytest.raises(InputError, match="Parquet table is readable only once complete"):
        monkeypatch.delitem(sys.modules, "pyarrow")
        ReadingsWriter(tmp_path / "r.parquet", visible=True)


def test_csv_numbers_read_back_bit_for_bit(tmp_path):
    """The block formatting writes every float as repr does: shortest digits, -0.0, nan, tiny and huge."""
    from optitact.io.tables import ReadingsWriter
    from optitact.pipeline.readings import Readings

    rng = np.random.default_rng(8)
    g = rng.random((3, 41)) * 10.0 ** rng.integers(-300, 300, (3, 41))
    g[0, :4] = [0.0, np.nan, 5e-324, 1.7976931348623157e308]
    u = rng.normal(size=(3, 41, 2))
    u[1, 2] = [-0.0, 1e16]
    r = Readings(g, u, g > 1.0, g > 1e100)
    sources = ['a,"b".npy#0', "plain#1", "x\ny#2"]
    with ReadingsWriter(tmp_path / "r.csv") as w:
        w.write(r[:1], sources[:1])
        w.write(r[1:], sources[1:])
    rows = _rows(tmp_path / "r.csv")
    assert [row["source"] for row in rows[::41]] == sources and len(rows) == 3 * 41
    for name, want in (("G", g), ("ux", u[..., 0]), ("uy", u[..., 1])):
        got = np.array([float(row[name]) for row in rows]).reshape(3, 41)
        assert got.tobytes() == want.tobytes(), name
        assert [row[name] for row in rows] == [repr(v) for v in want.reshape(-1).tolist()]
    assert [int(row["contact"]) for row in rows] == (g > 1.0).astype(int).reshape(-1).tolist()
    assert [int(row["element"]) for row in rows] == list(range(41)) * 3


def test_the_table_gets_standard_error_columns_after_the_others(tmp_path):
    from optitact.calib.shipped import default_calibration

    from optitact.io.tables import ReadingsWriter
    from optitact.pipeline.readings import Readings

    cal = default_calibration()
    r = Readings(cal.g_max * 0.5, np.zeros((41, 2)), np.ones(41, bool), np.zeros(41, bool))
    forces, clamped = cal.forces(r)
    se = cal.stderr(r)
    path = tmp_path / "out.csv"
    with ReadingsWriter(path, forces=True, sensor=cal.sensor, stderr=True) as w:
        w.write(r, ["a"], forces, clamped, se)
    rows = list(csv.reader(path.read_text().splitlines()))
    assert tuple(rows[0]) == ReadingsWriter.COLUMNS + ReadingsWriter.FORCE_COLUMNS + ("fx_se", "fy_se", "fz_se")
    np.testing.assert_array_equal(np.array([row[-3:] for row in rows[1:]], float), se)
    with ReadingsWriter(tmp_path / "plain.csv", forces=True, sensor=cal.sensor) as w:
        w.write(r, ["a"], forces, clamped)
    head = (tmp_path / "plain.csv").read_text().splitlines()[0]
    assert tuple(head.split(",")) == ReadingsWriter.COLUMNS + ReadingsWriter.FORCE_COLUMNS
    with pytest.raises(InputError, match="stderr=True needs forces"):
        ReadingsWriter(tmp_path / "x.csv", stderr=True)
    with pytest.raises(ValueError, match="pass stderr"), \
            ReadingsWriter(tmp_path / "y.csv", forces=True, sensor=cal.sensor, stderr=True) as w:
        w.write(r, ["a"], forces, clamped)


def test_process_writes_standard_errors_that_grow_with_the_noise(tmp_path):
    """``noise`` (and ``process --stderr``): fx_se, fy_se, fz_se after the other columns; the model error
    alone where nothing is in contact, and more for frames read with a noisier camera (a larger gain)."""
    from optitact.pipeline.uncertainty import PixelNoise

    np.save(tmp_path / "rec.npy", loaded_frames(6, seed=3))
    cal = _calibration()
    quiet = process_files([tmp_path / "rec.npy"], calibration=cal, noise=PixelNoise(0.001), batch=4)
    loud = process_files([tmp_path / "rec.npy"], calibration=cal, noise=PixelNoise(0.1), batch=4)
    model = process_files([tmp_path / "rec.npy"], calibration=cal, noise="model", batch=4)
    contact = quiet.readings.contact
    assert contact.any()
    # no contact: the model error at Fz = 0 (the measured error model's floor, as for an empty frame)
    floor = cal.stderr(Readings.empty(len(cal.g)))
    np.testing.assert_allclose(model.stderr[~contact], np.broadcast_to(floor, contact.shape + (3,))[~contact],
                               rtol=1e-12)
    assert np.all(loud.stderr[contact] > quiet.stderr[contact])
    assert np.all(quiet.stderr[contact] >= model.stderr[contact])
    process_files([tmp_path / "rec.npy"], calibration=cal, noise="model", out=tmp_path / "t.csv", batch=4)
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["fx_se", "fy_se", "fz_se"]
    with pytest.raises(ValueError, match="needs a calibration"):
        process_files([tmp_path / "rec.npy"], pipeline=cal.pipeline(), noise="model")
    with pytest.raises(TypeError, match="PixelNoise or 'model'"):
        process_files([tmp_path / "rec.npy"], calibration=cal, noise=0.01)


def test_frames_started_by_the_caller_give_the_same_table_and_are_closed(tmp_path):
    """process_files(frames=...): a read-ahead begun before the pipeline was built; the table is the same."""
    import threading

    from optitact.io.frames import expand_sources, iter_frames, read_ahead

    np.save(tmp_path / "rec.npy", _frames(9, seed=7))
    src = [tmp_path / "rec.npy"]
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    process_files(src, pipeline=pipe, out=tmp_path / "a.csv", batch=4)
    ahead = read_ahead(iter_frames(expand_sources(src)), depth=3)
    done = process_files(src, pipeline=pipe, out=tmp_path / "b.csv", batch=4, frames=ahead)
    assert done.n_frames == 9
    assert (tmp_path / "b.csv").read_bytes() == (tmp_path / "a.csv").read_bytes()
    assert not any(t.name == "optitact-read-ahead" and t.is_alive() for t in threading.enumerate())
    ahead = read_ahead(iter_frames(expand_sources(src)), depth=3)
    with pytest.raises(InputError, match="scheduler"):
        process_files(src, pipeline=pipe, out=tmp_path / "c.csv", scheduler="tcp://nowhere:1", frames=ahead)
    assert list(ahead) == []  # closed


def test_process_files_restores_the_switch_interval(tmp_path):
    """The shorter thread switch interval of a run that decodes ahead is undone, also when the run fails."""
    np.save(tmp_path / "rec.npy", _frames(4))
    before = sys.getswitchinterval()
    process_files([tmp_path / "rec.npy"], pipeline=Pipeline(SENSOR, CAM), out=tmp_path / "a.csv")
    assert sys.getswitchinterval() == before
    bad = _frames(4)
    bad[2, 0, 0] = np.nan
    np.save(tmp_path / "bad.npy", bad)
    with pytest.raises(InputError):
        process_files([tmp_path / "bad.npy"], pipeline=Pipeline(SENSOR, CAM), out=tmp_path / "b.csv")
    assert sys.getswitchinterval() == before


def _photon_stacks(gain: float, read: float, n: int = 40, seed: int = 11):
    """No-load and pressed stacks of a camera with shot noise of known gain (DN per electron) and read noise."""
    rng = np.random.default_rng(seed)
    signal = np.tile(np.linspace(0.0, 200.0, CAM.shape[1]), (CAM.shape[0], 1))  # mean DN above the dark level
    dark = 10.0 + rng.normal(0.0, read, (n, *CAM.shape))
    shot = gain * rng.poisson(signal / gain, (n, *CAM.shape))
    pressed = np.clip(np.rint(10.0 + shot + rng.normal(0.0, read, (n, *CAM.shape))), 0, 255).astype(np.uint8)
    return np.clip(np.rint(dark), 0, 255).astype(np.uint8), pressed


def test_calibrate_noise_measures_the_conversion_gain_and_process_reads_the_file(tmp_path, capsys):
    """calibrate noise recovers a known gain; process --stderr --noise reads as --dn-per-electron does."""
    from optitact.pipeline.uncertainty import PixelNoise

    noload, pressed = _photon_stacks(gain=0.5, read=1.5)
    np.save(tmp_path / "noload.npy", noload)
    np.save(tmp_path / "pressed.npy", pressed)
    assert main(["calibrate", "noise", "--noload", str(tmp_path / "noload.npy"), "--pressed",
                 str(tmp_path / "pressed.npy"), "--out", str(tmp_path / "noise.json")]) == 0
    printed = json.loads(capsys.readouterr().out)
    model = PixelNoise.load(tmp_path / "noise.json")
    assert printed == model.to_dict()
    assert model.dn_per_electron == pytest.approx(0.5, rel=0.1) and model.exponent == 1.0
    # rounding adds 1/12 to lit pixels; the dark frames' noise is the read noise (and its rounding)
    assert model.lit_variance == pytest.approx(1 / 12, abs=0.1)
    assert model.read_sigma == pytest.approx(math.sqrt(1.5**2 + 1 / 12) * math.sqrt(1 + 1 / 40), rel=0.05)
    doc = json.loads((tmp_path / "noise.json").read_text())
    assert doc["measured"]["noload_frames"] == doc["measured"]["pressed_frames"] == 40

    # process: a noise file holding only a gain reads as --dn-per-electron with that gain
    PixelNoise(0.05).save(tmp_path / "gain.json")
    cal = _calibration()
    cal.save(tmp_path / "cal.json")
    np.save(tmp_path / "rec.npy", loaded_frames(5, seed=4))
    common = ["process", str(tmp_path / "rec.npy"), "--calibration", str(tmp_path / "cal.json"), "--stderr"]
    assert main([*common, "--noise", str(tmp_path / "gain.json"), "--out", str(tmp_path / "a.csv")]) == 0
    assert main([*common, "--dn-per-electron", "0.05", "--out", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    assert main([*common, "--noise", str(tmp_path / "noise.json"), "--out", str(tmp_path / "c.csv")]) == 0
    # the dark noise is the pipeline's own (its baseline is one frame here), not the file's read_sigma
    PixelNoise(model.dn_per_electron, None, model.lit_variance, model.exponent).save(tmp_path / "d.json")
    assert main([*common, "--noise", str(tmp_path / "d.json"), "--out", str(tmp_path / "d.csv")]) == 0
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "d.csv").read_bytes()
    a, c = _rows(tmp_path / "a.csv"), _rows(tmp_path / "c.csv")
    lit = [i for i, row in enumerate(a) if row["contact"] == "1"]
    assert lit and all(float(c[i]["fz_se"]) > float(a[i]["fz_se"]) for i in lit)  # ten times the gain: noisier


@pytest.mark.parametrize("extra, match", [
    (["--noise", "N"], "--noise is for --stderr"),
    (["--stderr", "--noise", "N", "--dn-per-electron", "0.1"], "not both"),
    (["--stderr", "--noise", "missing.json"], "no such noise file"),
    (["--stderr", "--noise", "BAD"], "expected a JSON object with 'pixel_noise'"),
    (["--stderr", "--noise", "NEG"], "dn_per_electron must be finite and >= 0"),
])
def test_process_refuses_a_bad_noise_option(tmp_path, capsys, extra, match):
    cal = _calibration()
    cal.save(tmp_path / "cal.json")
    np.save(tmp_path / "rec.npy", loaded_frames(3, seed=4))
    (tmp_path / "N").write_text(json.dumps({"pixel_noise": {"dn_per_electron": 0.1}}))
    (tmp_path / "BAD").write_text(json.dumps({"dn_per_electron": 0.1}))
    (tmp_path / "NEG").write_text(json.dumps({"pixel_noise": {"dn_per_electron": -0.1}}))
    extra = [str(tmp_path / x) if x in ("N", "BAD", "NEG", "missing.json") else x for x in extra]
    assert main(["process", str(tmp_path / "rec.npy"), "--calibration", str(tmp_path / "cal.json"),
                 "--out", str(tmp_path / "r.csv"), *extra]) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "r.csv").exists()


def test_calibrate_noise_refuses_frames_of_two_cameras_and_a_bad_exponent(tmp_path, capsys):
    noload, pressed = _photon_stacks(gain=0.5, read=1.5, n=4)
    np.save(tmp_path / "noload.npy", noload)
    np.save(tmp_path / "pressed.npy", pressed[:, :40])
    base = ["calibrate", "noise", "--noload", str(tmp_path / "noload.npy"), "--out", str(tmp_path / "n.json")]
    assert main([*base, "--pressed", str(tmp_path / "pressed.npy")]) == 2
    assert "they must be of one camera" in capsys.readouterr().err
    np.save(tmp_path / "pressed.npy", pressed)
    assert main([*base, "--pressed", str(tmp_path / "pressed.npy"), "--exponent", "steep"]) == 2
    assert "--exponent must be a number or 'fit'" in capsys.readouterr().err
    assert not (tmp_path / "n.json").exists()
