"""Calibration fits: exact data at any scale, degenerate sets refused by name, readings beyond the range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import strategies as st
from optitact.calib.curves import EXTRAPOLATE
from optitact.calib.fit import Calibration

from optitact.errors import InputError, ShapeError
from optitact.pipeline.readings import Readings

from .helpers import LONE, SMALL, coupled_set
from .strategies import counted, rng_of, seeds, stress

_W = {"exact": 3, "degenerate": 5, "clamp": 2}
SHARE = {k: v / sum(_W.values()) for k, v in _W.items()}


def fit(readings, forces, model="coupled"):
    return Calibration.fit(readings, forces, sensor=LONE, camera=SMALL, model=model)


def with_(r, G=None, u=None):
    return Readings(r.G if G is None else G, r.u if u is None else u, r.contact, r.saturated)


@stress("calibration_fit", SHARE["exact"], f_exp=st.floats(-3, 3), g_exp=st.floats(-6, 6), seed=seeds,
        model=st.sampled_from(["coupled", "ohka"]), n=st.integers(30, 80))
def test_fit_is_exact_at_any_scale(f_exp, g_exp, seed, model, n):
    rng = rng_of(seed)
    f, r = coupled_set(rng, n, f_scale=10**f_exp, gain=10**g_exp, h=float(rng.uniform(1, 5)),
                       c=float(rng.uniform(0, 0.5)))
    cal = fit(r, f, model)
    est, clamped = cal.forces(r)
    assert np.isfinite(est).all() and not clamped.any()
    if model == "coupled":
        np.testing.assert_allclose(est, f, rtol=0, atol=1e-5 * np.abs(f).max())
    else:
        np.testing.assert_allclose(est[..., 2], f[..., 2], rtol=0, atol=1e-4 * float(f[..., 2].max()))


@stress("calibration_fit", SHARE["degenerate"], seed=seeds, model=st.sampled_from(["coupled", "ohka"]),
        kind=st.sampled_from(["duplicates", "constant", "too_few", "ill_conditioned", "no_shear", "non_finite",
                              "bad_types"]))
def test_degenerate_sets_are_refused_by_name(seed, model, kind):
    rng = rng_of(seed)
    n = int(rng.integers(10, 80))
    forces, r = coupled_set(rng, n, gain=float(10 ** rng.uniform(-5, 5)), h=float(rng.uniform(1, 5)),
                            c=float(rng.uniform(0, 0.5)))
    which = int(rng.integers(3))
    if kind == "duplicates":
        k = int(rng.integers(1, 4))
        idx = rng.integers(0, k, n)
        with pytest.raises(InputError, match="element 0.*" + ("do not vary" if k == 1 else "distinct")):
            fit(r[idx], forces[idx], model)
    elif kind == "constant":
        if which == 2:
            f2 = forces.copy()
            f2[..., 2] = 0.5
            with pytest.raises(InputError, match="normal forces.*spans"):
                fit(r, f2, model)
        else:
            bad = with_(r, G=np.full_like(r.G, 7.0)) if which == 0 else with_(r, u=np.zeros_like(r.u) + 0.3)
            with pytest.raises(InputError, match="do not vary"):
                fit(bad, forces, model)
    elif kind == "too_few":
        m = int(rng.integers(0, 8))
        with pytest.raises(InputError, match=f"{m} usable samples.*at least 8"):
            fit(r[:m], forces[:m], model)
    elif kind == "ill_conditioned":
        eps = float(10 ** rng.uniform(-13, -7))
        bad = with_(r, G=1000.0 * (1.0 + eps * rng.random(r.G.shape))) if which else \
            with_(r, u=5.0 + eps * 5.0 * rng.random(r.u.shape))
        with pytest.raises(InputError, match="ill-conditioned"):
            fit(bad, forces, model)
    elif kind == "no_shear":
        f2 = forces.copy()
        f2[..., :2] = 0.0
        with pytest.raises(InputError, match="shear"):
            fit(r, f2, model)
    elif kind == "non_finite":
        bad = float(rng.choice([np.nan, np.inf, -np.inf]))
        if which == 0:
            f2 = forces.copy()
            f2[int(rng.integers(n)), 0, int(rng.integers(3))] = bad
            with pytest.raises(InputError, match="finite"):
                fit(r, f2, model)
        elif which == 1:
            g = r.G.copy()
            g[int(rng.integers(n)), 0] = bad
            with pytest.raises(InputError, match="finite"):
                fit(with_(r, G=g), forces, model)
        else:
            u = r.u.copy()
            u[0, 0, int(rng.integers(2))] = bad
            with pytest.raises(InputError, match="finite"):
                fit(r, forces, model).forces(with_(r, u=u)[0])
    elif which == 0:
        with pytest.raises(TypeError, match="forces.*complex"):
            fit(r, forces.astype(complex), model)
    elif which == 1:
        with pytest.raises(TypeError, match="stack Readings"):
            fit(r[0], forces[0], model)
    else:
        with pytest.raises(ShapeError, match="forces must have shape"):
            fit(r, forces[:-1], model)


@counted("calibration_fit")
def test_fit_errors_duplicates_constant_and_ill_conditioned():
    f, r = coupled_set(np.random.default_rng(0), 40)
    idx = np.arange(40) % 3
    with pytest.raises(InputError, match="element 0: 3 distinct G values .duplicate points.; "
                                         "the cubic g.G. needs at least 4"):
        fit(r[idx], f[idx])
    g = 1000.0 * (1 + 1e-10 * np.random.default_rng(1).random(r.G.shape))
    with pytest.raises(InputError, match="element 0: G spans .* relative spread above 1e-06 "
                                         ".an ill-conditioned"):
        fit(with_(r, G=g), f)
    fz = f.copy()
    fz[..., 2] = 0.4
    with pytest.raises(InputError, match="the normal forces Fz spans 0 around a magnitude of 0.4"):
        fit(r, fz)
    f0 = f.copy()
    f0[..., :2] = 0.0
    with pytest.raises(InputError, match="no sample has shear"):
        fit(r, f0, model="ohka")


@counted("calibration_fit")
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_fit_and_forces_refuse_non_finite_readings(bad):
    f, r = coupled_set(np.random.default_rng(0), 20)
    g = r.G.copy()
    g[3, 0] = bad
    with pytest.raises(InputError, match=f"readings.G must be finite, got {bad}"):
        fit(with_(r, G=g), f)
    cal = fit(r, f)
    u = r.u.copy()
    u[0, 0, 1] = bad
    with pytest.raises(InputError, match="readings.u must be finite"):
        cal.forces(with_(r, u=u))
    with pytest.raises(InputError, match="readings.G must be >= 0, got -1.0"):
        cal.forces(Readings(-r.G[:1] * 0 - 1.0, r.u[:1], r.contact[:1], r.saturated[:1]))
    with pytest.raises(TypeError, match="forces must be a real numeric array .N., got dtype complex128"):
        fit(r, f.astype(complex))


@pytest.fixture(scope="module")
def clamp_cal():
    return fit(*reversed(coupled_set(np.random.default_rng(0), 30)))


@stress("calibration_fit", SHARE["clamp"], k_g=st.floats(0.0, 1e6),
        k_u=st.floats(0.0, 1e6),
        ang=st.floats(0, 2 * np.pi))
def test_forces_beyond_the_fitted_range_are_clamped_and_flagged(clamp_cal, k_g, k_u, ang):
    cal = clamp_cal
    G = np.array([cal.g_max * k_g])
    u = np.array([[[math.cos(ang), math.sin(ang)]]]) * (cal.u_max * k_u)
    est, clamped = cal.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    assert np.isfinite(est).all() and np.all(est[..., 2] >= 0)
    assert clamped[0, 0] == (G[0, 0] > 0 and (k_g > 1 or k_u > 1))
    # G holds a quarter beyond g_max (the curve's tangent up to there), u at u_max
    edge = Readings(np.minimum(G, cal.g_max * (1.0 + EXTRAPOLATE)), u * (1.0 if k_u <= 1 else 1.0 / k_u), G > 0,
                    np.zeros_like(G, bool))
    np.testing.assert_allclose(est, cal.forces(edge)[0], rtol=1e-9, atol=1e-12)


def test_forces_of_a_subnormal_centroid(clamp_cal):
    """Found by the stress cases at 10,000: the clamp divided u_max by every radius (overflow warning)."""
    u = np.array([[[5e-324 * float(clamp_cal.u_max[0]), 0.0]]])
    G = np.zeros((1, 1))
    est, clamped = clamp_cal.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    assert np.isfinite(est).all() and not clamped.any()
