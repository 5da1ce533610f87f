"""Execute notebooks in this process, one after the other; write ``NAME.json`` results into a folder.

Started by ``tests/conftest.py`` at the beginning of a session for the notebooks that read
nothing the tests cache (their kernels then run beside the other tests, on the core the tests
leave idle); ``tests/test_notebooks.py`` waits for the result. Usage:
``python _notebook_runner.py OUT_DIR NOTEBOOK.ipynb...``.
"""

from __future__ import annotations

import json
import os
import pathlib
import sys
import tempfile
import traceback

#: Where each test run leaves the notebooks it executed, with their outputs (git-ignored, like the
#: rest of docs/_build): the documentation build shows these in place of the unexecuted copies.
EXECUTED = pathlib.Path(__file__).resolve().parents[1] / "docs" / "_build" / "executed-notebooks"


def save_executed(nb, name: str) -> None:
    """Write an executed notebook to :data:`EXECUTED` as ``NAME.ipynb`` (whole, or not at all)."""
    import nbformat

    EXECUTED.mkdir(parents=True, exist_ok=True)
    tmp = EXECUTED / f".{name}.{os.getpid()}.tmp"
    nbformat.write(nb, tmp)
    tmp.replace(EXECUTED / f"{name}.ipynb")


#: Notebooks that read nothing the tests cache: they start with the session, in a background
#: process beside the tests, and their tests wait for them (the others run last).
EARLY_NOTEBOOKS = ("01_quickstart", "02_calibration", "04_numerical_stability")


def run(notebook: pathlib.Path) -> dict:
    """``{"errors": [...]}`` of one notebook executed top to bottom in a fresh folder."""
    import nbclient
    import nbformat

    nb = nbformat.read(notebook, as_version=4)
    with tempfile.TemporaryDirectory() as work:
        client = nbclient.NotebookClient(nb, timeout=None, startup_timeout=600, kernel_name="python3",
                                         resources={"metadata": {"path": work}})
        try:
            client.execute()
        except Exception:  # a failing cell: report it; the test shows it
            return {"errors": [traceback.format_exc()]}
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    if not errors:
        save_executed(nb, notebook.stem)
    return {"errors": errors}


def main(argv: list[str]) -> None:
    out = pathlib.Path(argv[0])
    for name in argv[1:]:
        path = pathlib.Path(name)
        result = run(path)
        tmp = out / f".{path.stem}.json.tmp"
        tmp.write_text(json.dumps(result))
        tmp.replace(out / f"{path.stem}.json")


if __name__ == "__main__":
    main(sys.argv[1:])
