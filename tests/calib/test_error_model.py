"""The calibration's own error measured on independent data (calib/error_model.py, Calibration.validated).

Truth is a known error law: residuals drawn as N(0, s^2 + a^2 + (b Fz)^2) beside a known noise s.
The fit must recover (a, b), the validated calibration's error bars must then cover 90 % of
fresh draws, and the model must survive the JSON round trip.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from optitact.calib.error_model import MIN_SAMPLES, ErrorModel
from optitact.calib.fit import Calibration
from optitact.calib.shipped import default_calibration

from optitact.errors import InputError, ShapeError
from optitact.pipeline.readings import Readings
from optitact.pipeline.uncertainty import coverage

FLOOR = np.array([0.001, 0.002, 0.003])
RELATIVE = np.array([0.006, 0.0, 0.012])


def draw(rng, n, noise_max=0.002):
    fz = rng.uniform(0.0, 1.0, n)
    s = rng.uniform(0.0, noise_max, (n, 3))
    sigma = np.sqrt(s**2 + FLOOR**2 + (RELATIVE * fz[:, None]) ** 2)
    return rng.normal(size=(n, 3)) * sigma, s, fz, sigma


def test_fit_recovers_a_known_error_law():
    res, s, fz, _ = draw(np.random.default_rng(0), 20000)
    m = ErrorModel.fit(res, s, fz, source="synthetic")
    np.testing.assert_allclose(m.floor_n, FLOOR, rtol=0.08, atol=0)
    np.testing.assert_allclose(m.relative, RELATIVE, rtol=0.05, atol=0.0006)
    assert m.samples == 20000 and m.source == "synthetic"


def test_fit_recovers_a_known_law_with_a_shear_part():
    """sigma^2 = s^2 + a^2 + (b Fz)^2 + (c Ft)^2: (a, b, c) come back; c = 0 where the law has none."""
    rng = np.random.default_rng(7)
    n = 40000
    fz, ft = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 0.35, n)
    shear = np.array([0.02, 0.0, 0.015])
    s = rng.uniform(0.0, 0.002, (n, 3))
    sigma = np.sqrt(s**2 + FLOOR**2 + (RELATIVE * fz[:, None]) ** 2 + (shear * ft[:, None]) ** 2)
    m = ErrorModel.fit(rng.normal(size=(n, 3)) * sigma, s, fz, ft)
    np.testing.assert_allclose(m.floor_n, FLOOR, rtol=0.1, atol=0)
    np.testing.assert_allclose(m.relative, RELATIVE, rtol=0.08, atol=0.0008)
    np.testing.assert_allclose(m.shear, shear, rtol=0.08, atol=0.002)
    np.testing.assert_allclose(m.sigma(fz[:5], ft[:5]), np.sqrt(sigma[:5] ** 2 - s[:5] ** 2), rtol=0.08)
    back = ErrorModel.from_dict(m.to_dict())
    np.testing.assert_array_equal(back.shear, m.shear)
    old = {k: v for k, v in m.to_dict().items() if k != "shear"}  # a file written before the shear part
    assert not ErrorModel.from_dict(old).shear.any()
    assert not ErrorModel.fit(*draw(np.random.default_rng(8), 500)[:3]).shear.any()  # no ft: no shear part
    with pytest.raises(ShapeError, match="ft"):
        ErrorModel.fit(m.floor_n[None].repeat(30, 0), np.zeros((30, 3)), np.ones(30), np.ones(29))


def test_fitted_error_bars_cover_ninety_percent_of_fresh_draws():
    res, s, fz, _ = draw(np.random.default_rng(1), 5000)
    m = ErrorModel.fit(res, s, fz)
    new, s2, fz2, _ = draw(np.random.default_rng(2), 20000)
    se = np.sqrt(s2**2 + m.sigma(fz2) ** 2)
    np.testing.assert_allclose(coverage(new, np.zeros_like(new), se), 0.9, rtol=0, atol=0.01)


def test_noise_is_not_counted_twice():
    """Residuals that are all noise leave (nearly) no model error."""
    rng = np.random.default_rng(3)
    s = rng.uniform(0.001, 0.003, (20000, 3))
    m = ErrorModel.fit(rng.normal(size=s.shape) * s, s, rng.uniform(0, 1, 20000))
    assert np.all(m.floor_n < 4e-4) and np.all(m.relative < 6e-4)  # against 1-3e-3 of noise


def test_fit_refuses_bad_inputs():
    res, s, fz, _ = draw(np.random.default_rng(4), 50)
    with pytest.raises(InputError, match=f"at least {MIN_SAMPLES}"):
        ErrorModel.fit(res[:5], s[:5], fz[:5])
    with pytest.raises(ShapeError, match=r"\(n, 3\)"):
        ErrorModel.fit(res[:, :2], s, fz)
    bad = res.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        ErrorModel.fit(bad, s, fz)
    with pytest.raises(InputError, match=">= 0"):
        ErrorModel([-1.0, 0.0, 0.0], [0.0, 0.0, 0.0], samples=3)


@pytest.fixture(scope="module")
def cal():
    """The shipped curves without their measured error model (the fit residuals' error bars)."""
    return replace(default_calibration(), error_model=None)


def readings(cal, rng, n):
    E = len(cal.g)
    G = cal.g_max * rng.uniform(0.2, 0.7, (n, E))
    u = rng.normal(0.0, 0.2, (n, E, 2)) * cal.u_max[:, None]
    return Readings(G, u, np.ones((n, E), bool), np.zeros((n, E), bool))


def test_validated_calibration_measures_its_error_and_keeps_it_in_its_file(cal, tmp_path):
    """Truth = estimate minus errors of a known law: validated() recovers it, stderr() uses it."""
    rng = np.random.default_rng(5)
    r = readings(cal, rng, 120)
    est = cal.forces(r)[0]
    sigma = np.sqrt(FLOOR**2 + (RELATIVE * est[..., 2:]) ** 2)
    truth = est - rng.normal(size=est.shape) * sigma
    v = cal.validated(r, truth, source="known law")
    assert v.error_model.source == "known law" and v.error_model.samples == 120 * len(cal.g)
    np.testing.assert_allclose(v.error_model.floor_n, FLOOR, rtol=0.25, atol=0)
    np.testing.assert_allclose(v.error_model.relative, RELATIVE, rtol=0.1, atol=0.001)
    assert cal.error_model is None and v.g is cal.g  # the curves are kept, the original unchanged
    # fresh frames of the same law: the error bars cover 90 %
    r2 = readings(cal, rng, 300)
    est2 = cal.forces(r2)[0]
    truth2 = est2 - rng.normal(size=est2.shape) * np.sqrt(FLOOR**2 + (RELATIVE * est2[..., 2:]) ** 2)
    np.testing.assert_allclose(coverage(est2, truth2, v.stderr(r2)), 0.9, rtol=0, atol=0.02)
    assert np.all(np.abs(coverage(est2, truth2, cal.stderr(r2)) - 0.9) > 0.05)  # the fit residuals are not
    back = Calibration.load(v.save(tmp_path / "cal.json"))
    np.testing.assert_array_equal(back.error_model.floor_n, v.error_model.floor_n)
    np.testing.assert_array_equal(back.stderr(r2), v.stderr(r2))


def test_validated_refuses_mismatched_forces(cal):
    r = readings(cal, np.random.default_rng(6), 3)
    with pytest.raises(ShapeError, match=r"\(T, E, 3\)"):
        cal.validated(r, np.zeros((3, len(cal.g), 2)))


def test_malformed_error_model_in_a_file_is_refused(cal):
    d = cal.to_dict()
    d["error_model"] = {"floor_n": {"fx": "0.1", "fy": 0, "fz": 0}, "relative": {"fx": 0, "fy": 0, "fz": 0},
                        "samples": 10}
    with pytest.raises(InputError, match="error_model"):
        Calibration.from_dict(d)


def test_fit_recovers_a_part_of_second_order_in_the_shear_for_fz():
    """sigma_z^2 = s^2 + a^2 + (b Fz)^2 + (d Ft^2)^2: d comes back for Fz (QUADRATIC_SHEAR), and the
    linear shear part it leaves is small; Fx and Fy have no second-order part; files round-trip it."""
    from optitact.calib.error_model import QUADRATIC_SHEAR

    assert QUADRATIC_SHEAR == (False, False, True)
    rng = np.random.default_rng(12)
    n = 60000
    fz, ft = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 0.5, n)
    shear2 = np.array([0.0, 0.0, 0.08])
    s = rng.uniform(0.0, 0.002, (n, 3))
    sigma = np.sqrt(s**2 + FLOOR**2 + (RELATIVE * fz[:, None]) ** 2 + (shear2 * ft[:, None] ** 2) ** 2)
    m = ErrorModel.fit(rng.normal(size=(n, 3)) * sigma, s, fz, ft)
    assert m.shear2[2] == pytest.approx(0.08, rel=0.1) and m.shear2[0] == m.shear2[1] == 0.0
    assert m.shear[2] < 0.004  # against the 0.02 N a linear part would need at Ft = 0.25 N
    np.testing.assert_allclose(m.sigma(fz[:5], ft[:5]), np.sqrt(sigma[:5] ** 2 - s[:5] ** 2), rtol=0.1)
    back = ErrorModel.from_dict(m.to_dict())
    np.testing.assert_array_equal(back.shear2, m.shear2)
    old = {k: v for k, v in m.to_dict().items() if k != "shear2"}  # a file written before the part
    assert not ErrorModel.from_dict(old).shear2.any()
    with pytest.raises(InputError, match=">= 0"):
        ErrorModel(FLOOR, RELATIVE, 10, shear2=[0.0, 0.0, -0.1])


