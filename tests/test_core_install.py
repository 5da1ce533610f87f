"""The core install: frames -> readings -> forces with NumPy, SciPy and OpenCV alone.

``pip install optitact`` (no extras) must turn a camera frame into forces with
the shipped calibration, from Python and from ``optitact process``. Here the
optional dependencies are made unimportable in a fresh interpreter (an import
hook that raises ``ModuleNotFoundError`` for them, as a missing package does),
and the frame is an analytic one: Gaussian spots drawn where the contact model
puts the apex element's cone patches, so no renderer is needed either.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

#: What the core must do without; each is an extra (optitact._optional.EXTRAS) or not used at all.
OPTIONAL = ("mitsuba", "drjit", "matplotlib", "zarr", "dask", "distributed", "sklearn", "dtaidistance",
            "skimage", "numba", "pyarrow", "pandas")

BLOCKER = textwrap.dedent(f"""
    import importlib.abc, sys
    class _Missing(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in {OPTIONAL!r}:
                raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
            return None
    sys.meta_path.insert(0, _Missing())
""")

FRAMES = textwrap.dedent("""
    import numpy as np, cv2
    import optitact
    sensor, camera = optitact.optics.sensor.DomeSensor.default(), optitact.optics.camera.FisheyeCamera()
    forces = np.zeros((41, 3))
    forces[0] = (0.0, 0.0, 0.6)
    contacts = optitact.optics.contact.contact_patches(sensor, forces)
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    rng = np.random.default_rng(0)
    base = np.clip(rng.normal(6.0, 0.4, (camera.height, camera.width)), 0, 255)
    spots = np.zeros_like(base)
    for (r, c) in camera.project(contacts.centers[0][contacts.in_contact[0]], sensor):
        spots += 120.0 * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * 1.5 ** 2))
    noload = np.round(base).astype(np.uint8)
    frame = np.round(np.clip(base + spots, 0, 255)).astype(np.uint8)
""")


def _run(code: str, tmp_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCKER + code], capture_output=True, text=True,
                          cwd=tmp_path)


def test_blocker_really_blocks(tmp_path):
    r = _run("import matplotlib", tmp_path)
    assert r.returncode != 0 and "No module named 'matplotlib'" in r.stderr


def test_frame_to_forces_in_python_without_extras(tmp_path):
    code = FRAMES + textwrap.dedent(f"""
        import json, sys
        from optitact.calib.shipped import default_calibration
        cal = default_calibration()
        field = cal.apply(cal.pipeline(baseline=noload).process(frame))
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in {OPTIONAL!r})
        print(json.dumps({{"fz": field.local[:, 2].tolist(), "heavy": heavy}}))
    """)
    r = _run(code, tmp_path)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    fz = out["fz"]
    assert out["heavy"] == []
    assert fz[0] > 0.05                       # the pressed element reads a normal force
    assert max(fz[1:]) == 0.0                 # and nothing else does


def test_process_cli_without_extras(tmp_path):
    code = FRAMES + textwrap.dedent("""
        cv2.imwrite("noload.png", noload)
        cv2.imwrite("frame.png", frame)
        from optitact.cli import main
        raise SystemExit(main(["process", "frame.png", "--baseline", "noload.png", "--calibration", "default",
                               "--out", "forces.csv"]))
    """)
    r = _run(code, tmp_path)
    assert r.returncode == 0, r.stderr
    rows = (tmp_path / "forces.csv").read_text().splitlines()
    header = rows[0].split(",")
    table = [dict(zip(header, line.split(","), strict=True)) for line in rows[1:]]
    assert len(table) == 41
    assert float(table[0]["fz"]) > 0.05 and all(float(t["fz"]) == 0.0 for t in table[1:])


def test_missing_extra_is_one_line_naming_it(tmp_path):
    code = textwrap.dedent("""
        from optitact._optional import require
        try:
            require("matplotlib.figure", purpose="plots")
        except ImportError as exc:
            print(type(exc).__name__, "|", exc)
    """)
    r = _run(code, tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == ("MissingExtraError | matplotlib is needed for plots but is not installed: "
                                "pip install 'optitact[plot]'")


@pytest.mark.parametrize("name", ["numpy.linalg"])
def test_require_imports_what_is_there(name):
    from optitact._optional import require

    assert require(name).__name__ == name


def test_the_library_never_imports_the_studies_layer(tmp_path):
    """Every library module (all but optitact.studies and the CLI that runs studies) imports without it."""
    code = textwrap.dedent("""
        import importlib, pkgutil, sys
        import optitact
        names = []

        def walk(pkg):  # pkgutil.walk_packages would import optitact.studies to look inside it
            for m in pkgutil.iter_modules(importlib.import_module(pkg).__path__, prefix=pkg + "."):
                if m.name.startswith(("optitact.studies", "optitact.cli")):
                    continue
                importlib.import_module(m.name)
                names.append(m.name)
                if m.ispkg:
                    walk(m.name)

        for pkg in ("optitact", "optitact.render", "optitact.calib", "optitact.forces"):
            walk(pkg)
        print(len(names), sorted(m for m in sys.modules if m.startswith("optitact.studies")))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    n, studies = r.stdout.split(" ", 1)
    assert int(n) > 30 and studies.strip() == "[]"


def test_the_command_line_loads_only_its_command(tmp_path):
    """import optitact loads no NumPy; optitact process imports neither the renderer's, the sets' nor the
    benchmarks' modules, and runs OpenBLAS on one thread unless the user set it."""
    code = textwrap.dedent("""
        import os, sys
        import optitact, optitact.cli
        assert "numpy" not in sys.modules, "import optitact loaded NumPy"
        try:
            optitact.cli.main(["process", "--help"])
        except SystemExit:
            pass
        loaded = sorted(m for m in sys.modules if m.startswith(("optitact.cli.", "optitact.studies", "mitsuba",
                                                                "zarr", "dask", "sklearn", "matplotlib")))
        from optitact.pipeline.frame_pipeline import Pipeline
        from optitact.registration.pose import register
        assert callable(register) and not isinstance(register, type(sys))
        print(loaded, os.environ.get("OPENBLAS_NUM_THREADS"))
    """)
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[-2] == "['optitact.cli._args', 'optitact.cli.process'] 1"
    env["OPENBLAS_NUM_THREADS"] = "2"  # the user's setting is kept
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert r.stdout.split("\n")[-2].endswith(" 2"), r.stderr
