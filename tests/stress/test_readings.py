"""Readings at their edges: analytic spots (inside, on the border), vanishing G, raw moments, the threshold."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from optitact.pipeline.imageops import G_MIN, readings_from_moments

from .helpers import N_EL, SMALL, assert_same, assert_sane, spot_tolerance
from .strategies import counted, rng_of, seeds, stress

_W = {"spot": 4, "spot_on_border": 3, "vanishing": 2, "moments": 2, "raw_moments": 1, "near_threshold": 2}
SHARE = {k: v / sum(_W.values()) for k, v in _W.items()}


def _spot_vs_truth(ctx, e, c, s, a, pipe):
    r = pipe.process(ctx.spot(e, c, s, a))
    assert_sane(r, pipe)
    g_true, m_true = ctx.spot_truth(e, c, s, a, pipe)
    tol = spot_tolerance(a * 2 * np.pi * s * s, s, float(ctx.footprint[e]))
    np.testing.assert_allclose(r.G[e], g_true, rtol=0, atol=tol, err_msg=f"G of a spot at {c} (s={s})")
    # first moments: the same bound times the farthest lever arm in the region
    np.testing.assert_allclose(r.u[e] * r.G[e], m_true, rtol=0, atol=tol * pipe.grids.radius,
                               err_msg=f"first moments of a spot at {c} (s={s})")


@stress("readings", SHARE["spot"], e=st.integers(0, N_EL - 1), s=st.floats(0.45, 0.7),
        cx=st.floats(-0.7, 0.7), cy=st.floats(-0.7, 0.7), a_exp=st.floats(0, 3))
def test_spot_reads_its_integral_over_the_region(ctx, e, s, cx, cy, a_exp):
    _spot_vs_truth(ctx, e, (cx, cy), s, 10.0**a_exp, ctx.pipeline(noise_sigma=0.0))


@stress("readings", SHARE["spot_on_border"], e=st.integers(0, N_EL - 1), s=st.floats(0.45, 0.7),
        off=st.floats(-2, 2), phi=st.floats(0, 2 * np.pi))
def test_spot_on_the_region_border_follows_the_cut_region(ctx, e, s, off, phi):
    """A spot centred near the region's edge (radius +- 2 s): G and moments follow the cut region."""
    pipe = ctx.pipeline(noise_sigma=0.0)
    rho = pipe.grids.radius + off * s
    _spot_vs_truth(ctx, e, rho * np.array([math.cos(phi), math.sin(phi)]), s, 100.0, pipe)


@stress("readings", SHARE["vanishing"], seed=seeds, e=st.integers(0, N_EL - 1),
        ks=st.lists(st.integers(0, 1070), min_size=1, max_size=6))
def test_vanishing_g_keeps_the_centroid(ctx, seed, e, ks):
    """G -> 0: the centroid stays put (no division blow-up) until G_MIN, then no contact, never NaN."""
    rng = rng_of(seed)
    img = ctx.spot(e, rng.uniform(-0.5, 0.5, 2), float(rng.uniform(0.45, 0.7)), 1.0)
    pipe = ctx.pipeline(noise_sigma=0.0)
    ref = pipe.process(img)
    for k in sorted(ks):
        r = pipe.process(np.ldexp(img, -k))
        assert_sane(r, pipe)
        g = ref.G[e] * 2.0**-k
        if g > 1e-240:
            assert r.contact[e], f"G = {g:.3g} must read contact on a noiseless pipeline"
            np.testing.assert_allclose(r.u[e], ref.u[e], rtol=0, atol=1e-12)
        elif g < G_MIN * 1e-3:
            assert not r.contact[e], f"G = {r.G[e]:.3g} (subnormal sums) reads contact"


@counted("readings")
def test_centroid_near_vanishing_g_does_not_blow_up(ctx):
    img = ctx.spot(20, (0.3, 0.1), 0.6, 1.0)
    p0 = ctx.pipeline(noise_sigma=0.0)
    ref = p0.process(img)
    for k in (0, 200, 600, 820, 1000, 1060, 1080):
        r = p0.process(np.ldexp(img, -k))
        assert_sane(r, p0)
        if ref.G[20] * 2.0**-k > 1e-240:
            np.testing.assert_allclose(r.u[20], ref.u[20], rtol=0, atol=1e-12)
        if ref.G[20] * 2.0**-k < 1e-253:
            assert not r.contact[20]


POOL = [0.0, -0.0, 5e-324, 1e-310, G_MIN, 1e-240, 1e-200, 1.0, 1e150, 1e300, -1.0, 3.0]


