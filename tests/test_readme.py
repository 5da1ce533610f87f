"""The README's code blocks run as written, in order, and say what is true.

Every fenced ``python`` block of README.md runs in one namespace, and the ``bash`` lines
that are cheap and safe run in a shell, all in document order in one temporary folder: a
reader pasting them one after another into one Python session and a shell in the same
folder. Two kinds of edits make it quick, both visible here and nowhere else:

- ``QUICK``: the named size constants a block defines on its first lines (``SIZE, SPP =
  ...``) get small values. The calibration set is path-traced (``RENDER_MODE =
  "pixels"``): the default two-stage transport would first measure the light-transport
  table of the small test camera (tens of minutes).
- ``SKIPPED``: bash lines not run (installs, the whole test suite, long renders), each with
  its reason. A bash line in neither ``SKIPPED`` nor ``RUN`` fails the test until it is
  classified.

Then the values the blocks left behind are checked against known truths. The study block
reuses the quick tracing result the taxel tests cached earlier in the session.
"""

from __future__ import annotations

import csv
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"

#: Constant line of a README block -> the small value the test gives it.
QUICK = {
    "SIZE, SPP": '(160, 120), 16',
    "FRAMES, RENDER_MODE": '24, "pixels"',
}

#: Bash lines the test runs (after removing a trailing comment).
RUN = {
    "optitact process --help",
    "optitact process frames.npy --baseline noload.npy --out readings.csv",
    "optitact process frames.npy --baseline noload.npy --calibration dome41.json --out forces.csv",
    "optitact experiment tracing",
}

#: Bash lines the test does not run, and why.
SKIPPED = {
    "pip install -e '.[render,plot]' && optitact demo": "an install, then a 640x480 render at 64 spp",
    "pip install -e '.[test]' && pytest": "an install, then the whole test suite",
    "optitact calibrate generate --frames 200 --pattern blend --seed 0 --out dome41.zarr":
        "regenerates the shipped calibration's set (minutes)",
    "optitact calibrate generate --frames 60 --pattern blend --seed 900 --render-mode pixels --spp 256 "
    "--out val.zarr": "the shipped calibration's validation set (path-traced, minutes)",
    "optitact calibrate fit dome41.zarr --joint --validation val.zarr --out calib/data/dome41.json "
    "--plot fit.png": "overwrites the shipped calibration, from the sets above",
    "optitact experiment finger --full --plot finger.png": "the full finger study (minutes)",
    **{line: "the own-sensor workflow: tests/test_workflows.py runs these lines as typed, each a new "
             "process, on a rendered stand-in's files (a recording for --camera 0)" for line in (
        "optitact register noload.png reg_*.png --camera-intrinsics cam.yml --fit-offsets --out setup.json",
        "optitact process presses/ --setup setup.json --calibration default --out forces.csv",
        "optitact calibrate fit --frames presses/ --forces gauge.csv --setup setup.json --start default "
        "--out mysensor.json",
        "optitact calibrate test --frames held/ --forces held.csv --calibration default --setup setup.json",
        "optitact calibrate test --frames held/ --forces held.csv --calibration mysensor.json "
        "--plot errors.png",
        "optitact process --camera 0 --calibration mysensor.json --out live.csv")},
}

FENCE = re.compile(r"^(?P<indent> *)```(?P<lang>\w*)\s*$")


