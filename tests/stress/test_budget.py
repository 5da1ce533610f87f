"""The stress budget: every category's shares add up to 1, so the examples add up to the requested total;
examples a test leaves unused pass on to the next."""

from __future__ import annotations

import copy
import importlib
import math

from hypothesis import strategies as st

from .strategies import CARRY, CATEGORIES, COUNTS, DECLARED, TESTS, stress, total_cases

MODULES = ("test_frames", "test_readings", "test_fits", "test_files", "test_accumulation", "test_ccd",
           "test_render_inputs")


def test_shares_add_up_and_every_category_has_cases():
    for name in MODULES:
        importlib.import_module(f"{__package__}.{name}")
    shares = {cat: 0.0 for cat in CATEGORIES}
    for cat, share, _ in DECLARED.values():
        shares[cat] += share
    assert all(math.isclose(s, 1.0) for s in shares.values()), shares
    total = sum(n for _, _, n in DECLARED.values())
    assert abs(total - total_cases()) <= len(DECLARED), (total, total_cases())


def test_examples_a_test_leaves_unused_pass_on_to_the_next():
    saved = dict(CARRY), copy.deepcopy(COUNTS), dict(DECLARED), dict(TESTS)
    seen = []
    try:
        CARRY["examples"] = 5

        @stress("ccd", 0.0, x=st.sampled_from([1, 2, 3]))
        def few(x):
            seen.append(x)

        @stress("ccd", 0.0, x=st.integers(0, 10**6))
        def many(x):
            seen.append(x)

        few()  # allotted its 1 and the 5 carried to it; three values to draw
        assert sorted(seen) == [1, 2, 3] and CARRY["examples"] == 3
        assert TESTS[f"{__name__}.{few.__qualname__}"] == {"declared": 1, "allotted": 6, "executed": 3}
        many()
        assert len(seen) == 3 + 4 and CARRY["examples"] == 0
        assert COUNTS["ccd"]["generated"] == saved[1]["ccd"]["generated"] + 7
    finally:
        for live, old in zip((CARRY, COUNTS, DECLARED, TESTS), saved, strict=True):
            live.clear()
            live.update(old)