@stress("readings", SHARE["moments"], seed=seeds, t=st.integers(1, 3), frac=st.sampled_from([None, "mixed"]))
def test_readings_from_moments_of_any_sums(seed, t, frac):
    """readings_from_moments on sums from zero through subnormal to huge: contact rule exact, never NaN."""
    rng = rng_of(seed)
    shape = (t, 5)
    G = rng.choice(POOL, shape)
    W = None if frac is None else G * rng.choice([1.0, 0.5, 1e-10, 0.0], shape)
    u0 = rng.uniform(-2, 2, shape + (2,))
    M = (G if W is None else W)[..., None] * u0
    floor = rng.choice([0.0, 0.5, 1e-300], 5)
    r = readings_from_moments(G, M, np.zeros(shape, bool), floor, weight=W)
    assert np.isfinite(r.G).all() and np.isfinite(r.u).all()
    want = (G > floor) & (G > G_MIN)
    np.testing.assert_array_equal(r.contact, want, err_msg="contact must be G > floor and G > G_MIN")
    good = want & ((G if W is None else W) > 1e-290)
    np.testing.assert_allclose(r.u[good], u0[good], rtol=1e-12, atol=0)
    assert np.all(r.u[~want] == 0) and np.all(r.G[~want] == 0)


@stress("readings", SHARE["raw_moments"],
        G=hnp.arrays(np.float64, 6, elements=st.sampled_from([0.0, 5e-324, 1e-300, G_MIN, 1e-200, 1.0, 1e300])),
        frac=st.sampled_from([1.0, 0.3, 0.0]),
        u0=st.floats(-2.2, 2.2).filter(lambda x: x == 0 or abs(x) > 1e-6))
def test_readings_from_moments_never_blow_up(G, frac, u0):
    w = G * frac
    M = np.stack([w * u0, -w * u0], -1)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        r = readings_from_moments(G, M, np.zeros(6, bool), np.zeros(6), weight=w)
    assert np.isfinite(r.u).all()
    np.testing.assert_array_equal(r.contact, G > G_MIN)
    good = r.contact & (w > 1e-290)
    np.testing.assert_allclose(r.u[good], np.tile([u0, -u0], (good.sum(), 1)), rtol=1e-12, atol=0)
    assert np.all(r.u[~r.contact] == 0)


@stress("readings", SHARE["near_threshold"], seed=seeds, sigma=st.floats(0.3, 2.0),
        filt=st.sampled_from(["none", "gaussian"]), dtype=st.sampled_from([np.float64, np.float32]))
def test_spots_near_the_threshold(ctx, seed, sigma, filt, dtype):
    """Spots whose peak sits near the threshold, with noise: G is 0 or above the floor, u inside the region."""
    rng = rng_of(seed)
    e = int(rng.integers(N_EL))
    pipe = ctx.pipeline(noise_sigma=sigma, filter=filt)
    img = ctx.spot(e, rng.uniform(-1.5, 1.5, 2), float(rng.uniform(0.3, 0.8)),
                   pipe.threshold * rng.uniform(0.5, 3))
    stack = (img + rng.normal(0.0, pipe.noise_sigma, (4,) + img.shape)).astype(dtype)
    r = pipe.process(stack)
    assert_sane(r, pipe)
    assert_same(r, pipe.replace(method="reference").process(stack), g_rtol=1e-9, u_atol=1e-9)


@counted("readings")
def test_centroid_weighs_lit_values_by_their_height_above_the_threshold(ctx):
    """Independent route: a noiseless pipeline on the hand-thresholded frame gives the same G and u."""
    rng = np.random.default_rng(8)
    img = ctx.spot(9, (0.4, -0.3), 0.5, 30.0) + ctx.spot(9, (-0.8, 0.5), 0.4, 12.0)
    img += rng.normal(0.0, 1.0, img.shape)
    p = ctx.pipe.replace(noise_sigma=1.0)
    t = p.threshold
    r = p.process(img)
    p0 = ctx.pipe.replace(noise_sigma=0.0)
    lit = img > t
    np.testing.assert_allclose(r.G[9], p0.process(np.where(lit, img, 0.0)).G[9], rtol=1e-12)
    np.testing.assert_allclose(r.u[9], p0.process(np.where(lit, img - t, 0.0)).u[9], rtol=0, atol=1e-12)
    plain = p0.process(np.where(lit, img, 0.0)).u[9]
    assert np.hypot(*(r.u[9] - plain)) > 1e-3  # the two weightings differ on this asymmetric pair
    assert_same(r, p.replace(method="reference").process(img), g_rtol=1e-12, u_atol=1e-12)
    assert SMALL.shape == img.shape
