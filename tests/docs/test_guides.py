"""The getting-started, guide and results pages of docs/ run as written and say what is true.

Each page runs as ``tests/test_readme.py`` runs the README: its python blocks in one namespace
of its own, its bash lines classified (run or skipped with a reason), in one temporary folder;
then the values its blocks left behind are checked. The calibration set is path-traced
(``RENDER_MODE = "pixels"``): the default two-stage transport would first measure the
light-transport table of the small test camera (tens of minutes). The study block reuses the
quick tracing result the taxel tests cached earlier in the session. The getting-started page's
example is the README's, word for word: ``tests/test_readme.py`` runs and checks it once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_readme import INSTALL, README, ROOT, Page, check_classified, check_languages, csv_rows, run_page

DOCS = ROOT / "docs"

#: A small camera and few samples for the pages that render (``SIZE, SPP = ...``).
SMALL = {"SIZE, SPP": "(160, 120), 16"}

WORKFLOW = ("the own-sensor workflow: tests/test_workflows.py runs these lines as typed, each a new "
            "process, on a rendered stand-in's files (a recording for --camera 0)")

PAGES = {page.name: page for page in (
    Page(DOCS / "getting_started.md", skipped=INSTALL, min_python=1),  # README's example: test_readme runs it
    Page(DOCS / "guides/index.md"),
    Page(DOCS / "guides/rendering.md", quick=SMALL, needs=("mitsuba",), min_python=1,
         run=frozenset({"optitact render --indenter sphere:radius=5 --at 30,40 --force 0.8 --slide 0.1,0 "
                        "--width 160 --height 120 --spp 4 --out pressed.png --forces-out pressed.csv"})),
    Page(DOCS / "guides/pipeline.md", quick=SMALL, needs=("mitsuba",), min_python=2,
         run=frozenset({"optitact process --help",
                        "optitact process frames.npy --baseline noload.npy --out readings.csv"})),
    Page(DOCS / "guides/calibration.md", quick={**SMALL, "FRAMES, RENDER_MODE": '24, "pixels"'},
         needs=("mitsuba", "matplotlib", "zarr"), min_python=2,
         run=frozenset({"optitact process frames.npy --baseline noload.npy --calibration dome41.json "
                        "--out forces.csv"}),
         skipped={
             "optitact calibrate generate --frames 200 --pattern blend --seed 0 --out dome41.zarr":
                 "regenerates the shipped calibration's set (minutes)",
             "optitact calibrate generate --frames 60 --pattern blend --seed 900 --render-mode pixels "
             "--spp 256 --out val.zarr": "the shipped calibration's validation set (path-traced, minutes)",
             "optitact calibrate fit dome41.zarr --joint --validation val.zarr --out calib/data/dome41.json "
             "--plot fit.png": "overwrites the shipped calibration, from the sets above"}),
    Page(DOCS / "guides/own_sensor.md", skipped={line: WORKFLOW for line in (
        "optitact register noload.png reg_*.png --camera-intrinsics cam.yml --fit-offsets --out setup.json",
        "optitact process presses/ --setup setup.json --calibration default --out forces.csv",
        "optitact calibrate fit --frames presses/ --forces gauge.csv --setup setup.json --start default "
        "--out mysensor.json",
        "optitact calibrate test --frames held/ --forces held.csv --calibration default --setup setup.json",
        "optitact calibrate test --frames held/ --forces held.csv --calibration mysensor.json "
        "--plot errors.png",
        "optitact process --camera 0 --calibration mysensor.json --out live.csv")} | {
        "optitact calibrate fit --frames presses/ --wrench ft.csv --ft-pose 0,0,-30 --setup setup.json "
        "--out mysensor.json": "run outside in on rendered object presses by "
                               "tests/calib/test_element_shapes.py::test_cli_wrench_calibration_outside_in"}),
    Page(DOCS / "guides/live.md", quick=SMALL, needs=("mitsuba",), min_python=1,
         run=frozenset({"optitact process --camera clip.avi --out live.csv",
                        "optitact process --camera clip.avi --calibration cal.json --record run.mcap --view "
                        "view.rrd --out live.csv",
                        "optitact process run.mcap --calibration cal.json --out replay.parquet"})),
    Page(DOCS / "guides/taxels.md", needs=("matplotlib", "sklearn", "dtaidistance"), min_python=2,
         run=frozenset({"optitact experiment tracing"}),
         skipped={"optitact experiment finger --full --plot finger.png": "the full finger study (minutes)"}),
    Page(DOCS / "guides/finger.md", min_python=1),
    *(Page(path) for path in sorted((DOCS / "results").glob("*.md"))),
)}


def test_every_page_is_listed():
    """A page added to the getting-started, guides or results has its code run here."""
    pages = {DOCS / "getting_started.md", *(DOCS / "guides").rglob("*.md"), *(DOCS / "results").rglob("*.md")}
    assert {p.relative_to(ROOT).as_posix() for p in pages} == set(PAGES)


@pytest.mark.parametrize("name", sorted(PAGES))
def test_every_block_has_a_language_the_test_knows(name):
    check_languages(PAGES[name])


@pytest.mark.parametrize("name", sorted(PAGES))
def test_every_bash_line_is_classified(name):
    check_classified(PAGES[name])


def _run(name: str, tmp_path: Path, monkeypatch) -> dict:
    ns, _ = run_page(PAGES[name], tmp_path, monkeypatch)
    return ns


def test_getting_started_shares_the_readme_example():
    """getting_started.md's python is the README's first example, which test_readme runs and checks."""
    def python(page):
        return [code for lang, _, code in page.blocks() if lang == "python"]

    assert python(PAGES["docs/getting_started.md"]) == python(README)


@pytest.mark.render
def test_rendering_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/rendering.md", tmp_path, monkeypatch)
    # A frame of the shrunk camera; project/unproject round-trips exactly.
    frame = ns["frame"]
    assert frame.dtype == np.uint8 and frame.shape == (120, 160)
    assert ns["noload"].shape == (2, 120, 160)
    np.testing.assert_allclose(ns["points"], ns["contacts"].centers[0], rtol=0, atol=1e-9)


@pytest.mark.render
def test_pipeline_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/pipeline.md", tmp_path, monkeypatch)
    # Frames to readings: the loaded element reads contact; a stack reads as frame by frame.
    r, rs, pipe, stack = ns["r"], ns["rs"], ns["pipe"], ns["stack"]
    assert r.contact[0] and r.G[0] > 0
    assert rs.G.shape == (10, 41)
    np.testing.assert_allclose(rs.G[3], pipe.process(stack[3]).G, rtol=1e-12, atol=0)
    rows = ns["rows"]
    assert {len(v) for v in rows.values()} == {410} and all(np.ndim(v) == 1 for v in rows.values())

    # The command line on the saved frames: the same readings as in Python.
    readings = csv_rows(tmp_path / "readings.csv")
    assert len(readings) == 410
    g = np.array([float(row["G"]) for row in readings]).reshape(10, 41)
    np.testing.assert_allclose(g, rs.G, rtol=1e-9, atol=1e-9)


@pytest.mark.render
def test_calibration_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/calibration.md", tmp_path, monkeypatch)
    # Calibration and forces: the apex load read back from the rendered frame. A 16-frame,
    # 4-spp set of a 160x120 camera is a coarse calibration (Monte Carlo noise in every frame):
    # Fz within 0.25 N of 0.8 N and Fx within 0.1 N of 0.1 N; the apex carries the largest Fz.
    est, forces = ns["field"].local, ns["forces"]
    assert abs(est[0, 2] - forces[0, 2]) < 0.25, est[0]
    assert abs(est[0, 0] - forces[0, 0]) < 0.1, est[0]
    assert np.argmax(est[:, 2]) == 0
    assert Path("forces.png").stat().st_size > 0
    assert ns["mine"].model == ns["cal"].model

    # The command line on the saved frames: the same forces as in Python.
    cal = ns["cal"]
    want, _ = cal.forces(cal.pipeline(baseline=ns["noload"]).process(ns["stack"]))
    got = np.array([[float(row[k]) for k in ("fx", "fy", "fz")] for row in csv_rows(tmp_path / "forces.csv")])
    np.testing.assert_allclose(got.reshape(10, 41, 3), want, rtol=1e-9, atol=1e-9)


@pytest.mark.render
def test_live_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/live.md", tmp_path, monkeypatch)
    # The recording streams frame by frame: the no-load frame is the baseline, then the apex is in contact.
    live = ns["live"]
    assert [index for index, *_ in live] == [0, 1, 2, 3]
    assert [baseline for _, baseline, _, _ in live] == [True, False, False, False]
    assert [bool(contact) for _, _, contact, _ in live[1:]] == [True, True, True]
    # ... and through the command line: the same, one row per frame and element, with capture times.
    rows = csv_rows(tmp_path / "live.csv")
    assert len(rows) == 4 * 41 and {"time_s", "wall_time"} <= set(rows[0])
    apex = [row for row in rows if row["element"] == "0"]
    assert [row["contact"] for row in apex][1:] == [apex[1]["contact"]] * 3
    # recorded, viewed into a file and replayed: the replay's forces are the live ones, to the last digit
    import pandas as pd

    replay = pd.read_parquet(tmp_path / "replay.parquet")
    live_forces = np.array([[float(row[k]) for k in ("fx", "fy", "fz")] for row in rows])
    np.testing.assert_array_equal(replay[["fx", "fy", "fz"]].to_numpy(), live_forces)
    assert live_forces[41:, 2].max() > 0.3  # the apex press reads as force
    assert (tmp_path / "view.rrd").stat().st_size > 0 and (tmp_path / "run.mcap").stat().st_size > 0


def test_taxels_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/taxels.md", tmp_path, monkeypatch)
    # Taxels: the indenter's centre comes back from the pad's moments within 0.3 mm.
    m = ns["m"]
    assert ns["taxel_frames"].shape == (6, 16, 16)
    assert abs(m["x_mm"][-1] - 3.0) < 0.3 and abs(m["y_mm"][-1] + 2.0) < 0.3

    # Studies: the names the page lists, and a result with the paper's figures beside ours.
    assert ns["studies"].names() == ["finger", "fingertip", "noise", "palpation", "tracing", "wire"]
    assert "published" in ns["result"]
    assert Path("tracing.png").stat().st_size > 0


def test_finger_guide_runs(tmp_path, monkeypatch):
    ns = _run("docs/guides/finger.md", tmp_path, monkeypatch)
    # The finger: the target is reached, the lean held, mu and the slip found.
    finger, ik, held = ns["finger"], ns["ik"], ns["held"]
    assert ik.error < 1e-3
    np.testing.assert_allclose(finger.forward(ik.theta), ns["target_mm"], rtol=0, atol=1e-3)
    assert abs(np.degrees(finger.lean(held.theta, z=held.z)) - 9.0) < 1e-3
    assert abs(ns["fe"].mean - 0.4) < 0.01
    onsets = ns["res"].onsets
    assert len(onsets) == 1 and 3.0 <= onsets[0] <= 3.5, onsets
    assert list(ns["slipping"]) == list(ns["res"].slipping)
