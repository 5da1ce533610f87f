"""Shared test set-up: caches go to a temporary folder, never the user's; notebooks run last.

Expensive objects (renders, calibration sets, study results) are built once per session
by fixtures here or in a folder's own ``conftest.py``; the notebooks run after every other
test, so they find the quick study results and tables in the session's cache.
"""

from __future__ import annotations

import pytest
from hypothesis import settings

# A busy machine is slow, not wrong: no per-example deadline anywhere in the suite.
settings.register_profile("optitact", deadline=None)
settings.load_profile("optitact")


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("OPTITACT_CACHE_DIR", str(tmp_path_factory.mktemp("optitact-cache")))
    yield
    mp.undo()


def pytest_collection_modifyitems(config, items):
    """Run the notebook executions last (stable order otherwise)."""
    items.sort(key=lambda item: item.get_closest_marker("notebook") is not None)
