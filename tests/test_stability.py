"""Numerical stability and bad input (issue 6): property-based stress tests of every stage.

Each stage must give the right answer -- against an independent truth: the
``"reference"`` method, ``math.fsum``, an exact power-of-two rescaling, a
noiseless pipeline on a hand-thresholded frame -- or raise a documented
``ValueError``/``TypeError`` subclass whose message names what was expected.
Hypothesis draws the inputs (derandomized, so CI is deterministic); frames are
built with NumPy from drawn parameters, which keeps a 160x120 frame cheap.
"""

from __future__ import annotations

import json
import math
import pickle
import re
import sys
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import optitact
from optitact.calib import Calibration, CalibrationMismatchError
from optitact.ccd import CCD, MAX_FULL_WELL
from optitact.contact import MAX_FORCE_N, check_forces, contact_patches
from optitact.errors import InputError, ShapeError
from optitact.io import ReadingsWriter
from optitact.pipeline import G_MIN, MAX_GREY, Pipeline, estimate_noise, readings_from_moments
from optitact.readings import Readings
from optitact.stability import (CATEGORIES, Case, CaseFailure, _Touch, flicker_check, generate_cases,
                                noise_sweep, run_case, run_stability)

SENSOR = optitact.DomeSensor.default()
SMALL = optitact.FisheyeCamera(width=160, height=120)
LONE = optitact.DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,))
H, W = SMALL.shape
N_EL = SENSOR.n_elements

