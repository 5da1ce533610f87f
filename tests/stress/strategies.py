"""Hypothesis set-up of the stress cases: one budget of examples shared among the categories.

Every generated test is declared with :func:`stress` (its category and its
share of the category's examples) and every explicit one with :func:`counted`.
The budget is ``OPTITACT_STRESS_CASES`` examples in all (default
:data:`DEFAULT_CASES`, a quick run); ``optitact bench stability --cases N``
runs this folder with ``OPTITACT_STRESS_CASES=N``. Runs are reproducible:
derandomized by default, seeded by ``OPTITACT_STRESS_SEED`` when it is set.
Every executed example is counted per category (:data:`COUNTS`) and per
generated test (:data:`TESTS`), and ``conftest.py`` writes the counts to
``OPTITACT_STRESS_COUNTS`` when set.

Hypothesis runs fewer examples than a test's ``max_examples`` when the
test's strategies have fewer distinct values (a few ``sampled_from``
choices) or when it filters examples out. The examples a test leaves
unused pass on to the next generated test that runs (:data:`CARRY`), so the
session executes its whole budget unless the last tests to run all run
short (``unspent`` in the counts says how many were left).
"""

from __future__ import annotations

import functools
import inspect
import os

import numpy as np
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st
from hypothesis.errors import UnsatisfiedAssumption

#: Categories and their share of the generated examples.
CATEGORIES = {
    "frames": 0.40,
    "readings": 0.14,
    "calibration_fit": 0.07,
    "calibration_file": 0.12,
    "accumulation": 0.05,
    "ccd": 0.09,
    "contact_render": 0.13,
}
#: Generated examples in all of a plain ``pytest`` run.
DEFAULT_CASES = 600
#: Executed examples per category: generated, passed, failed.
COUNTS = {cat: {"generated": 0, "passed": 0, "failed": 0} for cat in CATEGORIES}
#: Each generated test's (category, share, max_examples), by qualified name.
DECLARED: dict[str, tuple[str, float, int]] = {}
#: Each generated test that ran: its share of the budget (``declared``), what it was given
#: (``allotted``: its share plus the examples carried to it) and the examples it ``executed``.
TESTS: dict[str, dict[str, int]] = {}
#: Examples allotted to the generated tests that ran but not executed by them, passed on to the next.
CARRY = {"examples": 0}


def total_cases() -> int:
    """The budget of generated examples (``OPTITACT_STRESS_CASES``, default :data:`DEFAULT_CASES`)."""
    return int(os.environ.get("OPTITACT_STRESS_CASES", DEFAULT_CASES))


def stress_seed() -> int | None:
    """``OPTITACT_STRESS_SEED`` as an int, or None (derandomized runs)."""
    value = os.environ.get("OPTITACT_STRESS_SEED")
    return None if value in (None, "") else int(value)


def counted(category: str, *, into: dict[str, int] | None = None):
    """Count every call of the test (one example) under ``category``, as passed or failed.

    ``into``: a dict whose ``"executed"`` also counts the calls (one generated test's).
    """
    if category not in CATEGORIES:
        raise ValueError(f"category must be one of {sorted(CATEGORIES)}, got {category!r}")

    def count(outcome: str) -> None:
        COUNTS[category]["generated"] += 1
        COUNTS[category][outcome] += 1
        if into is not None:
            into["executed"] += 1

    def deco(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                out = fn(*args, **kwargs)
            except UnsatisfiedAssumption:
                raise
            except BaseException as exc:
                if type(exc).__name__ not in ("Skipped", "XFailed"):
                    count("failed")
                raise
            count("passed")
            return out
        return wrapper
    return deco


def stress(category: str, share: float, **strategies):
    """``@given(**strategies)`` with ``share`` of the category's examples, counted.

    The shares of a category's tests add up to 1 (``test_budget.py`` checks it).
    The test is given its share plus the examples carried over from earlier
    tests (:data:`CARRY`), and passes on what it leaves unused.
    """
    n = max(1, round(total_cases() * CATEGORIES[category] * share))
    s = stress_seed()

    def deco(fn):
        name = f"{fn.__module__}.{fn.__qualname__}"
        DECLARED[name] = (category, share, n)
        tally = {"declared": n, "allotted": 0, "executed": 0}
        body = counted(category, into=tally)(fn)

        def hypothesis_test(max_examples: int):
            # built per call: Hypothesis takes one settings object per test function
            test = settings(max_examples=max_examples, deadline=None, derandomize=s is None, database=None,
                            suppress_health_check=list(HealthCheck),
                            print_blob=False)(given(**strategies)(body))
            return test if s is None else seed(s)(test)

        def test(*args, **kwargs):
            allotted = n + CARRY["examples"]
            before = tally["executed"]
            tally["allotted"] += allotted
            TESTS[name] = tally
            try:
                hypothesis_test(allotted)(*args, **kwargs)
            finally:
                CARRY["examples"] = max(0, allotted - (tally["executed"] - before))

        functools.update_wrapper(test, fn)
        test.__signature__ = inspect.signature(given(**strategies)(fn))  # the fixtures pytest passes
        return test
    return deco


#: A seed for the NumPy generator of a case's arrays.
seeds = st.integers(0, 2**63 - 1)


def rng_of(value: int) -> np.random.Generator:
    """The NumPy generator of a drawn seed."""
    return np.random.default_rng(value)
