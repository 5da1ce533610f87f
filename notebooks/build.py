"""Write each ``*.py`` percent-script here as its ``.ipynb`` twin, outputs stripped.

The ``.py`` files are the reviewable sources (``# %%`` code cells, ``# %% [markdown]``
markdown cells, as jupytext writes them); ``python notebooks/build.py`` regenerates the
notebooks, and the test suite checks that the two agree and runs every notebook.
"""

from __future__ import annotations

import sys
from pathlib import Path

import nbformat

HERE = Path(__file__).resolve().parent


def cells_from_script(text: str) -> list[tuple[str, str]]:
    """``(kind, source)`` cells of a percent script (kind ``code`` or ``markdown``)."""
    cells: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith("# %%"):
            kind = "markdown" if "[markdown]" in line else "code"
            cells.append((kind, []))
            continue
        if not cells:
            continue  # the module docstring/header before the first cell
        kind, lines = cells[-1]
        if kind == "markdown":
            line = line[2:] if line.startswith("# ") else line.lstrip("#")
        lines.append(line)
    return [(kind, "\n".join(lines).strip("\n")) for kind, lines in cells]


def notebook_from_script(path: Path) -> nbformat.NotebookNode:
    """The notebook of a percent script, no outputs."""
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    for kind, source in cells_from_script(path.read_text()):
        cell = nbformat.v4.new_markdown_cell(source) if kind == "markdown" else nbformat.v4.new_code_cell(source)
        cell["id"] = f"cell-{len(nb.cells)}"
        nb.cells.append(cell)
    return nb


def scripts() -> list[Path]:
    """The notebook sources, in order."""
    return sorted(p for p in HERE.glob("[0-9]*.py"))


def main() -> int:
    for script in scripts():
        nb = notebook_from_script(script)
        nbformat.write(nb, script.with_suffix(".ipynb"))
        print(script.with_suffix(".ipynb").name, file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