PROPS = settings(max_examples=40, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def pipe():
    return Pipeline(SENSOR, SMALL)


@pytest.fixture(scope="module")
def dome_xy():
    """Element-local tangent offsets of every pixel's dome point, per element (lazily)."""
    pts = SMALL.unproject(np.stack(np.mgrid[0:H, 0:W], -1).astype(np.float64), SENSOR, outside="nan")
    cache = {}

    def get(e):
        if e not in cache:
            cache[e] = SENSOR.tangent_offset(np.full(SMALL.shape, e), pts)
        return cache[e]
    return get


def spot(dome_xy, e, c, s, a):
    d2 = np.sum((dome_xy(e) - np.asarray(c)) ** 2, axis=-1)
    out = np.zeros(SMALL.shape)
    near = np.isfinite(d2) & (d2 <= 36 * s * s)
    out[near] = a * np.exp(-d2[near] / (2 * s * s))
    return out


def assert_sane(r, p):
    assert np.isfinite(r.G).all() and np.isfinite(r.u).all() and np.all(r.G >= 0)
    assert np.all(r.G[~r.contact] == 0) and np.all(r.u[~r.contact] == 0)
    assert np.all(np.hypot(r.u[..., 0], r.u[..., 1]) <= p.grids.radius * (1 + 1e-9))


def assert_same(a, b, *, g_rtol=0.0, u_atol=0.0):
    np.testing.assert_array_equal(a.contact, b.contact)
    np.testing.assert_array_equal(a.saturated, b.saturated)
    np.testing.assert_allclose(a.G, b.G, rtol=g_rtol, atol=0)
    np.testing.assert_allclose(a.u, b.u, rtol=0, atol=u_atol)


# ---------------------------------------------------------------------------- frames
FRAME_DTYPES = [np.uint8, np.uint16, np.int16, np.int64, np.uint64, np.float16, np.float32, np.float64,
                np.longdouble]


@PROPS
@given(dtype=st.sampled_from(FRAME_DTYPES), seed=st.integers(0, 2**32 - 1),
       scale=st.sampled_from([0.0, 1e-30, 1e-3, 1.0, 255.0, 65535.0, 1e30]),
       n_spots=st.integers(0, 4), t_n=st.integers(1, 3), filt=st.sampled_from(["none", "gaussian", "median"]),
       sigma=st.sampled_from([0.0, 0.5, 2.0]),
       special=st.sampled_from([None, "nan", "inf", "neg", "huge", "hot"]))
def test_any_frame_gives_readings_or_a_documented_error(pipe, dome_xy, dtype, seed, scale, n_spots, t_n, filt,
                                                        sigma, special):
    rng = np.random.default_rng(seed)
    img = np.zeros((t_n, H, W))
    for e in rng.choice(N_EL, n_spots, replace=False):
        img += spot(dome_xy, int(e), rng.uniform(-1, 1, 2), rng.uniform(0.4, 0.8), rng.uniform(0.1, 1.0))
    img = img * scale
    info = np.finfo(dtype) if np.dtype(dtype).kind == "f" else np.iinfo(dtype)
    frames = np.clip(img, 0, min(float(info.max), 2.0**53)).astype(dtype)
    t, r, c = int(rng.integers(t_n)), int(rng.integers(H)), int(rng.integers(W))
    p = pipe.replace(filter=filt, noise_sigma=sigma)
    kind = np.dtype(dtype).kind
    if special == "hot" or (special in ("nan", "inf", "huge") and kind != "f") \
            or (special == "neg" and kind != "i"):
        frames[t, r, c] = info.max if kind in "ui" else 1e4
    elif special is not None:
        bad = {"nan": np.nan, "inf": np.inf, "neg": -1, "huge": min(float(info.max), 1e300)}
        frames[t, r, c] = bad[special]
    before = frames.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            res = p.process(frames)
        except InputError as exc:
            where = f"frame {t}, pixel (row {r}, col {c})"
            assert (special == "nan" and "finite" in str(exc) and where in str(exc)) \
                or (special == "inf" and "finite" in str(exc)) \
                or (special == "huge" and ("magnitude at most" in str(exc) or "finite" in str(exc))) \
                or (special == "neg" and "non-negative" in str(exc) and where in str(exc)), str(exc)
            return
        ref = p.replace(method="reference").process(frames)
    np.testing.assert_array_equal(frames, before)
    assert special not in ("nan", "inf") or kind != "f"
    assert_sane(res, p)
    assert_same(res, ref, g_rtol=1e-9, u_atol=1e-9 * max(1.0, float(np.abs(res.G).max())))


@PROPS
@given(k=st.integers(-900, 330), e=st.integers(0, N_EL - 1), seed=st.integers(0, 2**16))
def test_power_of_two_scaling_is_exact(pipe, dome_xy, k, e, seed):
    """Noiseless pipeline: frame x 2^k gives G x 2^k bit for bit and the same u, from 1e-270 to 1e99."""
    rng = np.random.default_rng(seed)
    img = spot(dome_xy, e, rng.uniform(-0.5, 0.5, 2), rng.uniform(0.45, 0.7), 1.0)
    p0 = pipe.replace(noise_sigma=0.0)
    base = p0.process(img)
    scaled = np.ldexp(img, k)
    if np.abs(scaled).max() > MAX_GREY:
        with pytest.raises(InputError, match=r"magnitude at most 1e\+100"):
            p0.process(scaled)
        return
    r = p0.process(scaled)
    assert_sane(r, p0)
    if scaled[scaled > 0].min() > 1e-290:  # no subnormal pixel or product: exact
        want = np.ldexp(base.G, k)
        keep = want > G_MIN
        np.testing.assert_array_equal(r.G, np.where(keep, want, 0.0))
        np.testing.assert_array_equal(r.u, np.where(keep[:, None], base.u, 0.0))
    elif r.contact[e]:
        np.testing.assert_allclose(r.u[e], base.u[e], rtol=0, atol=1e-6)


@pytest.mark.parametrize("c", [1e-30, 1e30])
def test_tiny_and_huge_float_frames(pipe, dome_xy, c):
    img = spot(dome_xy, 12, (0.3, -0.2), 0.6, 1.0)
    p0 = pipe.replace(noise_sigma=0.0)
    a, b = p0.process(img), p0.process(img * c)
    np.testing.assert_allclose(b.G, a.G * c, rtol=1e-12, atol=0)
    np.testing.assert_allclose(b.u, a.u, rtol=0, atol=1e-12)
    assert b.contact[12] and a.contact.sum() == b.contact.sum()


def test_float32_and_float64_of_the_same_frame(pipe, dome_xy):
    """Same values in float32 and float64: identical readings, even for values at the threshold itself."""
    rng = np.random.default_rng(3)
    img = spot(dome_xy, 5, (0.1, 0.2), 0.6, 80.0) + rng.normal(0.0, 0.5, SMALL.shape) + 10.0
    f32 = img.astype(np.float32)
    p = pipe.replace(baseline=np.full(SMALL.shape, 10.0))
    # put pixels exactly at, just above and just below the level a float32 rounding would move
    level = np.float32(10.0 + p.threshold)
    f32[60, 70:73] = [level, np.nextafter(level, np.float32(np.inf)), np.nextafter(level, np.float32(0))]
    a, b = p.process(f32), p.process(f32.astype(np.float64))
    assert_same(a, b, g_rtol=1e-15, u_atol=1e-15)
    assert_same(p.replace(method="reference").process(f32), a, g_rtol=1e-12, u_atol=1e-12)
    c = p.process(img)  # the float64 original: within float32 precision
    assert_same(a, c, g_rtol=1e-5, u_atol=2e-5)


@pytest.mark.parametrize("frames,exc,match", [
    (np.full((H, W), 1e101), InputError,
     r"magnitude at most 1e\+100, got 1e\+101 at frame 0, pixel \(row 0, col 0\)"),
    (np.full((2, H, W), -1e200), InputError, r"magnitude at most 1e\+100"),
    ([[0.0] * W] * (H - 1) + [[0.0] * 3], TypeError, "frames must be an array of grey levels"),
    (np.zeros((H, W), "m8[s]"), TypeError, "dtype .*timedelta64"),
])
def test_frame_errors(pipe, frames, exc, match):
    with pytest.raises(exc, match=match):
        pipe.process(frames)


def test_narrow_and_extended_floats_are_accepted(pipe, dome_xy):
    img = spot(dome_xy, 3, (0.0, 0.3), 0.6, 100.0)
    want = pipe.process(img.astype(np.float32))
    assert_same(pipe.process(img.astype(np.float16).astype(np.float32)), pipe.process(img.astype(np.float16)))
    assert_same(pipe.process(img.astype(np.longdouble)), pipe.process(img), g_rtol=1e-15, u_atol=1e-15)
    assert want.contact[3]


def test_float32_frames_with_a_baseline_beyond_float32(pipe):
    """A float64 baseline above float32's range: nothing is lit (no overflow warning on the level)."""
    p = pipe.replace(baseline=np.full(SMALL.shape, 1e39))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = p.process(np.full(SMALL.shape, 3e38, np.float32))
    assert not r.contact.any()


@pytest.mark.parametrize("kwargs,match", [
    (dict(k=1e300, noise_sigma=1e10), r"k \* noise_sigma must be finite"),
    (dict(min_pixels=1e308, k=30.0, noise_sigma=1e10), "noise floor of G overflows"),
    (dict(radius=1e308), "radius must be at most half a great circle of the dome, 62.83.* mm, got 1e\\+308"),
    (dict(radius=2.0, grid_mm=1e308), "grid_mm must be at most the region radius 2 mm, got 1e\\+308"),
])
def test_pipeline_options_that_overflow(kwargs, match):
    with pytest.raises(InputError, match=match):
        Pipeline(SENSOR, SMALL, **kwargs)


# ---------------------------------------------------------------------------- readings at the edge
@PROPS
@given(G=hnp.arrays(np.float64, 6, elements=st.sampled_from([0.0, 5e-324, 1e-300, G_MIN, 1e-200, 1.0, 1e300])),
       frac=st.sampled_from([1.0, 0.3, 0.0]), u0=st.floats(-2.2, 2.2).filter(lambda x: x == 0 or abs(x) > 1e-6))
def test_readings_from_moments_never_blow_up(G, frac, u0):
    w = G * frac
    M = np.stack([w * u0, -w * u0], -1)
    with warnings.catch_warnings(), np.errstate(over="raise", invalid="raise", divide="raise"):
        warnings.simplefilter("error")
        r = readings_from_moments(G, M, np.zeros(6, bool), np.zeros(6), weight=w)
    assert np.isfinite(r.u).all()
    np.testing.assert_array_equal(r.contact, G > G_MIN)
    good = r.contact & (w > 1e-290)
    np.testing.assert_allclose(r.u[good], np.tile([u0, -u0], (good.sum(), 1)), rtol=1e-12, atol=0)
    assert np.all(r.u[~r.contact] == 0)


def test_centroid_weighs_lit_values_by_their_height_above_the_threshold(pipe, dome_xy):
    """Independent route: a noiseless pipeline on the hand-thresholded frame gives the same G and u."""
    rng = np.random.default_rng(8)
    img = spot(dome_xy, 9, (0.4, -0.3), 0.5, 30.0) + spot(dome_xy, 9, (-0.8, 0.5), 0.4, 12.0)
    img += rng.normal(0.0, 1.0, img.shape)
    p = pipe.replace(noise_sigma=1.0)
    t = p.threshold
    r = p.process(img)
    p0 = pipe.replace(noise_sigma=0.0)
    lit = img > t
    np.testing.assert_allclose(r.G[9], p0.process(np.where(lit, img, 0.0)).G[9], rtol=1e-12)
    np.testing.assert_allclose(r.u[9], p0.process(np.where(lit, img - t, 0.0)).u[9], rtol=0, atol=1e-12)
    plain = p0.process(np.where(lit, img, 0.0)).u[9]
    assert np.hypot(*(r.u[9] - plain)) > 1e-3  # the two weightings differ on this asymmetric pair
    assert_same(r, p.replace(method="reference").process(img), g_rtol=1e-12, u_atol=1e-12)


def test_centroid_near_vanishing_g_does_not_blow_up(pipe, dome_xy):
    img = spot(dome_xy, 20, (0.3, 0.1), 0.6, 1.0)
    p0 = pipe.replace(noise_sigma=0.0)
    ref = p0.process(img)
    for k in (0, 200, 600, 820, 1000, 1060, 1080):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            r = p0.process(np.ldexp(img, -k))
        assert_sane(r, p0)
        if ref.G[20] * 2.0**-k > 1e-240:
            np.testing.assert_allclose(r.u[20], ref.u[20], rtol=0, atol=1e-12)
        if ref.G[20] * 2.0**-k < 1e-253:
            assert not r.contact[20]


# ---------------------------------------------------------------------------- noise sweep and flicker
@pytest.fixture(scope="module")
def nominal():
    return noise_sweep(n_frames=240, factors=(1.0,), seed=1)


def test_nominal_centroid_efficiency(nominal):
    """The issue's target: centroid efficiency >= 0.7 against the Cramer-Rao bound at the nominal noise."""
    n = nominal["nominal"]
    assert n["contact_rate"] == 1.0
    assert n["u_efficiency"] >= 0.7
    assert 0.5 <= n["G_efficiency"] <= 1.3
    # the bound is below the photon limit s / sqrt(N) only by the read and quantisation noise
    assert all(b >= n["u"]["simple_bound_mm"] for b in n["u"]["crb_mm"])
    assert all(abs(b) < 3 * s for b, s in zip(n["u"]["bias_mm"], n["u"]["std_mm"], strict=True)) \
        or max(abs(b) for b in n["u"]["bias_mm"]) < 0.001
    assert -0.05 < n["G"]["bias_rel"] < 0  # the threshold drops the rim: G reads a little low


def test_contact_flag_at_the_noise_floor_flickers_as_predicted():
    out = flicker_check(target_rate=0.5, n_frames=240, seed=2, camera=optitact.FisheyeCamera())
    assert out["deterministic"] and out["ok"], out
    assert 0.25 < out["predicted_rate"] < 0.75


# ---------------------------------------------------------------------------- calibration fits
def coupled_set(rng, n, *, f_scale=1.0, gain=120.0, h=3.0, c=0.2):
    fz = rng.uniform(0.05, 1.0, (n, 1)) * f_scale
    mag = rng.uniform(0, 0.35, (n, 1)) * fz
    ang = rng.uniform(0, 2 * np.pi, (n, 1))
    f = np.stack([mag * np.cos(ang), mag * np.sin(ang), fz], -1)
    u = f[..., :2] * (h / fz + c / math.sqrt(f_scale) / np.sqrt(fz))[..., None]
    return f, Readings(gain * fz, u, np.ones((n, 1), bool), np.zeros((n, 1), bool))


@PROPS
@given(f_exp=st.floats(-3, 3), g_exp=st.floats(-6, 6), seed=st.integers(0, 2**16))
def test_coupled_fit_is_exact_at_any_scale(f_exp, g_exp, seed):
    f, r = coupled_set(np.random.default_rng(seed), 30, f_scale=10**f_exp, gain=10**g_exp)
    cal = Calibration.fit(r, f, sensor=LONE, camera=SMALL)
    est, clamped = cal.forces(r)
    np.testing.assert_allclose(est, f, rtol=0, atol=1e-5 * np.abs(f).max())
    assert not clamped.any()


def fit_error(readings, forces, model="coupled"):
    return lambda: Calibration.fit(readings, forces, sensor=LONE, camera=SMALL, model=model)


def test_fit_errors_duplicates_constant_and_ill_conditioned():
    f, r = coupled_set(np.random.default_rng(0), 40)
    idx = np.arange(40) % 3
    with pytest.raises(InputError, match="element 0: 3 distinct G values .duplicate points.; "
                                         "the cubic g.G. needs at least 4"):
        fit_error(r[idx], f[idx])()
    g = 1000.0 * (1 + 1e-10 * np.random.default_rng(1).random(r.G.shape))
    with pytest.raises(InputError, match="element 0: G spans .* relative spread above 1e-06 "
                                         ".an ill-conditioned"):
        fit_error(Readings(g, r.u, r.contact, r.saturated), f)()
    fz = f.copy()
    fz[..., 2] = 0.4
    with pytest.raises(InputError, match="the normal forces Fz spans 0 around a magnitude of 0.4"):
        fit_error(r, fz)()
    f0 = f.copy()
    f0[..., :2] = 0.0
    with pytest.raises(InputError, match="no sample has shear"):
        fit_error(r, f0, model="ohka")()


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_fit_and_forces_refuse_non_finite_readings(bad):
    f, r = coupled_set(np.random.default_rng(0), 20)
    g = r.G.copy()
    g[3, 0] = bad
    with pytest.raises(InputError, match=f"readings.G must be finite, got {bad}"):
        fit_error(Readings(g, r.u, r.contact, r.saturated), f)()
    cal = Calibration.fit(r, f, sensor=LONE, camera=SMALL)
    u = r.u.copy()
    u[0, 0, 1] = bad
    with pytest.raises(InputError, match="readings.u must be finite"):
        cal.forces(Readings(r.G, u, r.contact, r.saturated))
    with pytest.raises(InputError, match="readings.G must be >= 0, got -1.0"):
        cal.forces(Readings(-r.G[:1] * 0 - 1.0, r.u[:1], r.contact[:1], r.saturated[:1]))
    with pytest.raises(TypeError, match="forces must be a real numeric array .N., got dtype complex128"):
        fit_error(r, f.astype(complex))()


@PROPS
@given(k_g=st.floats(0.0, 1e6), k_u=st.floats(0.0, 1e6), ang=st.floats(0, 2 * np.pi))
def test_forces_beyond_the_fitted_range_are_clamped_and_flagged(k_g, k_u, ang):
    f, r = coupled_set(np.random.default_rng(0), 30)
    cal = Calibration.fit(r, f, sensor=LONE, camera=SMALL)
    G = np.array([cal.g_max * k_g])
    u = np.array([[[math.cos(ang), math.sin(ang)]]]) * (cal.u_max * k_u)
    est, clamped = cal.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    assert np.isfinite(est).all() and np.all(est[..., 2] >= 0)
    assert clamped[0, 0] == (G[0, 0] > 0 and (k_g > 1 or k_u > 1))
    edge = Readings(np.minimum(G, cal.g_max), u * min(1.0, 1.0 / k_u if k_u else 1.0), G > 0,
                    np.zeros_like(G, bool))
    np.testing.assert_allclose(est, cal.forces(edge)[0], rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------------- calibration files
@pytest.fixture(scope="module")
def cal_doc():
    f, r = coupled_set(np.random.default_rng(5), 40)
    cal = Calibration.fit(r, f, sensor=LONE, camera=SMALL, pipeline_options={"noise_sigma": 0.5})
    return cal, cal.to_dict()


json_leaves = st.none() | st.booleans() | st.integers(-10**400, 10**400) | st.floats() | st.text(max_size=5)
json_values = st.recursive(json_leaves, lambda kids: st.lists(kids, max_size=4)
                           | st.dictionaries(st.text(max_size=4), kids, max_size=3), max_leaves=8)


def _paths(d, path=()):
    yield path
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _paths(v, path + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _paths(v, path + (i,))


@PROPS
@given(which=st.integers(0, 10**6), value=json_values)
def test_any_edit_of_a_calibration_file_loads_right_or_fails_clearly(cal_doc, tmp_path_factory, which, value):
    cal, doc = cal_doc
    doc = json.loads(json.dumps(doc))
    paths = [p for p in _paths(doc) if p]
    path = paths[which % len(paths)]
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = value
    try:
        text = json.dumps(doc)
    except ValueError:  # an integer beyond Python's digit limit cannot even be written
        return
    f = tmp_path_factory.mktemp("cal") / "c.json"
    f.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            back = Calibration.load(f)
        except (InputError, CalibrationMismatchError) as exc:
            assert isinstance(exc, ValueError) and len(str(exc)) > 10
            return
        G = np.array([[0.0], [0.5], [1.0], [2.0]]) * min(float(back.g_max[0]), 1e300)
        u = np.array([[[0.2, -0.4]]] * 4) * min(float(back.u_max[0]), 1e300)
        est, _ = back.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    assert np.isfinite(est).all() and np.all(est[..., 2] >= 0)
    for name in ("g", "f", "g_max", "u_max", "gu"):
        np.testing.assert_array_equal(getattr(back, name), np.array(doc["elements"][name], dtype=float))


@pytest.mark.parametrize("text,match", [
    ("[" * 100_000 + "]" * 100_000, "RecursionError"),
    ('{"schema": ' + "9" * 5000 + "}", "not a JSON calibration"),
    ('{"schema": NaN}', "NaN is not valid JSON"),
    ("\x80\x81 not utf-8", "not a JSON calibration"),
])
def test_unreadable_calibration_files(tmp_path, text, match):
    f = tmp_path / "c.json"
    f.write_bytes(text.encode("latin-1") if "\x80" in text else text.encode())
    with pytest.raises(InputError, match=match):
        Calibration.load(f)


def test_calibration_files_never_execute_anything(tmp_path):
    marker = tmp_path / "executed"
    f = tmp_path / "c.json"
    for payload in (pickle.dumps(_Touch(str(marker))), b"__import__('os').mkdir(%r)" % str(marker).encode()):
        f.write_bytes(payload)
        with pytest.raises(InputError, match="not a JSON calibration"):
            Calibration.load(f)
    assert not marker.exists()


@pytest.mark.parametrize("edit,exc,match", [
    (lambda d: d.update(schema_version=True), InputError, "schema version True"),
    (lambda d: d["pipeline"].update(baseline=[0]), InputError, r"unknown option\(s\) \['baseline'\]"),
    (lambda d: d.update(provenance="x"), InputError, "'provenance' must be an object, got str"),
    (lambda d: d.update(residuals_n={"fz": ["a"]}), InputError, r"residuals_n\['fz'\] must hold numbers"),
    (lambda d: d["elements"]["g"][0].__setitem__(1, -1.0), InputError, "g coefficients must be >= 0"),
    (lambda d: d["elements"]["f"][0].__setitem__(0, 0.0), InputError, "a > 0 and b >= 0"),
    (lambda d: d["elements"].update(u_max=[-1.0]), InputError, "g_max and u_max must be > 0"),
    (lambda d: d["elements"].update(g_scale=[1e-300]), InputError, "overflow float64 within their fitted"),
    (lambda d: d["elements"].update(g_max=[10**400]), InputError, r"elements\['g_max'\] must hold numbers"),
    (lambda d: d["sensor"].update(outer_radius=10**400), InputError, "'sensor' is not a valid sensor"),
    (lambda d: d["sensor"].update(ring_counts=5), InputError, "'sensor' is not a valid sensor"),
    (lambda d: d["camera"].update(width="wide"), InputError, "'camera' is not a valid camera"),
    (lambda d: d["pipeline"].update(noise_sigma=10**400), InputError, "'pipeline' options are not valid"),
    (lambda d: d["sensor"].update(lever_arm=3.5), CalibrationMismatchError, "does not match"),
])
def test_bad_calibration_documents(cal_doc, tmp_path, edit, exc, match):
    _, doc = cal_doc
    doc = json.loads(json.dumps(doc))
    edit(doc)
    f = tmp_path / "c.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(exc, match=match):
        Calibration.load(f)


# ---------------------------------------------------------------------------- accumulation
@PROPS
@given(t_n=st.integers(2, 400), offset_exp=st.floats(0, 8), seed=st.integers(0, 2**16))
def test_baseline_mean_is_exact_to_rounding(pipe, t_n, offset_exp, seed):
    rng = np.random.default_rng(seed)
    stack = 10**offset_exp + rng.normal(0.0, 1.0, (t_n, H, W))
    b = pipe.replace(baseline=stack).baseline.reshape(-1)
    flat = stack.reshape(t_n, -1)
    for p in rng.integers(0, H * W, 12):
        exact = math.fsum(flat[:, p].tolist()) / t_n
        assert abs(b[p] - exact) <= 2 * np.spacing(abs(exact))


@PROPS
@given(stack=hnp.arrays(np.float64, st.tuples(st.integers(2, 3000), st.just(2), st.just(3)),
                        elements=st.floats(-1e6, 1e6)))
def test_estimate_noise_is_exact_to_rounding(stack):
    t_n = stack.shape[0]
    cols = stack.reshape(t_n, -1).T.tolist()
    var = []
    for col in cols:
        m = math.fsum(col) / t_n
        var.append(math.fsum((x - m) ** 2 for x in col) / (t_n - 1))
    exact = math.sqrt(math.fsum(var) / len(var))
    assert estimate_noise(stack) == pytest.approx(exact, rel=1e-12, abs=1e-300)


def test_big_batches_read_bit_for_bit_as_frame_by_frame(pipe, dome_xy):
    rng = np.random.default_rng(4)
    scenes = np.stack([np.clip(spot(dome_xy, e, (0.2, 0.1), 0.6, 200.0) + rng.normal(5, 1, SMALL.shape), 0, 255)
                       for e in (0, 17, 33)]).astype(np.uint8)
    which = rng.integers(0, 3, 1000)
    rs = pipe.process(scenes[which])
    singles = [pipe.process(s) for s in scenes]
    for t in range(0, 1000, 37):
        assert_same(rs[t], singles[which[t]])


def test_a_long_stream_of_readings_sums_exactly_through_the_csv(tmp_path):
    """10^6 readings would take seconds; 41 x 2000 rows show the same: every value reads back bit for bit."""
    rng = np.random.default_rng(0)
    G = 10 ** rng.uniform(-6, 6, (2000, N_EL))
    u = rng.normal(0, 0.7, (2000, N_EL, 2))
    r = Readings(G, u, G > 0, np.zeros_like(G, bool))
    path = tmp_path / "r.csv"
    with ReadingsWriter(path) as w:
        w.write(r, [f"f{i}" for i in range(2000)])
    import csv

    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    back = np.array([float(row["G"]) for row in rows])
    np.testing.assert_array_equal(back, G.reshape(-1))
    np.testing.assert_array_equal(np.array([float(row["uy"]) for row in rows]), u[..., 1].reshape(-1))
    assert math.fsum(back.tolist()) == math.fsum(G.reshape(-1).tolist())


# ---------------------------------------------------------------------------- CCD
finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10**20),
                          st.sampled_from([True, None, "3", 5e-324, 1e308]))


@PROPS
@given(field=st.sampled_from(["exposure", "full_well", "read_noise", "dark_offset", "bits", "gain"]),
       value=finite_or_not)
def test_ccd_settings_are_valid_or_refused_by_name(field, value):
    try:
        ccd = CCD(**{field: value})
    except (TypeError, InputError) as exc:
        assert field in str(exc) or "gain" in str(exc), str(exc)
        return
    rad = np.array([[0.0, 1e-3, 1.0, 1e3, 1e300]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = [ccd.expose(rad, seed=0), ccd.mean_dn(rad), ccd.variance_dn(rad)]
    assert all(np.isfinite(np.asarray(o, np.float64)).all() for o in out)


@pytest.mark.parametrize("kwargs,match", [
    (dict(full_well=1e19), r"full_well must be at most 1e\+18 electrons"),
    (dict(full_well=5e-324), "gain inf DN/electron .* overflows float64"),
    (dict(gain=1e200), "overflows float64"),
    (dict(read_noise=1e200), "read_noise=1e\\+200 overflows float64"),
])
def test_ccd_settings_that_overflow(kwargs, match):
    with pytest.raises(InputError, match=match):
        CCD(**kwargs)
    assert MAX_FULL_WELL == 1e18


def test_ccd_ragged_radiance_is_a_type_error():
    with pytest.raises(TypeError, match="radiance must be a real numeric array; could not make one"):
        CCD().expose([[1.0, 2.0], [3.0]], seed=0)


# ---------------------------------------------------------------------------- contact and renderer inputs
@PROPS
@given(forces=hnp.arrays(np.float64, (N_EL, 3), elements=st.floats(allow_nan=True, allow_infinity=True,
                                                                     width=64)))
def test_contact_model_on_any_forces(forces):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            c = contact_patches(SENSOR, forces)
        except InputError as exc:
            assert not np.isfinite(forces).all() or np.abs(forces).max() > MAX_FORCE_N
            assert "finite" in str(exc) or "at most 1e+06 N" in str(exc)
            return
    for name in ("centers", "radii", "loads", "slide"):
        assert np.isfinite(getattr(c, name)).all()
    np.testing.assert_allclose(c.loads.sum(axis=1), np.maximum(forces[:, 2], 0.0), rtol=1e-9, atol=1e-300)
    assert np.all(np.hypot(c.slide[:, 0], c.slide[:, 1]) <= np.pi * SENSOR.outer_radius * (1 + 1e-12))


def test_shear_on_a_vanishing_normal_load_tips_without_overflow():
    f = np.zeros((N_EL, 3))
    f[0] = (1e6, 0.0, 1e-300)
    f[1] = (1e6, 1e6, 5e-324)
    f[2] = (0.1, 0.0, 1.0)
    f[3] = (1e-320, 0.0, 5e-324)  # all subnormal: the direction of a tipped feeler must not overflow
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = contact_patches(SENSOR, f)
    assert c.tipped[[0, 1, 3]].all() and not c.tipped[2]
    np.testing.assert_allclose(np.hypot(c.slide[:2, 0], c.slide[:2, 1]), np.pi * SENSOR.outer_radius)
    assert np.isfinite(c.centers).all()


@pytest.mark.parametrize("forces,exc,match", [
    (np.full((N_EL, 3), 2e6), InputError, r"forces must be at most 1e\+06 N in magnitude \(check the units\), "
                                          r"got 2000000.0 at index \(0, 0\)"),
    ([[0.0, 0.0, 1.0]] * 40 + [[0.0, 1.0]], TypeError, "forces must be a real numeric array; could not make"),
    (np.zeros((N_EL, 3), bool), TypeError, "forces must be a real numeric array, got dtype bool"),
])
def test_bad_forces(forces, exc, match):
    with pytest.raises(exc, match=match):
        check_forces(forces, SENSOR)


RENDER_BAD = [
    (dict(spp=0), InputError, "spp must be >= 1, got 0"),
    (dict(spp=2.5), TypeError, "spp must be an integer, got float"),
    (dict(seed=-1), InputError, "seed must be >= 0"),
    (dict(forces=np.full((N_EL, 3), np.nan)), InputError, "forces must be finite"),
    (dict(forces=np.full((N_EL, 3), -1e9)), InputError, r"at most 1e\+06 N"),
    (dict(forces=np.zeros((N_EL, 2))), ShapeError, r"forces must have shape \(41, 3\)"),
    (dict(transport="bidir"), InputError, "transport must be one of"),
    (dict(crop=(0, 0, 0, 4)), InputError, "crop window"),
    (dict(pixels=np.ones((3, 3), bool)), InputError, "pixels must have the camera's shape"),
    (dict(pixels=True, background=np.full((24, 32), np.nan)), InputError, "background must be finite"),
    (dict(target_error=-1.0), InputError, "target_error must be finite and > 0"),
    (dict(transport="two_stage", n_sub=0), InputError, "n_sub must be >= 1"),
    (dict(camera="cam"), TypeError, "camera must be a FisheyeCamera"),
]
RENDER_DEFECTS = [  # found by the stress cases; render/ now checks them before Mitsuba is imported
    (dict(variant="no_such_variant"), InputError, "variant"),
    (dict(crop=5), (TypeError, InputError), "crop"),
    (dict(pixels=True, background=-np.ones((24, 32))), InputError, "background"),
    (dict(pixels=True, background=np.full((24, 32), 1e300)), InputError, "background"),
]


def _render_call(kwargs):
    from optitact.render import render

    cam = optitact.FisheyeCamera(width=32, height=24)
    kw = dict(camera=cam, spp=1) | kwargs
    forces = kw.pop("forces", np.zeros((N_EL, 3)))
    if kw.get("pixels") is True:
        kw["pixels"] = np.ones(cam.shape, bool)
    saved = {k: sys.modules.get(k) for k in ("mitsuba", "drjit")}
    sys.modules["mitsuba"] = sys.modules["drjit"] = None  # importing either now fails
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            render(SENSOR, forces, **kw)
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


@pytest.mark.parametrize("kwargs,exc,match", RENDER_BAD)
def test_renderer_refuses_bad_input_before_mitsuba(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        _render_call(kwargs)


@pytest.mark.parametrize("kwargs,exc,match", RENDER_DEFECTS)
def test_renderer_input_defects(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        _render_call(kwargs)


# ---------------------------------------------------------------------------- the runner
def test_run_case_counts_warnings_and_deep_errors_as_failures():
    def warns():
        np.array([1.0]) / np.array([0.0])

    assert "RuntimeWarning" in run_case(Case("w", "x", warns))
    assert "ZeroDivisionError" in run_case(Case("z", "x", lambda: 1 / 0))
    assert run_case(Case("ok", "x", lambda: None)) is None

    def fails():
        raise CaseFailure("wrong number")

    assert run_case(Case("f", "x", fails)) == "wrong number"


def test_run_stability_smoke():
    out = run_stability(n_cases=140, seed=3, progress=False, sweep=False, long_rows=2000)
    assert out["cases"] == 140 and set(out["categories"]) == set(CATEGORIES)
    assert sum(c["cases"] for c in out["categories"].values()) == 140
    # every failure is one of the reported render/ defects
    assert all(re.match(r"contact_render/render_input/", n) for n in out["failures"]), out["failure_reasons"]
    json.dumps(out)


def test_generated_cases_are_deterministic(tmp_path):
    a = [c.name for c in generate_cases(300, seed=9, tmp=tmp_path, long_rows=100)]
    b = [c.name for c in generate_cases(300, seed=9, tmp=tmp_path, long_rows=100)]
    assert a == b and len(a) == 300 and len(set(a)) == 300
    with pytest.raises(InputError, match="n_cases must be a non-negative integer, got -1"):
        generate_cases(-1, tmp=tmp_path)
