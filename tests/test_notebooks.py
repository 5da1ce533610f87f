"""Every notebook runs top to bottom on a fresh install, and matches its percent-script twin.

The ``notebooks/*.py`` percent scripts are the reviewable sources; ``jupytext --to ipynb
notebooks/0*.py`` writes their ``.ipynb`` twins. Notebooks run last in the session
(``conftest.py``), so the quick study results, renders and tables the tests made are in the
cache they read; those that read none of it (``EARLY_NOTEBOOKS``) start with the session in a
background process (``_notebook_runner.py``) and their tests wait for the result.
"""

from __future__ import annotations

import json
import pathlib

import pytest
from _notebook_runner import EARLY_NOTEBOOKS, save_executed

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
jupytext = pytest.importorskip("jupytext")

ROOT = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
SCRIPTS = sorted(ROOT.glob("[0-9][0-9]_*.py"))


def test_there_are_notebooks():
    assert [p.stem[:2] for p in SCRIPTS] == ["01", "02", "03", "04", "05", "06"]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_notebook_matches_its_script_and_has_no_outputs(script):
    nb = nbformat.read(script.with_suffix(".ipynb"), as_version=4)
    want = jupytext.read(script)
    assert [(c.cell_type, c.source) for c in nb.cells] == [(c.cell_type, c.source) for c in want.cells], \
        "run: jupytext --to ipynb notebooks/0*.py"
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code")


@pytest.mark.notebook
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_notebook_runs(script, tmp_path, request):
    early = getattr(request.config, "_optitact_early_runner", None)
    if early is not None and script.stem in EARLY_NOTEBOOKS:  # started with the session (conftest.py)
        runner, out = early
        runner.wait()
        result = json.loads((out / f"{script.stem}.json").read_text())
        assert not result["errors"], result["errors"]
        return
    if script.stem == "06_finger":  # it reads the quick finger study the tests compute (and cache) once
        request.getfixturevalue("finger_quick_study")
    nb = nbformat.read(script.with_suffix(".ipynb"), as_version=4)
    # No cell timeout: a busy machine is slow, not wrong (CI has its own overall limit).
    client = nbclient.NotebookClient(nb, timeout=None, startup_timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    save_executed(nb, script.stem)  # the docs' tutorials show it with its outputs