def test_fit_recovers_a_scale_per_group_of_elements():
    """sigma^2 = s^2 + k_g^2 (a^2 + (b Fz)^2): the groups' k come back (normalised to a mean square of 1 over
    the samples), a group with too few samples takes the largest group's, and at() applies them per element."""
    from optitact.calib.error_model import MIN_GROUP_SAMPLES

    rng = np.random.default_rng(21)
    n_el, n = 41, 60000
    group = np.array([0] + [1] * 8 + [2] * 16 + [3] * 16)  # rings of the dome
    k = np.array([[0.5, 0.4, 0.7], [0.5, 0.4, 0.7], [1.0, 1.0, 1.0], [1.4, 1.6, 1.2]])
    element = rng.integers(0, n_el, n)
    fz = rng.uniform(0.0, 1.0, n)
    s = rng.uniform(0.0, 0.002, (n, 3))
    model = np.sqrt(FLOOR**2 + (RELATIVE * fz[:, None]) ** 2) * k[group[element]]
    res = rng.normal(size=(n, 3)) * np.sqrt(s**2 + model**2)
    m = ErrorModel.fit(res, s, fz, element=element, element_group=group)
    norm = np.sqrt(np.mean(k[group[element]] ** 2, axis=0))
    np.testing.assert_allclose(m.element_scale, k[group] / norm, rtol=0.06)
    np.testing.assert_allclose(m.floor_n * m.element_scale[0], FLOOR * k[0], rtol=0.15)
    np.testing.assert_allclose(m.relative * m.element_scale[-1], RELATIVE * k[3], rtol=0.06, atol=0.001)
    forces = np.zeros((2, n_el, 3))
    forces[..., 2] = 0.5
    np.testing.assert_allclose(m.at(forces), m.sigma(np.full((2, n_el), 0.5)) * m.element_scale, rtol=1e-12)
    with pytest.raises(ShapeError, match=r"\(\.\.\., 41, 3\)"):
        m.at(forces[:, :40])
    back = ErrorModel.from_dict(m.to_dict())
    np.testing.assert_array_equal(back.element_scale, m.element_scale)
    old = {key: v for key, v in m.to_dict().items() if key != "element_scale"}  # a file from before
    assert ErrorModel.from_dict(old).element_scale is None
    # ring 0 with fewer samples than MIN_GROUP_SAMPLES: no scale of its own, the largest group's
    few = (group[element] != 0) | (np.cumsum(group[element] == 0) < MIN_GROUP_SAMPLES)
    m2 = ErrorModel.fit(res[few], s[few], fz[few], element=element[few], element_group=group)
    ref = np.argmax(np.bincount(group[element[few]]))
    np.testing.assert_array_equal(m2.element_scale[0], m2.element_scale[np.flatnonzero(group == ref)[0]])


