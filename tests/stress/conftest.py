"""Fixtures of the stress cases, and the count of executed examples for ``optitact bench stability``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from .helpers import SMALL, Context
from .strategies import CARRY, COUNTS, DECLARED, TESTS, total_cases

_FAILURES: dict[str, str] = {}


@pytest.fixture(scope="session")
def ctx(tmp_path_factory) -> Context:
    """Pipelines and truths of the small camera, built once."""
    return Context(tmp_path_factory.mktemp("stress"))


def pytest_runtest_logreport(report):
    if report.failed:
        _FAILURES[report.nodeid] = str(report.longrepr)[-500:]


def pytest_sessionfinish(session, exitstatus):
    path = os.environ.get("OPTITACT_STRESS_COUNTS")
    if path:
        Path(path).write_text(json.dumps({
            "categories": COUNTS, "failures": _FAILURES, "camera": SMALL.to_dict(),
            "requested": total_cases(), "declared": sum(n for _, _, n in DECLARED.values()),
            "tests": TESTS, "unspent": CARRY["examples"]}))
