"""Hypothesis set-up of the stress cases: one budget of examples shared among the categories.

Every generated test is declared with :func:`stress` (its category and its
share of the category's examples) and every explicit one with :func:`counted`.
The budget is ``OPTITACT_STRESS_CASES`` examples in all (default
:data:`DEFAULT_CASES`, a quick run); ``optitact bench stability --cases N``
runs this folder with ``OPTITACT_STRESS_CASES=N``. Runs are reproducible:
derandomized by default, seeded by ``OPTITACT_STRESS_SEED`` when it is set.
Every executed example is counted per category (:data:`COUNTS`), and
``conftest.py`` writes the counts to ``OPTITACT_STRESS_COUNTS`` when set.
"""

from __future__ import annotations

import functools
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


def total_cases() -> int:
    """The budget of generated examples (``OPTITACT_STRESS_CASES``, default :data:`DEFAULT_CASES`)."""
    return int(os.environ.get("OPTITACT_STRESS_CASES", DEFAULT_CASES))


def stress_seed() -> int | None:
    """``OPTITACT_STRESS_SEED`` as an int, or None (derandomized runs)."""
    value = os.environ.get("OPTITACT_STRESS_SEED")
    return None if value in (None, "") else int(value)


def counted(category: str):
    """Count every call of the test (one example) under ``category``, as passed or failed."""
    if category not in CATEGORIES:
        raise ValueError(f"category must be one of {sorted(CATEGORIES)}, got {category!r}")

    def deco(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                out = fn(*args, **kwargs)
            except UnsatisfiedAssumption:
                raise
            except BaseException as exc:
                if type(exc).__name__ not in ("Skipped", "XFailed"):
                    COUNTS[category]["generated"] += 1
                    COUNTS[category]["failed"] += 1
                raise
            COUNTS[category]["generated"] += 1
            COUNTS[category]["passed"] += 1
            return out
        return wrapper
    return deco


def stress(category: str, share: float, **strategies):
    """``@given(**strategies)`` with ``share`` of the category's examples, counted.

    The shares of a category's tests add up to 1 (``test_budget.py`` checks it).
    """
    n = max(1, round(total_cases() * CATEGORIES[category] * share))
    s = stress_seed()

    def deco(fn):
        DECLARED[f"{fn.__module__}.{fn.__qualname__}"] = (category, share, n)
        test = given(**strategies)(counted(category)(fn))
        test = settings(max_examples=n, deadline=None, derandomize=s is None, database=None,
                        suppress_health_check=list(HealthCheck), print_blob=False)(test)
        return test if s is None else seed(s)(test)
    return deco


#: A seed for the NumPy generator of a case's arrays.
seeds = st.integers(0, 2**63 - 1)


def rng_of(value: int) -> np.random.Generator:
    """The NumPy generator of a drawn seed."""
    return np.random.default_rng(value)
