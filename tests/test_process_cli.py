"""``optitact process`` (frames -> readings CSV) and ``optitact bench pipeline``."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

import optitact
from optitact.cli import main
from optitact.frames import count_frames, expand_sources, iter_frames

SENSOR = optitact.DomeSensor.default()
CAM = optitact.FisheyeCamera(width=160, height=120)
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
    want = optitact.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames)
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
    want = optitact.Pipeline(SENSOR, CAM, baseline=frames[1:]).process(frames[1:])
    np.testing.assert_allclose(g, want.G, rtol=1e-8, atol=0)
    out16 = tmp_path / "r16.csv"
    assert main(["process", str(wide), "--out", str(out16), "--baseline", str(base),
                 "--noise-sigma", str(0.5 * 256)]) == 0
    rows = read_csv(out16)
    assert rows[0]["source"] == "f16.png"
    g16, _, _ = table(rows, 1)
    ref = optitact.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[2])
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
    names = [n for n, _ in iter_frames(files)]
    assert names == ["clip.avi#0", "clip.avi#1", "clip.avi#2"]
    out = tmp_path / "r.csv"
    assert main(["process", str(path), "--out", str(out)]) == 0
    g, _, contact = table(read_csv(out), 3)
    assert not contact[0].any()
    assert set(np.flatnonzero(contact[2])) == set(SPOTS)  # JPEG-compressed, same spots
    want = optitact.Pipeline(SENSOR, CAM, baseline=frames[0]).process(frames[2]).G
    np.testing.assert_allclose(g[2][list(SPOTS)], want[list(SPOTS)], rtol=0.1)


def test_process_setup_json(tmp_path, frames):
    cam = optitact.FisheyeCamera(width=160, height=120, fov_deg=150.0)
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"sensor": SENSOR.to_dict(), "camera": cam.to_dict()}))
    np.save(tmp_path / "s.npy", frames)
    out = tmp_path / "r.csv"
    assert main(["process", str(tmp_path / "s.npy"), "--out", str(out), "--setup",
                 str(setup)]) == 0
    g, _, _ = table(read_csv(out), 3)
    want = optitact.Pipeline(SENSOR, cam, baseline=frames[0]).process(frames)
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
    assert main(["bench", "pipeline", "--size", "80x60", "--frames", "2", "--repeats", "1",
                 "--spp", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    row = out["80x60"]
    assert out["cores"] >= 1
    for key in ("fast_fps", "batch_fps", "reference_fps", "floor_fps", "speedup"):
        assert row[key] > 0
    assert row["max_G_rel_diff"] < 1e-9 and row["max_u_diff_mm"] < 1e-9
    assert row["flags_identical"] and row["elements_in_contact"] > 0


def test_bench_pipeline_bad_size(capsys):
    assert main(["bench", "pipeline", "--size", "640by480"]) == 2
    assert "--size must look like 640x480" in capsys.readouterr().err


def test_process_files_from_python_equals_the_command(tmp_path, frames, capsys):
    """optitact.batch.process_files: the engine behind optitact process, callable from Python."""
    from optitact.batch import process_files

    np.save(tmp_path / "a.npy", frames)
    cv2.imwrite(str(tmp_path / "b.png"), frames[2])
    sources = [tmp_path / "a.npy", tmp_path / "b.png"]
    pipe = optitact.Pipeline(SENSOR, CAM)
    got = process_files(sources, pipeline=pipe, batch=2)
    want = optitact.Pipeline(SENSOR, CAM, baseline=frames[0]).process(np.concatenate([frames, frames[2:]]))
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
    from optitact.batch import process_files

    np.save(tmp_path / "a.npy", frames[:2])
    pipe = optitact.Pipeline(SENSOR, CAM)
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
