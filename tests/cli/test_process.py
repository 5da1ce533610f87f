"""``optitact process`` (frames -> readings CSV) and ``optitact bench pipeline``."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

import optitact
from optitact.cli import main
from optitact.errors import InputError
from optitact.io.frames import FramesWarning, count_frames, expand_sources, iter_frames
from optitact.pipeline.frame_pipeline import Pipeline

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAM = optitact.optics.camera.FisheyeCamera(width=160, height=120)
SPOTS = {0: (0.3, -0.2), 5: (-0.4, 0.1), 20: (0.0, 0.5)}  # element -> centre (mm, local)


def spot_frame(amp: float, sigma: float = 0.35, dark: int = 4, dtype=np.uint8) -> np.ndarray:
    """A frame with one Gaussian spot per element of SPOTS, drawn on the dome, over a dark level."""
    rows, cols = np.mgrid[0:CAM.height, 0:CAM.width]
    pts = CAM.unproject(np.stack([rows, cols], -1).astype(float), SENSOR, outside="nan")
    img = np.zeros(CAM.shape)
    for e, c in SPOTS.items():
        xy = SENSOR.tangent_offset(np.full(CAM.shape, e), pts)
        img += amp * np.exp(-0.5 * ((xy - c) ** 2).sum(-1) / sigma**2)
    img = np.nan_to_num(img) + dark
    return np.clip(np.rint(img), 0, np.iinfo(dtype).max).astype(dtype)


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def table(rows, n_frames):
    g = np.array([float(r["G"]) for r in rows]).reshape(n_frames, 41)
    u = np.array([[float(r["ux"]), float(r["uy"])] for r in rows]).reshape(n_frames, 41, 2)
    contact = np.array([r["contact"] == "1" for r in rows]).reshape(n_frames, 41)
    return g, u, contact


@pytest.fixture(scope="module")
def frames():
    return np.stack([spot_frame(0), spot_frame(120), spot_frame(200)])


def test_process_folder_matches_the_pipeline(tmp_path, frames, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{k:02d}.png"), f)
    (folder / "notes.txt").write_text("not a frame")
    out = tmp_path / "r.csv"
    assert main(["process", str(folder), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "baseline = mean of the first 1 frame" in err and "wrote readings of 3 frames" in err
    rows = read_csv(out)
    assert list(rows[0]) == ["frame", "source", "element", "G", "ux", "uy", "contact", "saturated"]
    assert len(rows) == 3 * 41 and rows[41]["source"] == "f01.png"
    g, u, contact = table(rows, 3)
    want = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames)
    np.testing.assert_allclose(g, want.G, rtol=1e-8, atol=0)
    np.testing.assert_allclose(u, want.u, rtol=0, atol=1e-8)
    assert np.array_equal(contact, want.contact)
    assert not contact[0].any()  # the baseline frame itself reads nothing
    assert set(np.flatnonzero(contact[2])) == set(SPOTS)
    for e, c in SPOTS.items():  # the spots' centres come back (8-bit rounding: 0.02 mm)
        np.testing.assert_allclose(u[2, e], c, rtol=0, atol=0.02)


def test_process_npy_stack_with_baseline_file_and_16_bit_png(tmp_path, frames):
    np.save(tmp_path / "stack.npy", frames[1:])
    base = tmp_path / "base.png"
    cv2.imwrite(str(base), frames[0].astype(np.uint16) * 256)
    wide = tmp_path / "f16.png"
    cv2.imwrite(str(wide), frames[2].astype(np.uint16) * 256)
    out = tmp_path / "r.csv"
    assert main(["process", str(tmp_path / "stack.npy"), "--out", str(out), "--baseline",
                 str(tmp_path / "stack.npy"), "--baseline-frames", "5"]) == 0
    g, _, _ = table(read_csv(out), 2)
    want = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, baseline=frames[1:]).process(frames[1:])
    np.testing.assert_allclose(g, want.G, rtol=1e-8, atol=0)
    out16 = tmp_path / "r16.csv"
    assert main(["process", str(wide), "--out", str(out16), "--baseline", str(base),
                 "--noise-sigma", str(0.5 * 256)]) == 0
    rows = read_csv(out16)
    assert rows[0]["source"] == "f16.png"
    g16, _, _ = table(rows, 1)
    ref = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[2])
    np.testing.assert_allclose(g16[0], 256 * ref.G, rtol=1e-8, atol=0)


def test_process_video(tmp_path, frames):
    path = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (CAM.width, CAM.height),
                         False)
    for f in frames:
        vw.write(f)
    vw.release()
    files = expand_sources([path])
    assert count_frames(files) == 3
    with pytest.warns(FramesWarning, match=r"clip\.avi: video codec 'MJPG' is lossy"):
        names = [n for n, _ in iter_frames(files)]
    assert names == ["clip.avi#0", "clip.avi#1", "clip.avi#2"]
    out = tmp_path / "r.csv"
    assert main(["process", str(path), "--out", str(out)]) == 0
    g, _, contact = table(read_csv(out), 3)
    assert not contact[0].any()
    assert set(np.flatnonzero(contact[2])) == set(SPOTS)  # JPEG-compressed, same spots
    want = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[2]).G
    np.testing.assert_allclose(g[2][list(SPOTS)], want[list(SPOTS)], rtol=0.1)


def test_process_setup_json(tmp_path, frames):
    cam = optitact.optics.camera.FisheyeCamera(width=160, height=120, fov_deg=150.0)
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"sensor": SENSOR.to_dict(), "camera": cam.to_dict()}))
    np.save(tmp_path / "s.npy", frames)
    out = tmp_path / "r.csv"
    assert main(["process", str(tmp_path / "s.npy"), "--out", str(out), "--setup",
                 str(setup)]) == 0
    g, _, _ = table(read_csv(out), 3)
    want = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, cam, baseline=frames[0]).process(frames)
    np.testing.assert_allclose(g, want.G, rtol=1e-8, atol=0)


@pytest.mark.parametrize("case, match", [
    ("missing", "frames not found"),
    ("empty_folder", "holds no frames"),
    ("unknown_type", "unknown frame file type"),
    ("sizes", "expected a 120x160 frame"),
    ("short", "before the 4 baseline frames"),
    ("bad_setup", "expected a JSON object with 'sensor' and 'camera'"),
    ("bad_option", "filter_size"),
    ("broken_png", "OpenCV cannot read this image"),
])
def test_process_errors_exit_2(tmp_path, frames, capsys, case, match):
    cv2.imwrite(str(tmp_path / "a.png"), frames[0])
    args = [str(tmp_path / "a.png")]
    extra: list[str] = []
    if case == "missing":
        args = [str(tmp_path / "nope")]
    elif case == "empty_folder":
        (tmp_path / "empty").mkdir()
        args = [str(tmp_path / "empty")]
    elif case == "unknown_type":
        (tmp_path / "a.xyz").write_text("")
        args = [str(tmp_path / "a.xyz")]
    elif case == "sizes":
        cv2.imwrite(str(tmp_path / "b.png"), np.zeros((20, 30), np.uint8))
        args += [str(tmp_path / "b.png")]
    elif case == "short":
        extra = ["--baseline-frames", "4"]
    elif case == "bad_setup":
        (tmp_path / "s.json").write_text("[1, 2]")
        extra = ["--setup", str(tmp_path / "s.json")]
    elif case == "bad_option":
        extra = ["--filter", "median", "--filter-size", "2.5"]
    elif case == "broken_png":
        (tmp_path / "c.png").write_bytes(b"not a png")
        args = [str(tmp_path / "c.png")]
    assert main(["process", *args, "--out", str(tmp_path / "r.csv"), *extra]) == 2
    err = capsys.readouterr().err
    assert "optitact: error:" in err and match in err


def test_process_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["process", "--help"])
    assert e.value.code == 0
    assert "--baseline-frames" in capsys.readouterr().out


def test_bench_pipeline_json(capsys):
    assert main(["bench", "pipeline", "--size", "80x60", "--loads", "1", "41", "--frames", "2",
                 "--repeats", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    size = out["80x60"]
    assert out["cores"] >= 1 and out["kernel"] in ("numba", "numpy") and out["warm_passes"] >= 1
    assert set(size["loads"]) == {"1", "41"} and set(out["table"]["80x60"]) == {"1", "41"}
    for n, row in size["loads"].items():
        for key in ("fast", "fast_after_flush", "numpy", "floor", "batch_1thread", "batch_threads",
                    "floor_1thread", "floor_threads", "reference"):
            assert row[f"{key}_us"] > 0 and row[f"{key}_cpu_us"] >= 0
        assert row["fast_over_floor"] > 0 and row["threads_speedup"] > 0 and row["speedup"] > 0
        assert row["fast_after_flush_over_floor"] > 0
        # exactness: the fast path against the reference, and the NumPy fallback bit for bit
        assert row["max_G_rel_diff"] < 1e-9 and row["max_u_diff_mm"] < 1e-9
        assert row["flags_identical"] and row["kernels_identical"]
        assert row["elements_in_contact"] >= (1 if n == "1" else 20)
        assert out["table"]["80x60"][n] == row["fast_over_floor"]
    assert size["precompute_cached_s"] > 0 and size["startup_to_first_frame_s"] > 0


def test_bench_process_json(capsys):
    """End to end: process on a cached recording against decoding it, side by side in fresh processes."""
    import cv2

    from optitact.studies.bench_process import NOLOAD_FRAMES, recording

    assert main(["bench", "process", "--size", "96x72", "--frames", "8", "--repeats", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    row = out["rows"]["96x72-MJPG"]
    assert row["calibration"] is None and row["frames"] == 8
    assert row["table_rows"] == 8 * 41  # process read every frame of the recording, every element
    for name in ("process", "decode", "decode_tuned"):
        assert row[f"{name}_wall_s"] > 0 and row[f"{name}_cpu_s"] > 0
    for key in ("wall_vs_decode", "cpu_vs_decode", "wall_vs_decode_tuned", "cpu_vs_decode_tuned"):
        assert row[key] > 0
    # the recording is kept: the same file, no-load frames first, then all elements lit
    video = recording(96, 72, "MJPG", frames=8, seed=0)
    cap = cv2.VideoCapture(str(video))
    grey = []
    while (got := cap.read())[0]:
        grey.append(cv2.cvtColor(got[1], cv2.COLOR_BGR2GRAY).astype(float))
    assert len(grey) == 8
    lit = [float(np.mean(g)) for g in grey]
    assert max(lit[:NOLOAD_FRAMES]) < min(lit[NOLOAD_FRAMES:])


def test_bench_pipeline_bad_size(capsys):
    assert main(["bench", "pipeline", "--size", "640by480"]) == 2
    assert "--size must look like 640x480" in capsys.readouterr().err


def test_process_files_from_python_equals_the_command(tmp_path, frames, capsys):
    """optitact.pipeline.batch.process_files: the engine behind optitact process, callable from Python."""
    from optitact.pipeline.batch import process_files

    np.save(tmp_path / "a.npy", frames)
    cv2.imwrite(str(tmp_path / "b.png"), frames[2])
    sources = [tmp_path / "a.npy", tmp_path / "b.png"]
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    got = process_files(sources, pipeline=pipe, batch=2)
    want = Pipeline(SENSOR, CAM, baseline=frames[0]).process(np.concatenate([frames, frames[2:]]))
    assert got.n_frames == 4 and got.readings.G.shape == (4, 41)
    assert got.sources[-1].endswith("b.png") and got.forces is None
    np.testing.assert_allclose(got.readings.G, want.G, rtol=1e-8, atol=0)
    np.testing.assert_array_equal(got.last_frame, frames[2])
    np.testing.assert_array_equal(got.last_readings.G, got.readings.G[-1])
    # written to a CSV: the same table as the command's, whatever the batch size
    out = tmp_path / "py.csv"
    assert process_files(sources, pipeline=pipe, out=out, batch=3).readings is None
    assert main(["process", *map(str, sources), "--out", str(tmp_path / "cli.csv"), "--fov", "140"]) == 0
    assert out.read_text() == (tmp_path / "cli.csv").read_text()
    # a given baseline replaces the first-frames one; baseline_frames=0 subtracts nothing
    given = process_files(sources, pipeline=pipe, baseline=frames[1])
    np.testing.assert_allclose(given.readings.G[2], pipe.with_baseline(frames[1]).process(frames[2]).G,
                               rtol=1e-12, atol=0)
    raw = process_files(sources, pipeline=pipe, baseline_frames=0)
    np.testing.assert_array_equal(raw.readings.G, pipe.process(np.concatenate([frames, frames[2:]])).G)


def test_process_files_errors_leave_no_file(tmp_path, frames):
    from optitact.pipeline.batch import process_files

    np.save(tmp_path / "a.npy", frames[:2])
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    out = tmp_path / "r.csv"
    with pytest.raises(ValueError, match="stream ended after 2 frames, before the 3 baseline frames"):
        process_files([tmp_path / "a.npy"], pipeline=pipe, baseline_frames=3, out=out)
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((20, 30), np.uint8))
    with pytest.raises(ValueError, match="small.png: expected a 120x160 frame"):
        process_files([tmp_path / "a.npy", tmp_path / "small.png"], pipeline=pipe, out=out)
    assert not out.exists() and not list(tmp_path.glob(".*tmp*"))
    with pytest.raises(TypeError, match="needs a pipeline or a calibration"):
        process_files([tmp_path / "a.npy"])
    with pytest.raises(TypeError, match="pipeline must be a Pipeline, got str"):
        process_files([tmp_path / "a.npy"], pipeline="fast")


def test_a_frame_file_of_text_is_bad_input_not_a_bug(tmp_path, capsys):
    """A .npy of strings is the user's bad data: one line and exit 2 (a TypeError subclass), no traceback."""
    np.save(tmp_path / "words.npy", np.full((120, 160), "a"))
    assert main(["process", str(tmp_path / "words.npy"), "--out", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("optitact: error:") and "dtype" in last
    assert not (tmp_path / "r.csv").exists()


# ----------------------------------------------------------------------------- issue 17
@pytest.fixture(scope="module")
def small_cal(tmp_path_factory):
    """The shipped calibration's curves for this module's 160x120 camera and the default pipeline (quick)."""
    from optitact.calib.document import fingerprint
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import DEFAULT_CALIBRATION

    shipped = json.loads(DEFAULT_CALIBRATION.read_text())
    shipped.update(camera=CAM.to_dict(), pipeline={}, fingerprint=fingerprint(SENSOR, CAM, {}))
    cal = Calibration.from_dict(shipped)
    return cal, cal.save(tmp_path_factory.mktemp("cal") / "cal.json")


def test_process_with_a_calibration_writes_global_forces_and_a_per_frame_table(tmp_path, frames, small_cal):
    """Forces where users need them: global columns per element, resultant and centre of pressure per frame."""

    cal, path = small_cal
    np.save(tmp_path / "s.npy", frames)
    out = tmp_path / "f.csv"
    assert main(["process", str(tmp_path / "s.npy"), "--calibration", str(path), "--out", str(out)]) == 0
    rows = read_csv(out)
    assert list(rows[0]) == ["frame", "source", "element", "G", "ux", "uy", "contact", "saturated", "fx", "fy",
                             "fz", "fx_global", "fy_global", "fz_global", "clamped"]
    assert len(rows) == 3 * 41
    per_frame = read_csv(tmp_path / "f.per_frame.csv")
    assert list(per_frame[0]) == ["frame", "source", "n_contact", "n_clamped", "total_normal", "resultant_x",
                                  "resultant_y", "resultant_z", "centre_of_pressure_x", "centre_of_pressure_y",
                                  "centre_of_pressure_z"]
    assert [r["source"] for r in per_frame] == ["s.npy#0", "s.npy#1", "s.npy#2"]
    # the truth: ForceField of the calibration's own estimate, frame by frame
    fields = cal.apply(cal.pipeline(baseline=frames[0]).process(frames))
    col = lambda name: np.array([float(r[name]) for r in rows]).reshape(3, 41)  # noqa: E731
    for t, ff in enumerate(fields):
        np.testing.assert_allclose(np.stack([col(k)[t] for k in ("fx", "fy", "fz")], -1), ff.local,
                                   rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(np.stack([col(k)[t] for k in ("fx_global", "fy_global", "fz_global")], -1),
                                   ff.global_forces, rtol=1e-9, atol=1e-12)
        row = per_frame[t]
        assert int(row["n_contact"]) == ff.n_contact and int(row["n_clamped"]) == int(ff.clamped.sum())
        np.testing.assert_allclose(float(row["total_normal"]), ff.total_normal, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose([float(row[f"resultant_{a}"]) for a in "xyz"], ff.resultant,
                                   rtol=1e-9, atol=1e-12)
        cop = [row[f"centre_of_pressure_{a}"] for a in "xyz"]
        if ff.centre_of_pressure is None:
            assert cop == ["", "", ""]
        else:
            np.testing.assert_allclose([float(v) for v in cop], ff.centre_of_pressure, rtol=1e-9, atol=1e-9)
    assert per_frame[0]["centre_of_pressure_x"] == "" and fields[2].n_contact > 0  # baseline frame: no contact
    # from Python, in memory: the same numbers
    from optitact.pipeline.batch import process_files

    got = process_files([tmp_path / "s.npy"], calibration=cal)
    np.testing.assert_allclose(got.resultant, [ff.resultant for ff in fields], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.global_forces, [ff.global_forces for ff in fields], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.total_normal, [ff.total_normal for ff in fields], rtol=1e-9, atol=1e-12)
    assert np.isnan(got.centre_of_pressure[0]).all()
    np.testing.assert_allclose(got.centre_of_pressure[2], fields[2].centre_of_pressure, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("n_frames, extra", [(1, []), (3, ["--baseline-frames", "3"])])
def test_input_that_is_all_baseline_is_an_error(tmp_path, frames, small_cal, capsys, n_frames, extra):
    """One loaded frame (or N frames with --baseline-frames N) would become its own baseline: zero forces."""
    _, cal_path = small_cal
    np.save(tmp_path / "s.npy", frames[-n_frames:])
    out = tmp_path / "f.csv"
    assert main(["process", str(tmp_path / "s.npy"), "--calibration", str(cal_path), "--out", str(out),
                 *extra]) == 2
    err = capsys.readouterr().err
    assert f"all {n_frames} frame(s) of the input would become the no-load baseline" in err
    assert "--baseline" in err and "--baseline-frames 0" in err
    assert not out.exists() and not list(tmp_path.glob("*.partial*")) and not list(tmp_path.glob(".*"))
    # with a baseline, or baseline_frames=0 stated, the same frames are measured
    np.save(tmp_path / "base.npy", frames[0])
    assert main(["process", str(tmp_path / "s.npy"), "--calibration", str(cal_path), "--out", str(out),
                 "--baseline", str(tmp_path / "base.npy")]) == 0
    fz = np.array([float(r["fz"]) for r in read_csv(out)]).reshape(n_frames, 41)
    assert (fz[-1, list(SPOTS)] > 0).all()
    assert main(["process", str(tmp_path / "s.npy"), "--out", str(out), "--baseline-frames", "0"]) == 0


def test_a_nan_frame_is_named_by_its_file_and_index(tmp_path, frames):
    """Per-frame errors name the file and the frame's index within it, not its place in a batch."""
    from optitact.pipeline.batch import process_files

    np.save(tmp_path / "a.npy", frames.astype(np.float32))
    bad = np.repeat(frames[1:2].astype(np.float32), 60, axis=0)
    bad[50, 7, 9] = np.nan
    np.save(tmp_path / "b.npy", bad)
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)
    with pytest.raises(InputError, match=r"^b\.npy, frame 50: the frame must be finite, got nan at pixel "
                                         r"\(row 7, col 9\)$"):
        process_files([tmp_path / "a.npy", tmp_path / "b.npy"], pipeline=pipe, batch=32)
    bad[50, 7, 9] = 0.0
    np.save(tmp_path / "b.npy", bad)
    np.save(tmp_path / "c.npy", np.zeros((2, 60, 80), np.float32))  # wrong size, second frame of its file
    with pytest.raises(InputError, match=r"^c\.npy, frame 0: expected a 120x160 frame"):
        process_files([tmp_path / "a.npy", tmp_path / "b.npy", tmp_path / "c.npy"], pipeline=pipe)
    # a NaN in the baseline frames is named too
    with pytest.raises(InputError, match=r"^b\.npy, frame 50: the frame must be finite"):
        bad[50, 7, 9] = np.inf
        np.save(tmp_path / "b.npy", bad)
        process_files([tmp_path / "b.npy"], pipeline=pipe, baseline_frames=52)


@pytest.mark.parametrize("case", ["folder", "missing_folder", "plot_folder"])
def test_out_is_checked_before_any_work(tmp_path, frames, capsys, monkeypatch, case):
    """--out naming a folder, or in a folder that does not exist, fails at once (nothing is read)."""
    import optitact.io.frames as frames_module

    cv2.imwrite(str(tmp_path / "a.png"), frames[0])
    cv2.imwrite(str(tmp_path / "b.png"), frames[2])
    read = []
    real = frames_module.iter_frames
    monkeypatch.setattr(frames_module, "iter_frames", lambda files: read.append(files) or real(files))
    out, extra = tmp_path / "r.csv", []
    if case == "folder":
        out = tmp_path / "results"
        out.mkdir()
    elif case == "missing_folder":
        out = tmp_path / "nope" / "r.csv"
    else:
        (tmp_path / "plots").mkdir()
        extra = ["--calibration", "default", "--plot", str(tmp_path / "plots")]
    assert main(["process", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    want = {"folder": f"--out {out} is a folder; expected the name of a file",
            "missing_folder": f"the folder {out.parent} does not exist",
            "plot_folder": "--plot " + str(tmp_path / "plots") + " is a folder"}[case]
    assert err.startswith("optitact: error:") and want in err and len(err.splitlines()) == 1
    assert read == [] and not (tmp_path / "nope").exists()
    from optitact.pipeline.batch import process_files

    if case == "folder":
        with pytest.raises(InputError, match="out: .* is a folder"):
            process_files([tmp_path / "a.png", tmp_path / "b.png"], pipeline=Pipeline(SENSOR, CAM),
                          out=out)


def test_the_progress_bar_appears_once_the_work_has_taken_its_delay(capsys):
    """Work shorter than the delay shows no bar (tqdm is not even made); longer work gets tqdm's bar,
    counting the frames done since the start."""
    import time

    from optitact.pipeline.batch import _Progress

    with _Progress(10, desc="process", delay=60.0) as bar:
        bar.update(10)
    assert capsys.readouterr().err == "" and bar._bar is None
    with _Progress(10, desc="process", delay=0.02) as bar:
        bar.update(4)  # before the delay: counted, not shown
        time.sleep(0.03)
        for _ in range(3):
            bar.update(2)
    err = capsys.readouterr().err
    assert "process: 100%" in err and "10/10" in err and bar.n == 10


def test_a_warning_is_one_line_with_or_without_a_progress_bar(capsys, monkeypatch):
    """Without tqdm loaded the warning is printed as it is (tqdm is not imported for it); with tqdm
    loaded it goes through tqdm.write, which keeps it clear of a bar."""
    import sys

    from optitact.cli import _one_line

    monkeypatch.delitem(sys.modules, "tqdm", raising=False)
    _one_line("lossy codec", UserWarning, "f.py", 1)
    assert capsys.readouterr().err == "optitact: warning: lossy codec\n" and "tqdm" not in sys.modules
    monkeypatch.undo()
    import tqdm

    written = []
    monkeypatch.setattr(tqdm.tqdm, "write", classmethod(lambda cls, s, file=None: written.append(s)))
    _one_line("lossy codec", UserWarning, "f.py", 1)
    assert written == ["optitact: warning: lossy codec"]
