"""Run the docstring examples of every module once, and ruff over the repository."""

from __future__ import annotations

import doctest
import importlib
import pathlib
import pkgutil
import subprocess
import sys

import optitact


def _modules() -> list[str]:
    """Every module of the installed package, render/calib/forces (mapped folders) included."""
    names = ["optitact"]
    for pkg in ("optitact", "optitact.render", "optitact.calib", "optitact.forces"):
        mod = importlib.import_module(pkg)
        names += [m.name for m in pkgutil.walk_packages(mod.__path__, prefix=f"{pkg}.")
                  if not m.name.endswith(".__main__")]  # running a __main__ would run the CLI
    return sorted(set(names))


MODULES = _modules()


def test_every_package_is_walked():
    prefixes = {m.rsplit(".", 1)[0] for m in MODULES}
    assert {"optitact", "optitact.render", "optitact.calib", "optitact.forces", "optitact.studies"} <= prefixes
    assert len(MODULES) > 30


def test_docstring_examples():
    failures = {}
    for name in MODULES:
        result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS, verbose=False,
                                 report=False)
        if result.failed:
            failures[name] = result.failed
    assert failures == {}


def test_ruff_clean():
    root = pathlib.Path(optitact.__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(root)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
