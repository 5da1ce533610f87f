"""Shared test set-up: caches go to a temporary folder, never the user's."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("OPTITACT_CACHE_DIR", str(tmp_path_factory.mktemp("optitact-cache")))
    yield
    mp.undo()
