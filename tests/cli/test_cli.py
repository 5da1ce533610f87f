"""CLI and forces-file tests (tiny renders)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

import optitact
from optitact.cli import main
from optitact.io.tables import read_forces_csv, write_forces_csv
from optitact.optics.loads import indenter_load

SENSOR = optitact.optics.sensor.DomeSensor.default()
TINY = ["--spp", "2", "--width", "64", "--height", "48"]


def forces_file(tmp_path, text, name="f.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_forces_csv_round_trip(tmp_path):
    f = np.random.default_rng(0).normal(size=(41, 3))
    write_forces_csv(tmp_path / "f.csv", f)
    np.testing.assert_array_equal(read_forces_csv(tmp_path / "f.csv", 41), f)


def test_forces_csv_three_columns_comments_and_header(tmp_path):
    rows = "\n".join(f"{i * 0.01},0,{i * 0.1}" for i in range(41))
    p = forces_file(tmp_path, "# a comment\nfx,fy,fz\n\n" + rows + "\n")
    f = read_forces_csv(p, 41)
    np.testing.assert_allclose(f[:, 2], 0.1 * np.arange(41), rtol=0, atol=1e-12)


@pytest.mark.parametrize("text,exc,match", [
    ("fx,fy,fz\n" + "0,0,1\n" * 40, ValueError, "expected 41 rows .* got 40"),
    ("0,0\n" * 41, ValueError, "expected 3 columns"),
    ("0,0,1\n" * 20 + "0,abc,1\n" + "0,0,1\n" * 20, ValueError, r"line 21, column 2: 'abc' is not a number"),
    ("0,0,1\n" * 40 + "0,0,nan\n", ValueError, "is not finite"),
    ("0,0,1\n" * 40 + "0,0\n", ValueError, "line 41: expected 3 columns, got 2"),
    ("".join(f"{i + 1},0,0,1\n" for i in range(41)), ValueError, "element column must read 0"),
    ("", ValueError, "got none"),
])
def test_forces_csv_errors(tmp_path, text, exc, match):
    with pytest.raises(exc, match=match):
        read_forces_csv(forces_file(tmp_path, text), 41)


def test_render_command_writes_frame(tmp_path):
    f = np.zeros((41, 3))
    f[0, 2] = 1.0
    write_forces_csv(tmp_path / "f.csv", f)
    out = tmp_path / "frame.png"
    rad = tmp_path / "rad.npy"
    code = main(["render", "--forces", str(tmp_path / "f.csv"), "--out", str(out),
                 "--radiance", str(rad), "--bits", "12", *TINY])
    assert code == 0
    frame = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (48, 64) and frame.dtype == np.uint16
    assert frame.max() <= 4095
    assert np.load(rad).shape == (48, 64)


@pytest.mark.parametrize("text,match", [
    (None, "forces file not found"),
    ("0,0,1\n" * 3, "expected 41 rows"),
    ("0,x,1\n" * 41, "'x' is not a number"),
])
def test_render_command_bad_forces_file_exit_2(tmp_path, capsys, text, match):
    path = tmp_path / "f.csv" if text is None else forces_file(tmp_path, text)
    code = main(["render", "--forces", str(path), "--out", str(tmp_path / "o.png"), *TINY])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("optitact: error: ")
    assert match in err[0]
    assert not (tmp_path / "o.png").exists()


def test_demo_writes_its_folder(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), *TINY]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    meta = json.loads((out / "forces.json").read_text())
    np.testing.assert_allclose(np.array(meta["forces_local_n"]), indenter_load(SENSOR),
                               rtol=0, atol=1e-12)
    assert meta["variant"] in ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
    assert meta["spp"] == 2 and meta["seed"] == 0
    frame = cv2.imread(str(out / "frame.png"), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (48, 64) and frame.dtype == np.uint8
    assert cv2.imread(str(out / "frame_view.png"), cv2.IMREAD_UNCHANGED).shape == (48, 64)
    overlay = cv2.imread(str(out / "overlay.png"))
    assert overlay.shape[1] >= 560 and overlay.shape[0] > 48 * overlay.shape[1] // 64  # enlarged, with bands


@pytest.mark.parametrize("argv", [["--help"], ["demo", "--help"], ["render", "--help"],
                                  ["calibrate", "generate", "--help"], ["calibrate", "fit", "--help"],
                                  ["bench", "accuracy", "--help"], ["bench", "pipeline", "--help"]])
def test_help(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    assert "usage: optitact" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["demo", "--spp", "0"], ["demo", "--seed", "-1"],
                                  ["render", "--out", "x.png"], ["frobnicate"]])
def test_bad_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2


def test_console_script_is_installed():
    r = subprocess.run([sys.executable, "-m", "optitact.cli", "--version"], capture_output=True,
                       text=True, check=True)
    assert r.stdout.strip() == f"optitact {optitact.__version__}"


def test_import_is_light_and_top_level_names_are_not_installed(tmp_path):
    code = (
        "import sys, optitact\n"
        "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n"
        "import optitact.render, optitact.calib, optitact.forces\n"
        "assert 'mitsuba' not in sys.modules\n"
        "for name in ('render', 'calib', 'forces'):\n"
        "    try:\n"
        "        __import__(name)\n"
        "    except ModuleNotFoundError:\n"
        "        pass\n"
        "    else:\n"
        "        raise SystemExit(f'{name} is importable at top level')\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp_path)


def test_indenter_load_is_centred_and_friction_limited():
    f = indenter_load(SENSOR, polar_deg=0.0, peak=0.5, shear_ratio=0.3)
    assert f[0, 2] == pytest.approx(0.5, abs=1e-12)
    assert np.all(f[:, 2] >= 0)
    t = np.hypot(f[:, 0], f[:, 1])
    np.testing.assert_allclose(t, 0.3 * f[:, 2], rtol=0, atol=1e-12)


def test_bench_render_json(capsys, tmp_path):
    plot = tmp_path / "pareto.png"
    assert main(["bench", "render", "--spp", "1", "4", "--reference-spp", "8", "--width", "64",
                 "--height", "48", "--cases", "1-heavy", "41", "--modes", "brute", "pixels", "adaptive",
                 "--targets", "0.3", "--plot", str(plot)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["size"] == "64x48" and out["reference_spp"] == 8
    assert len(out["rows"]) == 2 * (2 * 2 + 1)  # cases x (2 modes x 2 spp + adaptive x 1 target)
    for row in out["rows"]:
        assert row["seconds"] > 0 and row["g_rel_error"] >= 0 and row["u_error_mm"] >= 0
        assert "force_error_pct_fs" not in row  # the shipped calibration is for 640x480
    for case in ("1-heavy", "41"):
        errs = {r["setting"]: r["g_rel_error"] for r in out["rows"]
                if r["case"] == case and r["mode"] == "pixels"}
        assert errs[4] < errs[1]  # more samples, less error against the reference
        assert out["pareto"][case]
    head = out["headline"]
    assert head["case"] == "41" and head["speedup_at_equal_error"] > 0
    assert head["calibration_frame_s"] > 0 and cv2.imread(str(plot)) is not None


def test_bench_render_bad_case(capsys):
    assert main(["bench", "render", "--cases", "7-medium", "--width", "48", "--height", "36"]) == 2
    assert "unknown case" in capsys.readouterr().err


def test_a_bug_shows_its_traceback(monkeypatch, tmp_path):
    """Only bad input is a one-line error with exit 2; a TypeError from a bug propagates."""
    import optitact.cli.demo as demo

    def buggy(args):
        return len(None)  # TypeError: a programming error, not bad input

    monkeypatch.setattr(demo, "run_render", buggy)
    with pytest.raises(TypeError, match="NoneType"):
        main(["render", "--forces", str(tmp_path / "f.csv"), "--out", str(tmp_path / "x.png")])


@pytest.mark.parametrize("exc, code", [("input", 2), ("shape", 2), ("missing", 2), ("oserror", 2)])
def test_bad_input_is_one_line_exit_2(monkeypatch, tmp_path, capsys, exc, code):
    import optitact.cli.demo as demo
    from optitact.errors import InputError, MissingExtraError, ShapeError

    errors = {"input": InputError("forces must be finite"), "shape": ShapeError("expected 41 rows"),
              "missing": MissingExtraError("mitsuba is needed for rendering: pip install 'optitact[render]'"),
              "oserror": FileNotFoundError("forces file not found: f.csv")}

    def bad(args):
        raise errors[exc]

    monkeypatch.setattr(demo, "run_render", bad)
    assert main(["render", "--forces", "f.csv", "--out", str(tmp_path / "x.png")]) == code
    err = capsys.readouterr().err
    assert err.startswith("optitact: error: ") and err.count("\n") == 1 and "Traceback" not in err


@pytest.fixture
def fake_study(monkeypatch, tmp_path):
    """A tiny study registered under the name "fake" (the real ones are not needed here)."""
    import types

    from optitact.studies import _protocol
    from optitact.studies._protocol import Study

    def run(seed, *, full, progress):
        return {"value": seed + (10 if full else 1), "series": np.arange(3)}

    def draw(fig, result):
        fig.subplots().plot(result["series"])

    module = types.ModuleType("fake_study_for_tests")
    module.STUDY = Study(name="fake", summary="a test study", run=run, draw=draw,
                         published={"value": 42, "reference": "nobody (2024)"}, figsize=(3, 2))
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(_protocol, "_REGISTRY", {**_protocol._REGISTRY, "fake": module.__name__})
    monkeypatch.setenv("OPTITACT_CACHE_DIR", str(tmp_path / "cache"))
    return module


def test_experiment_runs_a_registered_study(fake_study, capsys, tmp_path):
    assert main(["experiment", "fake", "--seed", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["value"] == 4 and out["size"] == "quick" and out["seed"] == 3
    assert out["published"]["value"] == 42
    plot = tmp_path / "fake.png"
    assert main(["experiment", "fake", "--full", "--plot", str(plot), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["value"] == 10 and out["size"] == "full" and out["plot"] == str(plot)
    assert cv2.imread(str(plot)) is not None


def test_experiment_names_come_from_the_registry(fake_study, capsys):
    with pytest.raises(SystemExit):
        main(["experiment", "--help"])
    assert "fake" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["experiment", "nonesuch"])
    assert e.value.code == 2


def test_bench_stability_calls_the_noise_sweep_study(monkeypatch, capsys):
    import types

    calls = {}

    def bench_stability(*, cases, seed, progress):
        calls.update(cases=cases, seed=seed, progress=progress)
        return {"cases": cases, "failures": 0}

    module = types.ModuleType("optitact.studies.bench_stability")
    module.bench_stability = bench_stability
    monkeypatch.setitem(sys.modules, "optitact.studies.bench_stability", module)
    import optitact.studies

    monkeypatch.setattr(optitact.studies, "bench_stability", module, raising=False)
    assert main(["bench", "stability", "--cases", "12", "--seed", "5"]) == 0
    assert json.loads(capsys.readouterr().out) == {"cases": 12, "failures": 0}
    assert calls == {"cases": 12, "seed": 5, "progress": True}
    assert main(["bench", "stability", "--cases", "3", "--json"]) == 0  # --json says what it prints anyway
    assert json.loads(capsys.readouterr().out) == {"cases": 3, "failures": 0}


def test_core_works_without_the_extras(tmp_path):
    """import optitact, the pipeline, JSON calibrations, forces, batch and the CLI need none of the extras;
    a plot without matplotlib is a one-line error naming the extra."""
    code = (
        "import sys\n"
        "for m in ('matplotlib', 'zarr', 'dask', 'distributed', 'mitsuba', 'drjit', 'sklearn',\n"
        "          'dtaidistance'):\n"
        "    sys.modules[m] = None\n"
        "import numpy as np, optitact, optitact.pipeline.frame_pipeline, optitact.calib, optitact.forces\n"
        "import optitact.pipeline.batch\n"
        "import optitact.cli, optitact.render\n"
        "cal = optitact.calib.shipped.default_calibration()\n"
        "r = cal.pipeline().process(np.zeros(cal.camera.shape, np.uint8))\n"
        "field = cal.apply(r)\n"
        "assert field.local.shape == (41, 3)\n"
        "try:\n"
        "    field.save_plot('x.png', np.zeros(cal.camera.shape), cal.camera)\n"
        "except optitact.errors.MissingExtraError as e:\n"
        "    assert \"pip install 'optitact[plot]'\" in str(e), e\n"
        "else:\n"
        "    raise SystemExit('plotted without matplotlib')\n"
        "assert optitact.cli.main(['render', '--forces', 'none.csv', '--out', 'x.png']) == 2\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp_path)


def test_demo_renders_and_processes_a_setup(tmp_path, capsys):
    """demo --setup: the setup's camera (an off-axis OpenCV fisheye, its own 64x48 size) and as-built sensor
    are rendered (path-traced) and read with the shipped calibration transferred to them."""
    from optitact.optics.camera_models import OpenCVFisheyeCamera

    f0 = 24 / np.deg2rad(70)
    cam = OpenCVFisheyeCamera(64, 48, fx=f0, fy=f0, cx=32.0, cy=23.0, dist=(0.01, 0, 0, 0), tvec=(0.1, 0, 5.0))
    sensor = optitact.optics.sensor.DomeSensor(element_gain=np.linspace(0.9, 1.1, 41))
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"sensor": sensor.to_dict(), "camera": cam.to_dict()}))
    out = tmp_path / "demo"
    assert main(["demo", "--setup", str(setup), "--out", str(out), "--spp", "2"]) == 0
    err = capsys.readouterr().err
    assert "the shipped calibration is transferred to the setup's sensor and camera" in err
    meta = json.loads((out / "forces.json").read_text())
    assert optitact.optics.camera.camera_from_dict(meta["camera"]) == cam and meta["sensor"] == sensor.to_dict()
    assert cv2.imread(str(out / "frame.png"), cv2.IMREAD_UNCHANGED).shape == (48, 64)
    assert np.array(meta["estimated_forces_local_n"]).shape == (41, 3)
    assert main(["demo", "--setup", str(setup), "--out", str(out), "--width", "32", "--height", "24"]) == 2
    assert "the setup's camera" in capsys.readouterr().err