def blocks(text: str) -> list[tuple[str, int, str]]:
    """``(language, first line number, code)`` of every fenced block, indentation removed."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, body, start = len(m["indent"]), [], i + 1
        i += 1
        while not re.match(r"^ *```\s*$", lines[i]):
            body.append(lines[i][indent:])
            i += 1
        out.append((m["lang"], start + 1, "\n".join(body) + "\n"))
        i += 1
    return out


def shrink(code: str, used: set) -> str:
    """Give the ``QUICK`` constants defined in ``code`` their small values."""
    for names, value in QUICK.items():
        pattern = re.compile(rf"^{re.escape(names)} = .*$", re.M)
        if pattern.search(code):
            code = pattern.sub(f"{names} = {value}", code, count=1)
            used.add(names)
    return code


def bash_lines(code: str) -> list[str]:
    """The commands of a bash block, trailing comments removed."""
    return [ln.split("  #")[0].strip() for ln in code.splitlines() if ln.strip() and not ln.startswith("#")]


ALL = blocks(README.read_text(encoding="utf-8"))


def test_every_block_has_a_language_the_test_knows():
    """A block is python or bash (executed) or untagged (a synopsis); nothing else slips by."""
    assert {lang for lang, _, _ in ALL} <= {"python", "bash", ""}
    assert sum(lang == "python" for lang, _, _ in ALL) >= 6


def test_every_bash_line_is_classified():
    lines = [ln for lang, _, code in ALL if lang == "bash" for ln in bash_lines(code)]
    unknown = [ln for ln in lines if ln not in RUN and ln not in SKIPPED]
    assert not unknown, f"classify these README bash lines in RUN or SKIPPED: {unknown}"
    assert set(lines) == RUN | set(SKIPPED), "RUN/SKIPPED name lines the README no longer has"


def _shell(line: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    assert shutil.which("optitact", path=env["PATH"]), "the optitact command is not installed"
    return subprocess.run(["bash", "-c", line], cwd=cwd, env=env, capture_output=True, text=True)


def _csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.render
def test_readme_runs_top_to_bottom(tmp_path, monkeypatch):
    # find_spec, not importorskip: importing drjit here would pick its libLLVM before optitact.render does.
    if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("matplotlib") is None:
        pytest.skip("the README's examples need the render and plot extras")
    monkeypatch.chdir(tmp_path)
    ns: dict = {"__name__": "__readme__"}
    used: set = set()
    ran = []
    for lang, line, code in ALL:
        if lang == "python":
            exec(compile(shrink(code, used), f"README.md:{line}", "exec"), ns)  # noqa: S102
        elif lang == "bash":
            for cmd in bash_lines(code):
                if cmd in RUN:
                    done = _shell(cmd, tmp_path)
                    assert done.returncode == 0, f"README.md:{line}: {cmd}\n{done.stderr[-2000:]}"
                    ran.append((cmd, done))
    assert used == set(QUICK), "a QUICK constant is no longer defined by a README block"
    assert {cmd for cmd, _ in ran} == RUN

    # In Python: a frame of the shrunk camera; project/unproject round-trips exactly.
    frame, forces = ns["frame"], ns["forces"]
    assert frame.dtype == np.uint8 and frame.shape == (120, 160)
    assert ns["noload"].shape == (2, 120, 160)
    np.testing.assert_allclose(ns["points"], ns["contacts"].centers[0], rtol=0, atol=1e-9)

    # Frames to readings: the loaded element reads contact; a stack reads as frame by frame.
    r, rs, pipe, stack = ns["r"], ns["rs"], ns["pipe"], ns["stack"]
    assert r.contact[0] and r.G[0] > 0
    assert rs.G.shape == (10, 41)
    np.testing.assert_allclose(rs.G[3], pipe.process(stack[3]).G, rtol=1e-12, atol=0)
    rows = ns["rows"]
    assert {len(v) for v in rows.values()} == {410} and all(np.ndim(v) == 1 for v in rows.values())

    # Calibration and forces: the apex load read back from the rendered frame. A 16-frame,
    # 4-spp set of a 160x120 camera is a coarse calibration (Monte Carlo noise in every frame):
    # Fz within 0.25 N of 0.8 N and Fx within 0.1 N of 0.1 N; the apex carries the largest Fz.
    est = ns["field"].local
    assert abs(est[0, 2] - forces[0, 2]) < 0.25, est[0]
    assert abs(est[0, 0] - forces[0, 0]) < 0.1, est[0]
    assert np.argmax(est[:, 2]) == 0
    assert Path("forces.png").stat().st_size > 0
    assert ns["mine"].model == ns["cal"].model

    # The command line on the saved frames: the same readings and forces as in Python.
    readings = _csv(tmp_path / "readings.csv")
    assert len(readings) == 410
    g = np.array([float(row["G"]) for row in readings]).reshape(10, 41)
    np.testing.assert_allclose(g, rs.G, rtol=1e-9, atol=1e-9)
    cal = ns["cal"]
    want, _ = cal.forces(cal.pipeline(baseline=ns["noload"]).process(stack))
    got = np.array([[float(row[k]) for k in ("fx", "fy", "fz")] for row in _csv(tmp_path / "forces.csv")])
    np.testing.assert_allclose(got.reshape(10, 41, 3), want, rtol=1e-9, atol=1e-9)

    # The finger: the target is reached, the lean held, mu and the slip found.
    finger, ik, held = ns["finger"], ns["ik"], ns["held"]
    assert ik.error < 1e-3
    np.testing.assert_allclose(finger.forward(ik.theta), ns["target_mm"], rtol=0, atol=1e-3)
    assert abs(np.degrees(finger.lean(held.theta, z=held.z)) - 9.0) < 1e-3
    assert abs(ns["fe"].mean - 0.4) < 0.01
    onsets = ns["res"].onsets
    assert len(onsets) == 1 and 3.0 <= onsets[0] <= 3.5, onsets
    assert list(ns["slipping"]) == list(ns["res"].slipping)

    # Taxels: the indenter's centre comes back from the pad's moments within 0.3 mm.
    m = ns["m"]
    assert ns["taxel_frames"].shape == (6, 16, 16)
    assert abs(m["x_mm"][-1] - 3.0) < 0.3 and abs(m["y_mm"][-1] + 2.0) < 0.3

    # Studies: the names the README lists, and a result with the paper's figures beside ours.
    assert ns["studies"].names() == ["finger", "fingertip", "noise", "palpation", "tracing", "wire"]
    assert "published" in ns["result"]
    assert Path("tracing.png").stat().st_size > 0
