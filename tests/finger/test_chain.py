"""The simulated chain (force -> render -> CCD -> pipeline -> calibration) on a tiny camera."""

from __future__ import annotations

import json

import numpy as np
import pytest
from optitact.calib.document import CalibrationMismatchError

import optitact
from optitact.errors import InputError, ShapeError
from optitact.finger.chain import ChainSimulator


@pytest.mark.render
def test_chain_estimates_through_the_real_chain(tiny_chain):
    f = np.zeros((3, 41, 3))
    f[1, 0] = (0.1, 0.0, 0.8)
    f[2, 0] = (0.0, 0.1, 0.8)
    a = tiny_chain.estimate(f, first_index=5)
    b = tiny_chain.estimate(f, first_index=5)
    assert a.forces.shape == (3, 41, 3) and a.clamped.shape == a.contact.shape == (3, 41)
    np.testing.assert_array_equal(a.forces, b.forces)  # same seeds, same frames
    assert not a.contact[0].any() and a.contact[1:, 0].all()
    assert a.forces[1, 0, 2] > 0.3 and a.forces[1, 0, 0] > a.forces[2, 0, 0]  # coarse on a 120x90 camera
    np.testing.assert_array_equal(a.truth, f)
    assert len(a) == 3 and len(a.readings) == 3
    json.dumps(tiny_chain.describe())


def test_chain_checks(tiny_chain):
    with pytest.raises(CalibrationMismatchError):
        ChainSimulator(tiny_chain.calibration, camera=optitact.optics.camera.FisheyeCamera())
    with pytest.raises(InputError, match="must not set"):
        ChainSimulator(tiny_chain.calibration, render_options={"spp": 3})
    with pytest.raises(TypeError, match="Calibration"):
        ChainSimulator("shipped")
    with pytest.raises(ShapeError, match="forces"):
        tiny_chain.estimate(np.zeros((41, 2)))
