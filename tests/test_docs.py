"""Run the docstring examples of the public modules, and ruff over the repository."""

from __future__ import annotations

import doctest
import importlib
import pathlib
import subprocess
import sys

import pytest

MODULES = ["optitact.sensor", "optitact.camera", "optitact.contact", "optitact.ccd",
           "optitact.forces", "optitact.render", "optitact.pipeline", "optitact.readings", "optitact.sources"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0


def test_ruff_clean():
    root = pathlib.Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(root)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