def test_element_groups_are_checked():
    res, s, fz, _ = draw(np.random.default_rng(3), 100)
    with pytest.raises(InputError, match="both element and element_group"):
        ErrorModel.fit(res, s, fz, element=np.zeros(100, int))
    with pytest.raises(ShapeError, match="index element_group"):
        ErrorModel.fit(res, s, fz, element=np.full(100, 5), element_group=np.zeros(3, int))
    with pytest.raises(ShapeError, match="integers"):
        ErrorModel.fit(res, s, fz, element=np.zeros(100), element_group=np.zeros(3, int))
    with pytest.raises(InputError, match="> 0"):
        ErrorModel(FLOOR, RELATIVE, 10, element_scale=np.zeros((41, 3)))
    with pytest.raises(ShapeError, match=r"\(E, 3\)"):
        ErrorModel(FLOOR, RELATIVE, 10, element_scale=np.ones(41))


def test_validated_measures_a_scale_per_ring(cal):
    """A known law whose model error is twice as large on the outer ring: validated() finds it per ring."""
    rng = np.random.default_rng(9)
    r = readings(cal, rng, 150)
    est = cal.forces(r)[0]
    ring = cal.sensor.element_ring
    k = np.where(ring == ring.max(), 2.0, 1.0)[:, None]
    truth = est - rng.normal(size=est.shape) * np.sqrt(FLOOR**2 + (RELATIVE * est[..., 2:]) ** 2) * k
    v = cal.validated(r, truth, source="rings").error_model
    outer, inner = v.element_scale[ring == ring.max()], v.element_scale[ring != ring.max()]
    np.testing.assert_allclose(outer.mean(axis=0) / inner.mean(axis=0), 2.0, rtol=0.1)
    assert np.all(outer == outer[0]) and len(np.unique(v.element_scale[:, 0])) == len(np.unique(ring))
