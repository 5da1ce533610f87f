"""Shared, session-scoped fixtures of the finger tests: one tiny chain, one quick study result."""

from __future__ import annotations

import pytest
from optitact.calib.fit import fit
from optitact.calib.sets import generate

import optitact
from optitact.finger.chain import ChainSimulator

TINY = optitact.optics.camera.FisheyeCamera(width=120, height=90)


@pytest.fixture(scope="session")
def tiny_chain(tmp_path_factory):
    """A 120x90 camera calibrated on 20 frames at 8 spp (a few seconds; noisy, for smoke tests only)."""
    cset = generate(tmp_path_factory.mktemp("finger") / "c.zarr", frames=28, camera=TINY, spp=8, seed=0,
                    render_mode="pixels", baseline_frames=2, progress=False)
    return ChainSimulator(fit(cset), spp=4, seed=3, baseline_frames=2, baseline_spp=8)


@pytest.fixture(scope="session")
def quick_result(finger_quick_study):
    """The quick finger study (the root conftest's ``finger_quick_study``, shared with the notebook)."""
    return finger_quick_study
