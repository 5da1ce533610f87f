"""The stress budget: every category's shares add up to 1, so the examples add up to the requested total."""

from __future__ import annotations

import importlib
import math

from .strategies import CATEGORIES, DECLARED, total_cases

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
