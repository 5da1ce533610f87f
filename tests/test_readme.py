"""The README's code blocks run as written, in order, and say what is true.

The machinery here runs any Markdown page of the repository the way a reader would: every
fenced ``python`` block of the page runs in one namespace, and the ``bash`` lines that are
cheap and safe run in a shell, all in document order in one temporary folder: a reader
pasting them one after another into one Python session and a shell in the same folder.
``tests/docs/test_guides.py`` runs the getting-started, guide and results pages of
``docs/`` with it, a namespace per page. Two kinds of edits make it quick, both visible
in each page's :class:`Page` and nowhere else:

- ``quick``: the named size constants a block defines on its first lines (``SIZE, SPP =
  ...``) get small values.
- ``skipped``: bash lines not run (installs, the whole test suite, long renders), each with
  its reason. A bash line in neither ``skipped`` nor ``run`` fails the page's test until it
  is classified.

Then the values the blocks left behind are checked against known truths.
"""

from __future__ import annotations

import csv
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The languages a page's fenced blocks may have: python and bash (executed), untagged (a
#: synopsis) and the MyST directives the docs use.
LANGUAGES = {"python", "bash", "", "{toctree}"}


@dataclass(frozen=True)
class Page:
    """A Markdown page whose code the tests run, and how."""

    path: Path
    #: Constant line of a block -> the small value the test gives it.
    quick: dict = field(default_factory=dict)
    #: Bash lines the test runs (after removing a trailing comment).
    run: frozenset = frozenset()
    #: Bash lines the test does not run, and why.
    skipped: dict = field(default_factory=dict)
    #: Modules the page's code needs (the test skips without them).
    needs: tuple = ()
    #: The fewest python blocks the page has.
    min_python: int = 0

    @property
    def name(self) -> str:
        return self.path.relative_to(ROOT).as_posix()

    def blocks(self) -> list[tuple[str, int, str]]:
        return blocks(self.path.read_text(encoding="utf-8"))


FENCE = re.compile(r"^(?P<indent> *)```(?P<lang>\{[\w-]+\}|\w*)\s*$")


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


def shrink(code: str, quick: dict, used: set) -> str:
    """Give the ``quick`` constants defined in ``code`` their small values."""
    for names, value in quick.items():
        pattern = re.compile(rf"^{re.escape(names)} = .*$", re.M)
        if pattern.search(code):
            code = pattern.sub(f"{names} = {value}", code, count=1)
            used.add(names)
    return code


def bash_lines(code: str) -> list[str]:
    """The commands of a bash block, trailing comments removed."""
    return [ln.split("  #")[0].strip() for ln in code.splitlines() if ln.strip() and not ln.startswith("#")]


def check_languages(page: Page) -> None:
    """A block is python or bash (executed), untagged (a synopsis) or a MyST directive."""
    found = page.blocks()
    assert {lang for lang, _, _ in found} <= LANGUAGES, page.name
    assert sum(lang == "python" for lang, _, _ in found) >= page.min_python, page.name


def check_classified(page: Page) -> None:
    lines = [ln for lang, _, code in page.blocks() if lang == "bash" for ln in bash_lines(code)]
    unknown = [ln for ln in lines if ln not in page.run and ln not in page.skipped]
    assert not unknown, f"classify these {page.name} bash lines in run or skipped: {unknown}"
    assert set(lines) == page.run | set(page.skipped), f"run/skipped name lines {page.name} no longer has"


def _shell(line: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    assert shutil.which("optitact", path=env["PATH"]), "the optitact command is not installed"
    return subprocess.run(["bash", "-c", line], cwd=cwd, env=env, capture_output=True, text=True)


def csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run_page(page: Page, tmp_path: Path, monkeypatch) -> tuple[dict, dict]:
    """Run a page's blocks in order in ``tmp_path``: its namespace, and the bash lines run with results."""
    # find_spec, not importorskip: importing drjit here would pick its libLLVM before optitact.render does.
    missing = [name for name in page.needs if importlib.util.find_spec(name) is None]
    if missing:
        pytest.skip(f"{page.name}'s examples need {', '.join(missing)}")
    monkeypatch.chdir(tmp_path)
    ns: dict = {"__name__": "__page__"}
    used: set = set()
    ran = {}
    for lang, line, code in page.blocks():
        if lang == "python":
            exec(compile(shrink(code, page.quick, used), f"{page.name}:{line}", "exec"), ns)  # noqa: S102
        elif lang == "bash":
            for cmd in bash_lines(code):
                if cmd in page.run:
                    done = _shell(cmd, tmp_path)
                    assert done.returncode == 0, f"{page.name}:{line}: {cmd}\n{done.stderr[-2000:]}"
                    ran[cmd] = done
    assert used == set(page.quick), f"a quick constant is no longer defined by a {page.name} block"
    assert set(ran) == page.run
    return ns, ran


#: The commands of README.md and docs/getting_started.md, which CI runs as written (.ci/run).
INSTALL = {
    "pip install -e '.[render,plot]' && optitact demo": "an install, then a 640x480 render at 64 spp",
    "pip install -e '.[test]' && pytest": "an install, then the whole test suite",
}

#: The first example (README.md, docs/getting_started.md) renders the shipped calibration's 640x480 camera:
#: 4 samples per pixel keep it to about a second a render.
FIRST_EXAMPLE_QUICK = {"SPP": "4"}

README = Page(
    ROOT / "README.md",
    quick=FIRST_EXAMPLE_QUICK,
    skipped={**INSTALL,
             "pip install -e '.[docs]' && sphinx-build docs docs/_build/html":
                 "an install, then the documentation build (tests/docs/test_sphinx.py builds it)"},
    needs=("mitsuba",),
    min_python=1,
)


def check_first_example(ns: dict) -> None:
    """The apex load read back from the rendered frame with the shipped calibration.

    At 4 spp with one no-load frame, Fz within 0.15 N of 0.8 N and Fx within 0.1 N of 0.1 N;
    the apex carries the largest Fz.
    """
    est, forces = ns["field"].local, ns["forces"]
    assert ns["frame"].dtype == np.uint8 and ns["frame"].shape == (480, 640)
    assert abs(est[0, 2] - forces[0, 2]) < 0.15, est[0]
    assert abs(est[0, 0] - forces[0, 0]) < 0.1, est[0]
    assert np.argmax(est[:, 2]) == 0


def test_every_block_has_a_language_the_test_knows():
    check_languages(README)


def test_every_bash_line_is_classified():
    check_classified(README)


@pytest.mark.render
def test_readme_runs_top_to_bottom(tmp_path, monkeypatch):
    ns, _ = run_page(README, tmp_path, monkeypatch)
    check_first_example(ns)
