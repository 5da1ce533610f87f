"""Plane resultants, decoupling, ranges, the calibrated matrix and the repeatability error."""


import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.decoupling import (
    DecouplingMatrix,
    axis_ranges,
    decouple,
    detection_ranges,
    plane_resultants,
    repeatability_error,
)
from optitact.taxels.fingertip25 import PLANE_AXIS, UNIT_SIDE, Fingertip25, Fingertip25Config
from optitact.taxels.sources import Indenter, Scenario

PUBLISHED_ANGLES = (0.0, 77.25, 62.09, 46.47, 9.03)
PUBLISHED_UNITS = (8, 4, 2, 2, 3)


@pytest.fixture
def quiet(fingertip_quiet):
    """Noise- and scatter-free sensor without crosstalk (session fixture)."""
    return fingertip_quiet


def scenario(force, direction=(0.0, 0.0, 1.0), n=5, rate=100.0):
    return Scenario(Indenter("point"), t_s=np.arange(n) / rate, force_n=force, extra={"direction": direction})


def test_detection_ranges_from_the_formula():
    r = detection_ranges()
    n = np.array(PUBLISHED_UNITS, dtype=float)
    factor = n * np.cos(np.radians(PUBLISHED_ANGLES))                    # independent: n_k cos(theta_k)
    np.testing.assert_allclose(r["low_n"], 0.2 * factor, rtol=1e-12, atol=0)
    np.testing.assert_allclose(r["high_n"], 5.0 * factor, rtol=1e-12, atol=0)
    assert r["axis"].tolist() == list(PLANE_AXIS)
    assert (r["low_n"][0], r["high_n"][0]) == pytest.approx((1.6, 40.0), abs=1e-12)   # F1 = 8 F_s
    assert r["low_n"][1] == pytest.approx(0.17, abs=0.01) and r["high_n"][1] == pytest.approx(4.41, abs=0.005)
    wide = detection_ranges(config=Fingertip25Config(force_high_n=10.0, r_high_kohm=0.5))
    np.testing.assert_allclose(wide["high_n"], 10.0 * factor, rtol=1e-12, atol=0)
    ax = axis_ranges()
    assert ax["x"][1] == pytest.approx(r["high_n"][1] + r["high_n"][2], rel=1e-12)


def test_plane_resultants_match_published_formula():
    fs = 1.7
    units = np.where(UNIT_SIDE > 0, fs, 0.0)                              # every + side unit reads F_s
    res = plane_resultants(units)
    cos = np.cos(np.radians(PUBLISHED_ANGLES))
    expect = [8 * fs, 4 * fs * cos[1], 2 * fs * cos[2], 2 * fs * cos[3], 3 * fs * cos[4]]
    np.testing.assert_allclose([res[f"F{k}"] for k in range(1, 6)], expect, rtol=1e-12, atol=0)
    mirrored = plane_resultants(np.where(UNIT_SIDE < 0, fs, 0.0))
    assert mirrored["F2"] == pytest.approx(-4 * fs * cos[1], rel=1e-12)


def test_decouple_inverts_the_design_model(quiet):
    rng = np.random.default_rng(0)
    forces = rng.uniform([-8.0, 0.0, 2.0], [8.0, 20.0, 38.0], size=(50, 3))
    np.testing.assert_allclose(decouple(quiet.unit_forces(forces)), forces, rtol=0, atol=1e-12)
    # through the whole chain (kOhm frames, threshold, 0.2 N quantisation): each unit is off by <= 0.1 N
    f = np.array([3.0, 6.0, 17.0])
    frames = quiet.frames(scenario(np.linalg.norm(f), direction=f, n=3), seed=0)
    est = decouple(frames[-1], units="kOhm")
    bound = 0.1 * np.array([2 * (4 + 2), 2 + 3, 8])                     # units per axis x 0.1 N
    assert np.all(np.abs(est - f) <= bound)
    assert decouple(np.zeros((2, 3, 5, 5), dtype=np.float32)).dtype == np.float32
    with pytest.raises(ShapeError, match=r"values must have shape \(..., 5, 5\)"):
        decouple(np.zeros((5, 4)))
    with pytest.raises(InputError, match="units must be one of"):
        decouple(np.zeros((5, 5)), units="ohm")
    with pytest.raises(InputError, match="unit forces must be >= 0"):
        decouple(-np.ones((5, 5)))


def test_crosstalk_cancels_on_x_and_is_removed_by_calibration():
    src = Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0, crosstalk=0.1))
    pure_z = decouple(src.unit_forces([0.0, 0.0, 20.0]))
    assert pure_z[0] == pytest.approx(0.0, abs=1e-12) and pure_z[2] == pytest.approx(20.0, abs=1e-12)
    assert pure_z[1] > 0.1                                               # y planes feel the normal force
    rng = np.random.default_rng(1)
    forces = rng.uniform([-6.0, 0.0, 2.0], [6.0, 15.0, 30.0], size=(80, 3))
    units = src.unit_forces(forces)
    m = DecouplingMatrix.fit(units[:60], forces[:60])
    err_cal = np.abs(m.apply(units[60:]) - forces[60:]).max()
    err_pub = np.abs(decouple(units[60:]) - forces[60:]).max()
    assert err_cal < 1e-8 < err_pub                                      # the model is linear in the domain
    with pytest.raises(ShapeError, match="at least 26 loads"):
        DecouplingMatrix.fit(units[:10], forces[:10])
    with pytest.raises(ShapeError, match=r"matrix must have shape \(3, 25\)"):
        DecouplingMatrix(np.zeros((3, 24)), np.zeros(3))


def test_repeatability_error_on_known_data():
    # s = 1 at the first point, 0 at the second: 3 * 1 / 100 * 100 % = 3 %
    assert repeatability_error([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]], 100.0) == pytest.approx(3.0, abs=1e-12)
    x = np.random.default_rng(0).normal(10.0, 0.2, size=(12, 4))
    expect = 3 * x.std(axis=0, ddof=1).max() / 50.0 * 100
    assert repeatability_error(x, 50.0) == pytest.approx(expect, rel=1e-12)
    assert repeatability_error(x[:, 0], 50.0, z=2.0) == pytest.approx(2 * x[:, 0].std(ddof=1) * 2, rel=1e-12)
    with pytest.raises(ShapeError, match="n >= 2 repetitions"):
        repeatability_error([[1.0, 2.0]], 10.0)
    with pytest.raises(InputError, match="full_scale must be finite and > 0"):
        repeatability_error([1.0, 2.0], 0.0)
    with pytest.raises(InputError, match="samples must be finite"):
        repeatability_error([1.0, np.nan], 1.0)
