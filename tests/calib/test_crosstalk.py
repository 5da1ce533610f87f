"""The joint inversion across elements, on an ideal sensor built from an exactly known cross-talk law."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from optitact.calib.crosstalk import CrossTalk
from optitact.calib.curves import grey_for_force as _grey_for_force
from optitact.calib.curves import zero_shear_centroid
from optitact.calib.fit import Calibration
from optitact.calib.patterns import pattern_forces
from optitact.calib.sets import Design
from optitact.calib.shipped import default_calibration

from optitact.errors import InputError
from optitact.pipeline.readings import Readings

CAL = replace(default_calibration(), crosstalk=None)  # the shipped curves, each element on its own
SENSOR = CAL.sensor
#: The law: per pair of rings (1/N) and a near field at 6 mm; the apex's own-ring entry has no meaning.
TRUE_K = np.array([[0.0, 0.004, 0.003, 0.002, 0.0],
                   [0.004, 0.008, 0.004, 0.002, 0.012],
                   [0.002, 0.004, 0.006, 0.003, 0.010],
                   [0.001, 0.002, 0.003, 0.005, 0.008]])
TRUE = CrossTalk(TRUE_K)
TRAIN = Design(fz_max=0.95, shear_max=0.25, mu_max=0.25)
TEST = Design(fz_max=0.8, shear_max=0.15, mu_max=0.15)


def ideal(n: int, seed: int, pattern: str, design: Design):
    """Readings of a sensor whose curves are the shipped ones exactly and whose elements dim each other
    by ``TRUE``: ``G = G_iso exp(-W Fz)``, ``G_iso`` the shipped curves inverted at the true force."""
    f = pattern_forces(pattern, n, SENSOR, design, seed)
    f[..., 2] = np.where(f[..., 2] > 0, np.maximum(f[..., 2], 0.02), 0.0)
    contact = f[..., 2] > 0
    fz = f[..., 2]
    safe = np.where(contact, fz, 1.0)
    u = f[..., :2] * ((CAL.f[:, 0] + CAL.f[:, 1] * np.sqrt(safe)) / safe)[..., None]  # coupled shear inverted
    u = u + zero_shear_centroid(CAL.u0, safe)
    g_iso = np.where(contact, _grey_for_force(CAL, fz, u), 0.0)
    g = g_iso * np.exp(-(fz @ TRUE.matrix(SENSOR).T))
    none = np.zeros_like(contact)
    return (Readings(g, np.where(contact[..., None], u, 0.0), contact, none), f,
            Readings(g_iso, np.where(contact[..., None], u, 0.0), contact, none))


@pytest.fixture(scope="module")
def fitted():
    r, f, r_iso = ideal(120, 1, "blend", TRAIN)
    est, _ = CAL.forces(r_iso)  # the ideal sensor's isolated readings are the shipped curves' exactly
    np.testing.assert_allclose(est, f, atol=1e-12)
    kw = dict(sensor=SENSOR, camera=CAL.camera, pipeline_options=CAL.pipeline_options)
    return Calibration.fit(r, f, joint=True, **kw), Calibration.fit(r, f, **kw)


@pytest.mark.parametrize("pattern", ["uniform", "single", "clustered", "checkerboard"])
def test_joint_inversion_recovers_every_family_exactly(fitted, pattern):
    """To 1e-6 N on families it was not fitted on, where the per-element curves are off by centinewtons."""
    joint, alone = fitted
    r, f, _ = ideal(24, 7, pattern, TEST)
    loaded = f[..., 2] > 0
    est, clamped = joint.forces(r)
    assert not clamped[loaded].any()
    assert np.abs(est - f)[loaded].max() < 1e-6
    worst_alone = np.abs(alone.forces(r)[0] - f)[loaded].max()
    assert worst_alone > 1e-2, worst_alone


def test_the_law_is_recovered(fitted):
    joint, _ = fitted
    np.testing.assert_allclose(joint.crosstalk.matrix(SENSOR), TRUE.matrix(SENSOR), atol=1e-9)
    fit = joint.provenance["crosstalk_fit"]
    assert fit["rms_log_before"] > 0.01 and fit["rms_log_after"] < 1e-9 and fit["refinement_converged"]


def test_without_neighbours_the_joint_model_is_the_per_element_one(fitted):
    joint, _ = fitted
    r, f, r_iso = ideal(41, 3, "single", TEST)
    np.testing.assert_allclose(r.G, r_iso.G, rtol=0, atol=0)  # nobody else loaded: no cross-talk
    np.testing.assert_allclose(joint.forces(r)[0], f, atol=1e-9)


def test_saved_loaded_transferred_and_refined_calibrations_keep_the_coupling(fitted, tmp_path):
    joint, _ = fitted
    back = Calibration.load(joint.save(tmp_path / "joint.json"))
    r, f, _ = ideal(6, 11, "uniform", TEST)
    np.testing.assert_array_equal(back.forces(r)[0], joint.forces(r)[0])
    doc = json.loads((tmp_path / "joint.json").read_text())
    assert np.array(doc["crosstalk"]["coefficients"]).shape == (4, 5)
    gains = np.linspace(0.9, 1.1, SENSOR.n_elements)
    moved = joint.transferred(SENSOR.__class__(element_gain=gains), joint.camera)
    assert moved.crosstalk is joint.crosstalk
    scaled = Readings(r.G * gains, r.u, r.contact, r.saturated)
    np.testing.assert_allclose(moved.forces(scaled)[0], joint.forces(r)[0], atol=1e-9)


def test_bad_coupling_documents_are_refused(fitted):
    joint, _ = fitted
    doc = joint.to_dict()
    for bad, match in (({"coefficients": [[0.1]]}, "R \\+ 1"), ({"coefficients": "x"}, "numbers"),
                       ({"coefficients": TRUE_K[:3, :4].tolist()}, "rings"),
                       ({"coefficients": TRUE_K.tolist(), "near_mm": -1}, "near_mm")):
        with pytest.raises(InputError, match=match):
            Calibration.from_dict({**doc, "crosstalk": bad})
    with pytest.raises(TypeError, match="joint"):
        Calibration.fit(*ideal(20, 2, "blend", TRAIN)[:2], sensor=SENSOR, camera=CAL.camera, joint="yes")
