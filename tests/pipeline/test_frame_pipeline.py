"""Tests for the frame pipeline (pipeline.frame_pipeline) and its readings (pipeline.readings).

Ground truths are independent of the code under test: Gaussian spots drawn at
known dome points (energy ``A 2 pi s^2`` and centre known in closed form, pixel
values from the camera's inverse map and the sphere's log map), constant and
linear images (region areas, bilinear exactness), hand-made arrays for each
step, and brute-force geometry. Rendered frames (``render`` marker) check that
the fast and reference methods agree on realistic frames.

Cameras are small (200x150 for accuracy, 160x120 elsewhere) so the file runs
in seconds.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import warnings

import numpy as np
import pytest

import optitact
from optitact.errors import InputError, ShapeError
from optitact.optics.ccd import CCD
from optitact.optics.loads import random_load
from optitact.pipeline.fastpath import CHUNK_FRAMES
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import (
    apply_threshold,
    denoise,
    estimate_noise,
    readings_from_moments,
    subtract_baseline,
)
from optitact.pipeline.readings import Readings
from optitact.pipeline.regions import REGION_MARGIN_MM, default_region_radius, dewarp, integrate

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAM = optitact.optics.camera.FisheyeCamera(width=200, height=150)    # accuracy tests and renders
SMALL = optitact.optics.camera.FisheyeCamera(width=160, height=120)  # stacks, dtypes, errors
N_EL = SENSOR.n_elements
R = SENSOR.outer_radius
DTYPES = [np.uint8, np.uint16, np.float32, np.float64]
#: An element of every ring: apex, ring 1, ring 2, ring 3 (both at the image's edge side).
RING_ELEMENTS = [0, 3, 12, 30, 40]


# ---------------------------------------------------------------------------- analytic frames
_DOME_CACHE: dict = {}


def _pixel_dome_points(cam):
    """Dome point (mm) seen at every pixel centre, NaN where the ray misses the dome."""
    if cam not in _DOME_CACHE:
        rr, cc = np.mgrid[0:cam.height, 0:cam.width]
        px = np.stack([rr, cc], axis=-1).astype(np.float64)
        _DOME_CACHE[cam] = cam.unproject(px, SENSOR, outside="nan")
    return _DOME_CACHE[cam]


def spot_frame(cam, spots, background=0.0):
    """Float64 frame of Gaussian spots on the dome.

    ``spots``: iterable of ``(element, centre (x, y) mm, sigma mm, amplitude)``;
    a pixel's value is ``A exp(-|xy - c|^2 / (2 s^2))`` with ``xy`` the
    element-local tangent coordinates of the dome point it sees, cut at 5
    sigma (energy lost: exp(-12.5) = 4e-6 of it). True G = A 2 pi s^2, true
    u = c.
    """
    pts = _pixel_dome_points(cam)
    img = np.zeros(cam.shape) + background
    for e, c, s, a in spots:
        xy = SENSOR.tangent_offset(np.full(cam.shape, e), pts)
        d2 = np.sum((xy - np.asarray(c, float)) ** 2, axis=-1)
        near = np.isfinite(d2) & (d2 <= (5.0 * s) ** 2)
        img[near] += a * np.exp(-d2[near] / (2.0 * s * s))
    return img


def true_g(a, s):
    return a * 2.0 * math.pi * s * s


def assert_no_contact_except(r, keep=()):
    others = np.setdiff1d(np.arange(N_EL), keep)
    assert not r.contact[..., others].any()
    assert np.all(r.G[..., others] == 0.0)
    assert np.all(r.u[..., others, :] == 0.0)


def assert_same_readings(a, b, *, g_rtol=0.0, u_atol=0.0):
    """Readings equal: flags exactly, G and u to the given tolerances (0: bit-identical)."""
    assert a.G.shape == b.G.shape and a.u.shape == b.u.shape
    np.testing.assert_array_equal(a.contact, b.contact)
    np.testing.assert_array_equal(a.saturated, b.saturated)
    if g_rtol == 0.0 and u_atol == 0.0:
        np.testing.assert_array_equal(a.G, b.G)
        np.testing.assert_array_equal(a.u, b.u)
    else:
        np.testing.assert_allclose(a.G, b.G, rtol=g_rtol, atol=0)
        np.testing.assert_allclose(a.u, b.u, rtol=0, atol=u_atol)


def scene_spots(seed, elements=range(N_EL), *, s_range=(0.35, 0.5), a_range=(40.0, 150.0)):
    rng = np.random.default_rng(seed)
    out = []
    for e in elements:
        c = rng.uniform(-0.5, 0.5, 2)
        out.append((int(e), c, rng.uniform(*s_range), rng.uniform(*a_range)))
    return out


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def fast0():
    """Noiseless fast pipeline (threshold 0) on the 200x150 camera."""
    return Pipeline(SENSOR, CAM, noise_sigma=0.0)


@pytest.fixture(scope="module")
def ref0(fast0):
    return fast0.replace(method="reference")


@pytest.fixture(scope="module")
def wide():
    """Regions wider than half the closest spacing (3.5 > 2.77 mm): neighbours meet at Voronoi borders."""
    return Pipeline(SENSOR, CAM, radius=3.5, noise_sigma=0.0)


@pytest.fixture(scope="module")
def small():
    return Pipeline(SENSOR, SMALL)


@pytest.fixture(scope="module")
def small_scene():
    """Integer-valued float64 frame (max < 255) on the 160x120 camera and its flat baseline."""
    spots = [(0, (0.2, -0.1), 0.6, 120.0), (5, (-0.3, 0.4), 0.55, 90.0),
             (20, (0.1, 0.3), 0.6, 140.0), (33, (0.0, -0.4), 0.5, 100.0)]
    frame = np.rint(spot_frame(SMALL, spots, background=10.0))
    assert frame.max() < 255
    return frame, np.full(SMALL.shape, 10.0), [s[0] for s in spots]


@pytest.fixture(scope="module")
def noisy_scene():
    """uint8 frame with spots on all 41 elements, a structured background and noise, and its baseline."""
    rows, cols = np.mgrid[0:CAM.height, 0:CAM.width]
    background = 20.0 + 8.0 * np.sin(rows / 9.0) * np.cos(cols / 13.0)
    rng = np.random.default_rng(3)
    frame = spot_frame(CAM, scene_spots(2), background) + rng.normal(0.0, 1.0, CAM.shape)
    base = background[None] + rng.normal(0.0, 1.0, (4,) + CAM.shape)
    to8 = lambda a: np.clip(np.rint(a), 0, 254).astype(np.uint8)  # noqa: E731
    return to8(frame), to8(base)


# ---------------------------------------------------------------------------- 1. analytic spots
@pytest.mark.parametrize("method", ["fast", "reference"])
@pytest.mark.parametrize("e", RING_ELEMENTS)
@pytest.mark.parametrize("c", [(0.0, 0.0), (0.13, -0.27), (-0.41, 0.22), (0.3, 0.35)])
def test_spot_at_known_dome_point(fast0, ref0, method, e, c):
    pipe = fast0 if method == "fast" else ref0
    s, a = 0.4, 100.0
    r = pipe.process(spot_frame(CAM, [(e, c, s, a)]))
    # Issue: u within 0.01 mm without noise. Measured here: u <= 0.0009 mm, G <= 0.16 %.
    np.testing.assert_allclose(r.u[e], c, rtol=0, atol=0.003)
    np.testing.assert_allclose(r.G[e], true_g(a, s), rtol=0.005, atol=0)
    assert r.contact[e] and not r.saturated.any()
    assert_no_contact_except(r, [e])


@pytest.mark.parametrize("e", RING_ELEMENTS)
@pytest.mark.parametrize("frac", [(0.0, 0.0), (0.25, 0.5), (0.5, 0.5), (0.7, 0.15)])
def test_spot_at_sub_pixel_offset(fast0, e, frac):
    """A spot centred at a fractional pixel position near the element centre."""
    px = np.floor(CAM.project(SENSOR.element_positions[e], SENSOR)) + frac
    c = SENSOR.tangent_offset(e, CAM.unproject(px, SENSOR))
    s, a = 0.4, 80.0
    r = fast0.process(spot_frame(CAM, [(e, c, s, a)]))
    np.testing.assert_allclose(r.u[e], c, rtol=0, atol=0.003)
    np.testing.assert_allclose(r.G[e], true_g(a, s), rtol=0.005, atol=0)


@pytest.mark.parametrize("e", [0, 12])
def test_centroid_follows_small_shifts(fast0, e):
    """Shifts far below a pixel footprint (~0.3 mm) move u by the same amount."""
    base = np.array([0.1, -0.2])
    us = []
    for step in np.arange(5) * 0.04:
        shift = base + step * np.array([1.0, 0.5])
        us.append(fast0.process(spot_frame(CAM, [(e, shift, 0.4, 100.0)])).u[e])
    np.testing.assert_allclose(np.diff(us, axis=0), np.tile([0.04, 0.02], (4, 1)), rtol=0, atol=0.002)


@pytest.mark.parametrize("method", ["fast", "reference"])
def test_g_proportional_to_spot_energy(fast0, ref0, method):
    pipe = fast0 if method == "fast" else ref0
    spots = [(3, (0.2, 0.1), 0.4, 50.0), (30, (-0.1, 0.3), 0.45, 70.0)]
    one = pipe.process(spot_frame(CAM, spots))
    two = pipe.process(spot_frame(CAM, [(e, c, s, 2 * a) for e, c, s, a in spots]))
    np.testing.assert_allclose(two.G, 2.0 * one.G, rtol=1e-12, atol=0)
    np.testing.assert_allclose(two.u, one.u, rtol=0, atol=1e-12)
    # Energy grows with s^2 at a fixed amplitude.
    wide_ = pipe.process(spot_frame(CAM, [(e, c, 1.25 * s, a) for e, c, s, a in spots]))
    np.testing.assert_allclose(wide_.G[[3, 30]], 1.25**2 * one.G[[3, 30]], rtol=0.01, atol=0)


def test_several_spots_are_read_independently(fast0):
    spots = scene_spots(7, elements=[0, 2, 9, 17, 26, 35], s_range=(0.35, 0.45))
    r = fast0.process(spot_frame(CAM, spots))
    for e, c, s, a in spots:
        np.testing.assert_allclose(r.u[e], c, rtol=0, atol=0.003)
        np.testing.assert_allclose(r.G[e], true_g(a, s), rtol=0.005, atol=0)
    assert_no_contact_except(r, [s[0] for s in spots])


# ---------------------------------------------------------------------------- 2. regions
def _border_spot(e, f, delta):
    """Centre (e's tangent coordinates) of a point on the e-f geodesic, delta mm from the bisector towards e."""
    n = SENSOR.element_frames[:, 2, :]
    ang = math.acos(float(n[e] @ n[f]))
    t = 0.5 - delta / (R * ang)
    p = R * (math.sin((1 - t) * ang) * n[e] + math.sin(t * ang) * n[f]) / math.sin(ang)
    return SENSOR.tangent_offset(e, p)


@pytest.mark.parametrize("delta", [0.75, -0.75])
def test_spot_straddling_two_regions_goes_to_its_element(wide, delta):
    e, f = 12, 13  # neighbours in ring 2, 5.54 mm apart: their regions touch at radius 3.5
    s, a = 0.3, 100.0
    r = wide.process(spot_frame(CAM, [(e, _border_spot(e, f, delta), s, a)]))
    near, far = (e, f) if delta > 0 else (f, e)
    g = true_g(a, s)
    assert r.G[near] > 0.97 * g  # half-plane share Phi(2.5) = 0.994
    assert r.G[far] < 0.03 * g
    np.testing.assert_allclose(r.G[e] + r.G[f], g, rtol=0.01, atol=0)
    assert_no_contact_except(r, [e, f])


@pytest.mark.parametrize("delta", [-0.3, -0.1, 0.1, 0.3])
def test_straddling_spot_splits_like_the_half_planes(wide, delta):
    """G splits at the Voronoi border as the Gaussian's half-plane integrals Phi(delta / s)."""
    e, f, s, a = 12, 13, 0.4, 100.0
    r = wide.process(spot_frame(CAM, [(e, _border_spot(e, f, delta), s, a)]))
    share = 0.5 * (1.0 + math.erf(delta / s / math.sqrt(2.0)))
    np.testing.assert_allclose(r.G[e] / true_g(a, s), share, rtol=0, atol=0.03)
    np.testing.assert_allclose((r.G[e] + r.G[f]) / true_g(a, s), 1.0, rtol=0, atol=0.01)


@pytest.mark.parametrize("which", ["default", "wide"])
def test_region_cells_are_voronoi_cells_within_the_radius(fast0, wide, which):
    pipe = fast0 if which == "default" else wide
    g = pipe.grids
    n = SENSOR.element_frames[:, 2, :]
    gx, gy = np.meshgrid(g.coords, g.coords)
    disc = np.hypot(gx, gy) <= g.radius
    for e in range(N_EL):
        m = g.mask[e]
        assert m.any()
        pts = SENSOR.dome_point(e, np.stack([gx[m], gy[m]], axis=-1))
        cos = np.clip(pts @ n.T / R, -1.0, 1.0)  # (cells, E)
        assert np.all(R * np.arccos(cos[:, e]) <= g.radius + 1e-9)
        assert np.all(np.argmax(cos, axis=1) == e)  # nearer to its own centre than to any other
        assert np.all(g.area[e][m] > 0) and np.all(g.area[e][~m] == 0)
        assert np.all(g.pixels[e][~m] == -10.0)
        # The cells' pixel positions see their dome points (an independent inverse map).
        np.testing.assert_allclose(CAM.unproject(g.pixels[e][m], SENSOR), pts, rtol=0, atol=1e-6)
    if which == "default":
        # All regions are whole discs for this camera, far from the Voronoi borders.
        assert np.all(g.mask == disc[None])
    else:
        # Wide regions are cut where a neighbour is nearer.
        assert g.mask[12].sum() < disc.sum()


def _pixels_read(grids, e, shape):
    """(H, W) bool: the pixels the bilinear dewarp of region e reads (2x2 around each cell's position)."""
    rc = grids.pixels[e][grids.mask[e]]
    mine = np.zeros(shape, bool)
    for rows in (np.floor(rc[:, 0]), np.ceil(rc[:, 0])):
        for cols in (np.floor(rc[:, 1]), np.ceil(rc[:, 1])):
            mine[rows.astype(int), cols.astype(int)] = True
    return mine


def test_default_regions_share_no_pixel(fast0):
    owner = np.full(CAM.shape, -1)
    for e in range(N_EL):
        mine = _pixels_read(fast0.grids, e, CAM.shape)
        assert np.all(owner[mine] == -1), f"region {e} reads pixels of region {owner[mine].max()}"
        owner[mine] = e


def test_touching_regions_share_only_border_pixels(wide):
    both = _pixels_read(wide.grids, 12, CAM.shape) & _pixels_read(wide.grids, 13, CAM.shape)
    assert both.any()
    pts = CAM.unproject(np.argwhere(both).astype(np.float64), SENSOR)
    n = SENSOR.element_frames[[12, 13], 2, :]
    d = R * np.arccos(np.clip(pts @ n.T / R, -1, 1))
    assert np.all(np.abs(d[:, 0] - d[:, 1]) < 1.0)  # within about a pixel footprint of the border


def test_region_areas_are_geodesic_discs(fast0):
    """Sum of cell areas ~ area of a geodesic disc on the sphere, 2 pi R^2 (1 - cos(r/R))."""
    g = fast0.grids
    cap = 2.0 * math.pi * R**2 * (1.0 - math.cos(g.radius / R))
    np.testing.assert_allclose(g.area.sum(axis=(1, 2)), cap, rtol=0.01, atol=0)


# ---------------------------------------------------------------------------- 3. steps
def test_subtract_baseline_clips_at_zero_without_wrapping():
    frame = np.array([[5, 1], [0, 3]], np.uint8)
    base = np.array([[2, 2], [2, 2]], np.uint8)
    before = frame.copy()
    out = subtract_baseline(frame, base)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [[3.0, 0.0], [0.0, 1.0]])  # uint8 would wrap to 255
    np.testing.assert_array_equal(frame, before)
    np.testing.assert_array_equal(subtract_baseline(frame, np.full((2, 2), 0.5)), [[4.5, 0.5], [0.0, 2.5]])


def test_subtract_baseline_none_is_a_float_copy():
    frame = np.array([[5.0, 1.0], [0.0, 3.0]])
    out = subtract_baseline(frame)
    np.testing.assert_array_equal(out, frame)
    assert out.dtype == np.float64 and not np.shares_memory(out, frame)


def test_subtract_baseline_shape_mismatch():
    with pytest.raises(ShapeError, match=re.escape("baseline must have the frame's shape (2, 2), got (2, 3)")):
        subtract_baseline(np.zeros((2, 2)), np.zeros((2, 3)))


def test_denoise_none_returns_a_copy():
    img = np.arange(12.0).reshape(3, 4)
    out = denoise(img)
    np.testing.assert_array_equal(out, img)
    out[0, 0] = 99.0
    assert img[0, 0] == 0.0


@pytest.mark.parametrize("sigma", [0.7, 1.0, 2.0])
def test_gaussian_spreads_an_interior_delta_like_a_sampled_gaussian(sigma):
    img = np.zeros((31, 33))
    img[15, 16] = 10.0
    out = denoise(img, method="gaussian", size=sigma)
    rad = math.ceil(3 * sigma)
    x = np.arange(-rad, rad + 1)
    k = np.exp(-x**2 / (2 * sigma**2))
    k /= k.sum()
    expected = np.zeros_like(img)
    expected[15 - rad:16 + rad, 16 - rad:17 + rad] = 10.0 * np.outer(k, k)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.sum(), 10.0, rtol=1e-12, atol=0)
    assert out.max() < 10.0 and out[15, 16 + rad] > 0 and out[15, 17 + rad] == 0


def test_gaussian_threshold_scales_with_the_filtered_noise():
    """sigma_f = sigma * sum(k^2) (the 2-D kernel's L2 norm): the threshold and the measured noise agree."""
    sigma_px = 1.0
    x = np.arange(-3, 4)
    k = np.exp(-x**2 / (2 * sigma_px**2))
    k /= k.sum()
    gain = np.sum(k**2)
    pipe = Pipeline(SENSOR, SMALL, filter="gaussian", noise_sigma=2.0, k=3.0)
    np.testing.assert_allclose(pipe.threshold, 3.0 * 2.0 * gain, rtol=1e-12, atol=0)
    noise = np.random.default_rng(0).normal(0.0, 2.0, (300, 300))
    filtered = denoise(noise, method="gaussian", size=sigma_px)[10:-10, 10:-10]
    np.testing.assert_allclose(filtered.std(), 2.0 * gain, rtol=0.05, atol=0)


def test_median_removes_an_isolated_hot_pixel_and_keeps_a_block():
    img = np.full((9, 9), 4.0)
    img[2, 2] = 200.0
    img[5:8, 5:8] = 50.0
    out = denoise(img, method="median", size=3)
    assert out[2, 2] == 4.0
    assert out[6, 6] == 50.0  # the centre of a 3x3 block survives a 3x3 median
    assert np.all(out[:4, :4] == 4.0)
    assert denoise(img, method="median", size=7)[6, 6] == 4.0  # 9 of 49 pixels: gone


def test_denoise_unknown_method():
    with pytest.raises(InputError, match=re.escape("filter must be one of ('none', 'gaussian', 'median'), "
                                                   "got 'box'")):
        denoise(np.zeros((3, 3)), method="box")


def test_apply_threshold_zeroes_at_or_below():
    img = np.array([[0.0, 1.0, 1.5], [1.5000001, 3.0, -2.0]])
    out = apply_threshold(img, 1.5)
    np.testing.assert_array_equal(out, [[0.0, 0.0, 0.0], [1.5000001, 3.0, 0.0]])
    assert out.dtype == np.float64
    np.testing.assert_array_equal(apply_threshold(np.array([[3, 7]], np.uint8), 3), [[0.0, 7.0]])


def test_dewarp_is_bilinear_and_exact_on_linear_images(fast0):
    g = fast0.grids
    rows, cols = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    for img, k in ((cols, 1), (rows, 0)):
        out = dewarp(img, g)
        assert out.shape == g.mask.shape
        np.testing.assert_allclose(out[g.mask], g.pixels[g.mask][:, k], rtol=0, atol=1e-9)
        assert np.all(out[~g.mask] == 0.0)


def test_constant_image_gives_region_area_and_zero_centroid(fast0, ref0):
    g = fast0.grids
    area = g.area.sum(axis=(1, 2))
    patches = dewarp(np.ones(CAM.shape), g)
    np.testing.assert_allclose(patches[g.mask], 1.0, rtol=0, atol=1e-12)
    G, M = integrate(patches, g)
    np.testing.assert_allclose(G, area, rtol=1e-9, atol=0)
    np.testing.assert_allclose(M / G[:, None], 0.0, rtol=0, atol=1e-9)  # symmetric discs
    for pipe in (fast0, ref0):
        r = pipe.process(np.ones(CAM.shape))
        np.testing.assert_allclose(r.G, area, rtol=1e-9, atol=0)
        np.testing.assert_allclose(r.u, 0.0, rtol=0, atol=1e-9)
        assert r.contact.all()


def test_integrate_axis_convention(fast0):
    """x runs along grid columns, y along grid rows: one lit cell gives its area and coordinates."""
    g = fast0.grids
    n = len(g.coords)
    patches = np.zeros(g.mask.shape)
    e, i, j = 7, n // 2 - 3, n // 2 + 5
    assert g.mask[e, i, j]
    patches[e, i, j] = 2.0
    G, M = integrate(patches, g)
    a = g.area[e, i, j]
    np.testing.assert_allclose(G[e], 2.0 * a, rtol=1e-15, atol=0)
    np.testing.assert_allclose(M[e], 2.0 * a * np.array([g.coords[j], g.coords[i]]), rtol=1e-15, atol=0)
    assert np.all(np.delete(G, e) == 0) and np.all(np.delete(M, e, axis=0) == 0)


@pytest.mark.parametrize("lead", [(), (3,)])
def test_readings_from_moments_no_contact_is_zero_without_warnings(lead):
    G = np.broadcast_to([0.0, 5.0, 1e-3, -1.0], lead + (4,))
    M = np.broadcast_to([[0.0, 0.0], [10.0, -5.0], [1.0, 1.0], [3.0, 3.0]], lead + (4, 2))
    floor = np.array([0.0, 0.01, 0.01, 0.0])
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        r = readings_from_moments(G, M, np.zeros(lead + (4,), bool), floor)
    np.testing.assert_array_equal(r.contact, np.broadcast_to([False, True, False, False], lead + (4,)))
    np.testing.assert_array_equal(r.G, np.broadcast_to([0.0, 5.0, 0.0, 0.0], lead + (4,)))
    np.testing.assert_array_equal(r.u, np.broadcast_to([[0, 0], [2.0, -1.0], [0, 0], [0, 0]], lead + (4, 2)))
    assert np.isfinite(r.u).all() and r.G.dtype == np.float64 and r.saturated.dtype == bool


def test_estimate_noise_recovers_a_known_sigma():
    rng = np.random.default_rng(4)
    pattern = rng.uniform(0, 50, (60, 80))  # fixed pattern: not temporal noise
    stack = pattern + rng.normal(0.0, 2.0, (8, 60, 80))
    np.testing.assert_allclose(estimate_noise(stack), 2.0, rtol=0.03, atol=0)
    np.testing.assert_allclose(estimate_noise(stack.astype(np.float32)), 2.0, rtol=0.03, atol=0)
    assert estimate_noise(np.broadcast_to(pattern, (3, 60, 80))) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("frames,exc,match", [
    (np.zeros((60, 80)), ShapeError, re.escape("stack (T, H, W) with T >= 2, got (60, 80)")),
    (np.zeros((1, 60, 80)), ShapeError, "T >= 2, got \\(1, 60, 80\\)"),
    (np.zeros((2, 4, 4), complex), TypeError, "real numeric stack, got dtype complex128"),
    (np.full((2, 4, 4), np.nan), InputError, "frames must be finite"),
])
def test_estimate_noise_errors(frames, exc, match):
    with pytest.raises(exc, match=match):
        estimate_noise(frames)


def test_default_region_radius():
    # Default sensor: the patch reach 1.25 + 0.45 + margin is below half the closest spacing.
    reach = SENSOR.cone_circle_radius + SENSOR.cone_base_radius + REGION_MARGIN_MM
    assert default_region_radius(SENSOR) == pytest.approx(reach, rel=1e-15)
    assert reach == pytest.approx(2.2)
    # A crowded sensor: half the closest geodesic spacing, found by brute force.
    tight = optitact.optics.sensor.DomeSensor(ring_counts=(1, 8), ring_polar_deg=(0.0, 10.0))
    p = tight.element_positions
    d = [tight.outer_radius * math.acos(min(1.0, float(p[i] @ p[j]) / tight.outer_radius**2))
         for i in range(len(p)) for j in range(i)]
    assert min(d) / 2 < reach
    np.testing.assert_allclose(default_region_radius(tight), min(d) / 2, rtol=1e-12, atol=0)
    lone = optitact.optics.sensor.DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,))
    assert default_region_radius(lone) == pytest.approx(reach, rel=1e-15)


# ---------------------------------------------------------------------------- 4. reference vs fast
def _fast_ref(pipe):
    return pipe.replace(method="fast"), pipe.replace(method="reference")


@pytest.mark.parametrize("filt", ["none", "gaussian", "median"])
@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_reference_and_fast_agree_on_analytic_frames(noisy_scene, filt, dtype):
    frame, base = noisy_scene
    fast, ref = _fast_ref(Pipeline(SENSOR, CAM, baseline=base.astype(dtype), filter=filt,
                                   noise_sigma=1.0))
    a, b = fast.process(frame.astype(dtype)), ref.process(frame.astype(dtype))
    # Issue: G within 0.5 %, u within 0.005 mm, flags identical; they agree to rounding.
    assert_same_readings(a, b, g_rtol=1e-9, u_atol=1e-9)
    assert a.contact.sum() >= (41 if filt == "none" else 30)


def test_reference_and_fast_agree_on_ground_truth(noisy_scene):
    """Noisy uint8 spots: both methods within noise-level tolerances of the drawn spots.

    The threshold t (3 DN) drops the spot's rim: a Gaussian of peak A keeps the energy
    ``A 2 pi s^2 (1 - t / A)`` above t.
    """
    frame, base = noisy_scene
    # the mean frame as baseline: one threshold everywhere (a stack would add a noise map)
    fast, ref = _fast_ref(Pipeline(SENSOR, CAM, baseline=base.mean(axis=0), noise_sigma=1.0))
    t = fast.threshold
    assert t == 3.0 and fast.threshold_map is None
    for r in (fast.process(frame), ref.process(frame)):
        for e, c, s, a in scene_spots(2):
            np.testing.assert_allclose(r.u[e], c, rtol=0, atol=0.04)
            np.testing.assert_allclose(r.G[e], true_g(a, s) * (1 - t / a), rtol=0.06, atol=0)


@pytest.mark.parametrize("base,thr", [(0.7, 0.3), (1.4, 0.6), (1.7, 0.3), (10.0, 2.0), (10.0, 0.0)])
def test_integer_frames_at_the_threshold_agree_exactly(base, thr):
    """Integer frames with a float baseline: frame - base == threshold up to one rounding step.

    ``n - base > thr`` decides in both methods (e.g. 1 - 0.7 = 0.30000000000000004 > 0.3, while
    0.7 + 0.3 rounds to 1.0).
    """
    n = math.floor(base + thr) + (1 if thr == 0.0 else 0)
    frame = np.full(SMALL.shape, n, np.uint8)
    fast, ref = _fast_ref(Pipeline(SENSOR, SMALL, baseline=np.full(SMALL.shape, base), k=1.0,
                                   noise_sigma=thr, min_pixels=0.0))
    a, b = fast.process(frame), ref.process(frame)
    assert_same_readings(a, b, g_rtol=1e-12, u_atol=1e-12)
    lit = (float(n) - base) > thr
    assert np.all(a.contact == lit)


@pytest.fixture(scope="module")
def saturated_scene():
    spots = [(3, (0.1, 0.2), 0.5, 600.0), (12, (0.0, 0.0), 0.5, 120.0), (30, (-0.2, 0.1), 0.5, 400.0)]
    img = spot_frame(SMALL, spots, background=5.0)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), np.full(SMALL.shape, 5, np.uint8)


@pytest.mark.parametrize("method", ["fast", "reference"])
@pytest.mark.parametrize("filt", ["none", "gaussian", "median"])
def test_saturated_flags_analytic(saturated_scene, method, filt):
    frame, base = saturated_scene
    pipe = Pipeline(SENSOR, SMALL, baseline=base, method=method, filter=filt)
    r = pipe.process(frame)
    expected = np.zeros(N_EL, bool)
    expected[[3, 30]] = True
    np.testing.assert_array_equal(r.saturated, expected)
    assert r.contact[[3, 12, 30]].all()
    # As uint16 (saturation 65535, with a uint16 baseline) nothing is saturated; a float frame
    # with saturation=255 is.
    assert not pipe.with_baseline(base.astype(np.uint16)).process(frame.astype(np.uint16)).saturated.any()
    np.testing.assert_array_equal(pipe.replace(saturation=255.0).process(frame.astype(np.float32)).saturated,
                                  expected)


@pytest.mark.parametrize("method", ["fast", "reference"])
def test_saturated_pixel_in_a_bright_baseline_is_flagged(method):
    """A pixel at 255 whose baseline + threshold is above 255 is dark but still saturated."""
    px = np.round(SMALL.project(SENSOR.element_positions[9], SENSOR)).astype(int)
    base = np.full(SMALL.shape, 20.0)
    base[px[0], px[1]] = 254.6
    frame = np.full(SMALL.shape, 20, np.uint8)
    frame[px[0], px[1]] = 255
    r = Pipeline(SENSOR, SMALL, baseline=base, method=method).process(frame)
    assert r.saturated[9] and r.saturated.sum() == 1
    assert not r.contact.any()


# ---------------------------------------------------------------------------- 4b. rendered frames
@pytest.fixture(scope="module")
def rendered():
    """Rendered 200x150 frames of all 41 elements loaded, their no-load stack, and a 4x brighter pair."""
    from optitact.render import render

    forces = random_load(SENSOR, seed=5)
    radiance = render(SENSOR, forces, camera=CAM, spp=16, seed=1)
    empty = render(SENSOR, np.zeros((N_EL, 3)), camera=CAM, spp=16, seed=2)
    ccd = CCD()
    stack = lambda img: np.broadcast_to(img, (4,) + img.shape)  # noqa: E731
    return dict(frame=ccd.expose(radiance, seed=11), noload=ccd.expose(stack(empty), seed=12),
                bright=ccd.expose(4.0 * radiance, seed=13),
                bright_noload=ccd.expose(stack(4.0 * empty), seed=14))


@pytest.mark.render
@pytest.mark.parametrize("filt", ["none", "gaussian", "median"])
def test_reference_and_fast_agree_on_rendered_frames(rendered, filt):
    fast, ref = _fast_ref(Pipeline.from_noload(SENSOR, CAM, rendered["noload"], filter=filt))
    frame = rendered["frame"]
    assert frame.dtype == np.uint8
    a, b = fast.process(frame), ref.process(frame)
    assert_same_readings(a, b, g_rtol=1e-9, u_atol=1e-9)
    if filt != "median":  # a 3x3 median removes the smallest cone spots at this resolution
        assert a.contact.sum() >= 38
    assert np.isfinite(a.u).all() and np.all(np.abs(a.u) < fast.grids.radius)


@pytest.mark.render
@pytest.mark.parametrize("filt", ["none", "gaussian"])
def test_saturated_rendered_frames(rendered, filt):
    frame = rendered["bright"]
    hot = np.argwhere(frame == 255)
    assert len(hot) > 0
    fast, ref = _fast_ref(Pipeline.from_noload(SENSOR, CAM, rendered["bright_noload"], filter=filt))
    a, b = fast.process(frame), ref.process(frame)
    assert_same_readings(a, b, g_rtol=1e-9, u_atol=1e-9)
    # Independent truth: where the saturated pixels lie on the dome.
    pts = CAM.unproject(hot.astype(np.float64), SENSOR)
    dist = R * np.arccos(np.clip(pts @ SENSOR.element_frames[:, 2, :].T / R, -1, 1))  # (hot, E)
    radius, margin = fast.grids.radius, 0.6  # margin: about one pixel footprint
    must = np.zeros(N_EL, bool)
    must[np.argmin(dist, axis=1)[dist.min(axis=1) < radius - margin]] = True
    may = (dist < radius + margin).any(axis=0)
    assert must.sum() >= 5
    assert np.all(a.saturated[must]) and not np.any(a.saturated[~may])


# ---------------------------------------------------------------------------- 5. stacks and readings
@pytest.fixture(scope="module")
def long_stack(small_scene):
    """70 uint8 frames (> CHUNK_FRAMES): three scenes repeated, with noise."""
    frame, base, _ = small_scene
    scenes = [frame, np.roll(frame, 3, axis=1), base]
    rng = np.random.default_rng(9)
    st = np.stack([scenes[t % 3] for t in range(70)]) + rng.integers(-1, 2, (70,) + SMALL.shape)
    return np.clip(st, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("t_n", [1, 3, 70])
@pytest.mark.parametrize("filt", ["none", "gaussian"])
def test_stack_equals_frame_by_frame(small, long_stack, small_scene, t_n, filt):
    assert 70 > CHUNK_FRAMES
    pipe = small.replace(baseline=small_scene[1], filter=filt)
    st = long_stack[:t_n]
    rs = pipe.process(st)
    assert rs.is_stack and len(rs) == t_n and rs.G.shape == (t_n, N_EL) and rs.u.shape == (t_n, N_EL, 2)
    singles = Readings.stack([pipe.process(f) for f in st])
    assert_same_readings(rs, singles)  # bit-identical
    if t_n == 70:
        assert rs.contact.any(axis=1).sum() >= 40


def test_reference_stack_equals_frame_by_frame(small, long_stack, small_scene):
    pipe = small.replace(baseline=small_scene[1], method="reference")
    rs = pipe.process(long_stack[:3])
    for t in range(3):
        assert_same_readings(rs[t], pipe.process(long_stack[t]))


def test_readings_as_dict_and_indexing(small, long_stack):
    rs = small.process(long_stack[:3])
    d = rs.as_dict()
    assert list(d) == ["frame", "element", "G", "ux", "uy", "contact", "saturated"]
    assert all(len(v) == 3 * N_EL for v in d.values())
    np.testing.assert_array_equal(d["frame"], np.repeat(np.arange(3), N_EL))
    np.testing.assert_array_equal(d["element"], np.tile(np.arange(N_EL), 3))
    np.testing.assert_array_equal(d["G"], rs.G.ravel())
    np.testing.assert_array_equal(d["uy"], rs.u[..., 1].ravel())
    one = small.process(long_stack[1])
    d1 = one.as_dict()
    assert list(d1) == ["element", "G", "ux", "uy", "contact", "saturated"]
    assert all(len(v) == N_EL for v in d1.values())
    np.testing.assert_array_equal(d1["ux"], one.u[:, 0])
    assert_same_readings(rs[1], one)
    assert_same_readings(rs[-1], small.process(long_stack[2]))
    assert len(rs[1:3]) == 2 and rs[1:3].is_stack
    assert len(list(rs)) == 3 and not one.is_stack and one.n_elements == N_EL
    with pytest.raises(TypeError, match="single frame have no length"):
        len(one)
    with pytest.raises(TypeError, match="single frame cannot be indexed"):
        one[0]
    with pytest.raises(InputError, match="cannot stack an empty list"):
        Readings.stack([])
    with pytest.raises(ShapeError, match=re.escape("u must have shape (41, 2), got (41,)")):
        Readings(one.G, one.G, one.contact, one.saturated)
    empty = Readings.empty(N_EL, 2)
    assert empty.G.shape == (2, N_EL) and not empty.contact.any()


# ---------------------------------------------------------------------------- 6. dtypes, shapes, inputs
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("method", ["fast", "reference"])
def test_dtypes_give_the_same_readings(small, small_scene, dtype, method):
    frame, base, elements = small_scene
    pipe = small.replace(baseline=base, method=method)
    expected = pipe.process(frame)
    r = pipe.process(frame.astype(dtype))
    if dtype == np.float32:
        assert_same_readings(r, expected, g_rtol=1e-6, u_atol=1e-6)
    else:
        assert_same_readings(r, expected)
    assert r.G.dtype == np.float64 and r.contact[elements].all()
    assert_no_contact_except(r, elements)
    # (H, W) and (1, H, W): the same numbers, with and without the frame axis.
    rs = pipe.process(frame.astype(dtype)[None])
    assert rs.G.shape == (1, N_EL) and r.G.shape == (N_EL,)
    assert_same_readings(rs[0], r)


@pytest.mark.parametrize("method", ["fast", "reference"])
@pytest.mark.parametrize("filt", ["none", "gaussian", "median"])
@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_inputs_are_never_modified(small, small_scene, method, filt, dtype):
    frame, base, _ = small_scene
    frame, base = frame.astype(dtype), base.astype(dtype)
    frame_copy, base_copy = frame.copy(), base.copy()
    pipe = small.replace(baseline=base, method=method, filter=filt)
    pipe.process(frame)
    pipe.process(np.stack([frame, frame]))
    np.testing.assert_array_equal(frame, frame_copy)
    np.testing.assert_array_equal(base, base_copy)


@pytest.mark.parametrize("method", ["fast", "reference"])
def test_read_only_and_non_contiguous_inputs(small, small_scene, method):
    frame, base, _ = small_scene
    frame = frame.astype(np.uint8)
    pipe = small.replace(baseline=base, method=method)
    expected = pipe.process(frame)
    big = np.zeros((SMALL.height, 2 * SMALL.width), np.uint8)
    big[:, ::2] = frame
    ro = frame.copy()
    ro.flags.writeable = False
    flipped = frame[::-1, ::-1].copy()[::-1, ::-1]
    for view in (big[:, ::2], np.asfortranarray(frame), ro, flipped):
        assert_same_readings(pipe.process(view), expected)
    st = np.zeros((4,) + SMALL.shape, np.uint8)
    st[::2] = frame
    expected_st = pipe.process(np.stack([frame, frame]))
    for view in (st[::2], np.asfortranarray(np.stack([frame, frame]))):
        assert_same_readings(pipe.process(view), expected_st)
    assert_same_readings(pipe.process(frame.tolist()), expected)  # nested lists are arrays too


def test_signed_integer_frames(small, small_scene):
    frame, base, _ = small_scene
    pipe = small.replace(baseline=base)
    for dtype in (np.int16, np.int32, np.int64):
        assert_same_readings(pipe.process(frame.astype(dtype)), pipe.process(frame))


# ---------------------------------------------------------------------------- 7. baselines and streams
@pytest.mark.parametrize("method", ["fast", "reference"])
def test_baseline_ways_agree_with_subtracting_by_hand(small, small_scene, method):
    frame, base, elements = small_scene
    # a structured baseline, constant along rows: a one-frame baseline's noise estimate (from
    # differences along rows) is 0, so the threshold stays the scalar one of the pipeline by hand
    base = base + (np.arange(SMALL.height)[:, None] // 7) % 3
    frame8, base8 = frame.astype(np.uint8), base.astype(np.uint8)
    a = Pipeline(SENSOR, SMALL, baseline=base8, method=method).process(frame8)
    b = small.replace(method=method).with_baseline(base8).process(frame8)
    assert_same_readings(a, b)
    by_hand = small.replace(method=method).process(np.maximum(frame - base, 0.0))
    assert_same_readings(a, by_hand, g_rtol=1e-12, u_atol=1e-12)
    assert a.contact[elements].all()


def test_baseline_stack_is_averaged_and_read_only(small):
    st = np.stack([np.full(SMALL.shape, v, np.uint8) for v in (10, 11, 13)])
    pipe = small.with_baseline(st)
    np.testing.assert_allclose(pipe.baseline, 34.0 / 3.0, rtol=1e-15, atol=0)
    assert pipe.baseline.dtype == np.float64 and not pipe.baseline.flags.writeable
    assert pipe.grids is small.grids  # the geometry is shared
    assert small.baseline is None  # with_baseline returns a new pipeline
    assert small.replace(filter="median").filter_size == 3
    assert small.replace(filter="median").replace(filter="gaussian").filter_size == 1.0



def test_replacing_how_a_pipeline_runs_copies_it_without_measuring_again(small, small_scene):
    """kernel and threads change no reading: replace() copies the pipeline, not measuring the baseline again."""
    from optitact.pipeline.frame_pipeline import RUN_OPTIONS

    frame, base, _ = small_scene
    pipe = small.with_baseline(base.astype(np.uint8))
    frames = np.stack([frame, base]).astype(np.uint8)
    pipe.process(frames)  # fills the per-dtype cache, which the copy must not share
    for changes in ({"kernel": "numpy"}, {"threads": 1}, {"kernel": "auto", "threads": 2}):
        assert changes.keys() <= RUN_OPTIONS
        other = pipe.replace(**changes)
        assert other is not pipe and other.fast_path is not pipe.fast_path
        assert other.noise_map is pipe.noise_map and other.entry_threshold is pipe.entry_threshold
        assert other.floor is pipe.floor  # not made again
        fresh = Pipeline(SENSOR, SMALL, baseline=base.astype(np.uint8), **changes)
        assert (other.kernel, other.threads) == (fresh.kernel, fresh.threads)
        np.testing.assert_array_equal(other.floor, fresh.floor)
        a, b = other.process(frames), fresh.process(frames)
        for x, y in zip((a.G, a.u, a.contact, a.saturated), (b.G, b.u, b.contact, b.saturated), strict=True):
            np.testing.assert_array_equal(x, y)
    assert (pipe.kernel, pipe.threads) == (small.kernel, small.threads)  # the original is unchanged
    with pytest.raises(InputError, match="kernel must be one of"):
        pipe.replace(kernel="fortran")
    with pytest.raises(InputError, match="threads"):
        pipe.replace(threads=0)

def test_from_noload(small, small_scene):
    frame, base, elements = small_scene
    rng = np.random.default_rng(2)
    t_n, sigma = 6, 1.5
    st = np.clip(np.rint(base + 10.0 + rng.normal(0.0, sigma, (t_n,) + SMALL.shape)), 0, 255)
    st = st.astype(np.uint8)
    pipe = Pipeline.from_noload(SENSOR, SMALL, st, filter="median")
    by_hand = math.sqrt(st.astype(np.float64).var(axis=0, ddof=1).mean())
    np.testing.assert_allclose(pipe.noise_sigma, by_hand * math.sqrt(1 + 1 / t_n), rtol=1e-12, atol=0)
    np.testing.assert_allclose(estimate_noise(st), math.hypot(sigma, math.sqrt(1 / 12)), rtol=0.03, atol=0)
    np.testing.assert_allclose(pipe.baseline, st.mean(axis=0), rtol=1e-15, atol=0)
    assert pipe.filter == "median" and pipe.filter_size == 3
    # sqrt(1 + 1/T): the noise of a new frame minus the T-frame mean.
    new = np.rint(base + 10.0 + rng.normal(0.0, sigma, SMALL.shape))
    np.testing.assert_allclose(np.std(new - pipe.baseline), pipe.noise_sigma, rtol=0.04, atol=0)
    r = pipe.process(np.clip(frame + 10.0, 0, 255).astype(np.uint8))
    assert r.contact[elements].all()
    assert_no_contact_except(r, elements)
    assert not pipe.process(st).contact.any()
    with pytest.raises(ShapeError, match="T >= 2"):
        Pipeline.from_noload(SENSOR, SMALL, st[0])


def test_stream_with_baseline_frames(small, small_scene):
    frame, base, _ = small_scene
    rng = np.random.default_rng(5)
    noload = [np.clip(base + rng.integers(0, 2, SMALL.shape), 0, 255).astype(np.uint8) for _ in range(2)]
    frames = noload + [frame.astype(np.uint8), base.astype(np.uint8), frame.astype(np.uint8)]
    out = list(small.stream(iter(frames), baseline_frames=2))
    assert len(out) == len(frames) and all(not r.is_stack for r in out)
    expected = small.with_baseline(np.stack(noload)).process(np.stack(frames))
    for t, r in enumerate(out):
        assert_same_readings(r, expected[t])
    plain = list(small.stream(frames))
    assert_same_readings(Readings.stack(plain), small.process(np.stack(frames)))


def test_stream_errors(small):
    frame = np.zeros(SMALL.shape, np.uint8)
    with pytest.raises(InputError, match="stream ended after 1 frames, before the 2 baseline frames"):
        list(small.stream([frame], baseline_frames=2))
    with pytest.raises(InputError, match="baseline_frames must be >= 0"):
        list(small.stream([frame], baseline_frames=-1))
    with pytest.raises(TypeError, match="baseline_frames must be an integer"):
        list(small.stream([frame], baseline_frames=1.5))
    assert list(small.stream([], baseline_frames=2)) == []


def test_take_baseline_splits_the_first_frames():
    from optitact.pipeline.baseline import take_baseline

    items = [(f"f{k}", np.full((2, 3), k, np.uint8)) for k in range(5)]
    base, head, rest = take_baseline(items, 2, frame=lambda item: item[1])
    assert base.shape == (2, 2, 3) and [n for n, _ in head] == ["f0", "f1"]
    assert [n for n, _ in rest] == ["f2", "f3", "f4"]
    base, head, rest = take_baseline(iter(range(3)), 0)
    assert base is None and head == [] and list(rest) == [0, 1, 2]
    with pytest.raises(InputError, match="stream ended after 1 frames, before the 3 baseline frames"):
        take_baseline(items[:1], 3, frame=lambda item: item[1])


def test_region_weights_seam(small):
    """The public seam the renderer uses: the pixels each element's region reads."""
    from optitact.pipeline.regions import region_weights, split_regions

    w = small.region_weights
    assert small.replace(k=4.0).region_weights is w  # shared in memory per geometry
    folded = region_weights(split_regions(SENSOR, SMALL), SMALL.shape)  # from the grids themselves
    for name in ("pixel", "label", "weights", "pixel_area", "n_pixels"):
        assert getattr(w, name).tobytes() == getattr(folded, name).tobytes(), name
    assert (w.radius, w.grid_mm) == (folded.radius, folded.grid_mm) == (small.grids.radius, small.grids.grid_mm)
    pixel, label = w.region_pixels([0, 5])
    assert set(np.unique(label)) == {0, 5}
    np.testing.assert_array_equal(pixel, w.pixel[np.isin(w.label, [0, 5])])
    mask = np.zeros(small.grids.n_elements, bool)
    mask[[0, 5]] = True
    np.testing.assert_array_equal(w.region_pixels(mask)[0], pixel)
    assert w.region_pixels()[0] is w.pixel
    assert np.array_equal(np.bincount(w.label, minlength=len(w.n_pixels)), w.n_pixels)


# ---------------------------------------------------------------------------- 8. errors
H, W = SMALL.shape


@pytest.mark.parametrize("frames,exc,match", [
    (np.zeros(5), ShapeError, re.escape("frames must be a frame (H, W) or a stack (T, H, W), got shape (5,)")),
    (np.zeros((1, 1, H, W)), ShapeError, re.escape("or a stack (T, H, W), got shape (1, 1, 120, 160)")),
    (np.zeros((H, W + 1)), ShapeError, re.escape("frames must be 120x160 (H, W) for this camera, got 120x161")),
    (np.zeros((2, W, H)), ShapeError, re.escape("for this camera, got 160x120")),
    (np.zeros((0, H, W), np.uint8), InputError, re.escape("frames is an empty stack (0 frames)")),
    (np.zeros((H, W), bool), TypeError, "integer or float dtype .* got bool"),
    (np.zeros((H, W), complex), TypeError, "integer or float dtype .* got complex128"),
    (np.zeros((H, W), object), TypeError, "integer or float dtype .* got object"),
    (np.full((H, W), "a"), TypeError, "integer or float dtype"),
])
def test_bad_frames(small, frames, exc, match):
    with pytest.raises(exc, match=match):
        small.process(frames)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_pixel_names_frame_and_pixel(small, dtype, bad):
    st = np.zeros((3, H, W), dtype)
    st[1, 5, 7] = bad
    want = re.escape(f"frames must be finite, got {st[1, 5, 7]} at frame 1, pixel (row 5, col 7)")
    with pytest.raises(InputError, match=want):
        small.process(st)
    with pytest.raises(InputError, match=re.escape("at frame 0, pixel (row 5, col 7)")):
        small.process(st[1])
    with pytest.raises(InputError, match=re.escape("at frame 0, pixel (row 5, col 7)")):
        small.replace(method="reference").process(st[1])


def test_negative_integer_pixel(small):
    st = np.zeros((2, H, W), np.int64)
    st[1, 2, 4] = -3
    with pytest.raises(InputError, match=re.escape("frames must be non-negative grey levels, got -3 at "
                                                   "frame 1, pixel (row 2, col 4)")):
        small.process(st)


@pytest.mark.parametrize("kwargs,exc,match", [
    (dict(method="slow"), InputError, re.escape("method must be one of ('fast', 'reference'), got 'slow'")),
    (dict(filter="box"), InputError,
     re.escape("filter must be one of ('none', 'gaussian', 'median'), got 'box'")),
    (dict(filter="median", filter_size=4), InputError, "filter_size of a median must be odd, got 4"),
    (dict(filter="median", filter_size=2.5), TypeError, "filter_size must be an integer, got float"),
    (dict(filter="gaussian", filter_size=0.0), InputError, "filter_size must be finite and > 0"),
    (dict(noise_sigma=-1.0), InputError, "noise_sigma must be finite and >= 0, got -1.0"),
    (dict(noise_sigma=float("nan")), InputError, "noise_sigma must be finite and >= 0"),
    (dict(noise_sigma="1"), TypeError, "noise_sigma must be a real number, got str"),
    (dict(k=-3.0), InputError, "k must be finite and >= 0"),
    (dict(min_pixels=-1), InputError, "min_pixels must be finite and >= 0"),
    (dict(saturation=0.0), InputError, "saturation must be finite and > 0"),
    (dict(radius=0.0), InputError, "radius must be finite and > 0"),
    (dict(radius=2.0, grid_mm=1e-3), InputError, "grid_mm=0.001 is too fine for radius=2.0"),
    (dict(baseline=np.zeros((H, W + 2))), ShapeError,
     re.escape("baseline must be 120x160 (H, W) for this camera, got 120x162")),
    (dict(baseline=np.full((H, W), np.nan)), InputError, "baseline must be finite, got nan at frame 0"),
    (dict(baseline=np.zeros((0, H, W))), InputError, "baseline is an empty stack"),
])
def test_bad_options(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        Pipeline(SENSOR, SMALL, **kwargs)


@pytest.mark.parametrize("args,match", [
    (("sensor", SMALL), "sensor must be a DomeSensor, got str"),
    ((SENSOR, None), "camera must be a FisheyeCamera, got NoneType"),
    ((SMALL, SENSOR), "sensor must be a DomeSensor, got FisheyeCamera"),
])
def test_wrong_sensor_or_camera_type(args, match):
    with pytest.raises(TypeError, match=match):
        Pipeline(*args)


def test_errors_subclass_the_builtins():
    assert issubclass(ShapeError, ValueError) and issubclass(InputError, ValueError)


# ---------------------------------------------------------------------------- 9. no contact
@pytest.mark.parametrize("method", ["fast", "reference"])
@pytest.mark.parametrize("filt", ["none", "gaussian", "median"])
def test_no_contact_frames(small, method, filt):
    pipe = small.replace(method=method, filter=filt, noise_sigma=1.0)
    level = np.full(SMALL.shape, 37, np.uint8)
    rng = np.random.default_rng(6)
    noise = (37 + rng.integers(-1, 2, SMALL.shape)).astype(np.uint8)  # std 0.82 < noise_sigma
    cases = [(pipe, np.zeros(SMALL.shape, np.uint8)), (pipe, np.zeros(SMALL.shape)),
             (pipe.with_baseline(level), level), (pipe.with_baseline(level), level.astype(np.float32)),
             (pipe.with_baseline(level), np.full(SMALL.shape, 20, np.uint8)),  # below the baseline
             (pipe.with_baseline(level), noise), (pipe.with_baseline(level), np.stack([level, noise]))]
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        for p, frame in cases:
            r = p.process(frame)
            assert not r.contact.any() and not r.saturated.any()
            assert np.all(r.G == 0.0) and np.all(r.u == 0.0)
            assert np.isfinite(r.G).all() and np.isfinite(r.u).all()


@pytest.mark.parametrize("filt", [
    "none",
    "gaussian",
    "median",
])
def test_noload_frames_rarely_read_contact(filt):
    """Fresh no-load frames of known noise: at most 2 % of the regions read contact."""
    rng = np.random.default_rng(2)
    noload = lambda t: np.clip(np.rint(20 + rng.normal(0.0, 1.5, (t,) + SMALL.shape)), 0, 255)  # noqa: E731
    pipe = Pipeline.from_noload(SENSOR, SMALL, noload(6).astype(np.uint8), filter=filt)
    r = pipe.process(noload(20).astype(np.uint8))
    assert r.contact.mean() <= 0.02


def test_contact_needs_more_than_the_noise_floor(small):
    """One pixel just above the threshold is not contact (min_pixels=3); a bright one is."""
    px = np.round(SMALL.project(SENSOR.element_positions[0], SENSOR)).astype(int)
    for value, contact in ((2, False), (40, True)):
        frame = np.zeros(SMALL.shape, np.uint8)
        frame[px[0], px[1]] = value  # threshold 1.5
        for method in ("fast", "reference"):
            r = small.replace(method=method).process(frame)
            assert r.contact[0] == contact and r.contact.sum() == int(contact)
            assert (r.G[0] > 0) == contact


def test_processing_frames_never_imports_mitsuba():
    code = (
        "import sys, numpy as np, optitact\n"
        "cam = optitact.optics.camera.FisheyeCamera(width=64, height=48)\n"
        "from optitact.optics.sensor import DomeSensor\n"
        "from optitact.pipeline.frame_pipeline import Pipeline\n"
        "p = Pipeline(DomeSensor.default(), cam, filter='gaussian')\n"
        "p.process(np.zeros(cam.shape, np.uint8))\n"
        "p.replace(method='reference').process(np.zeros(cam.shape))\n"
        "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_process_command_imports_only_what_it_needs(tmp_path):
    """`optitact process` with a calibration, on .npy frames: no renderer, cluster, learning, plots, stores."""
    frames = np.zeros((3,) + optitact.optics.camera.FisheyeCamera().shape, np.uint8)
    frames[2, 200:210, 300:310] = 60
    np.save(tmp_path / "frames.npy", frames)
    out = tmp_path / "r.csv"
    code = (
        "import sys\n"
        "import optitact.pipeline.kernel\n"
        "optitact.pipeline.kernel.available = lambda: False  # NumPy sums: no numba compile in a fresh cache\n"
        "from optitact.cli import main\n"
        f"rc = main(['process', {str(tmp_path / 'frames.npy')!r}, '--calibration', 'default',\n"
        f"           '--out', {str(out)!r}])\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in "
        "{'mitsuba', 'drjit', 'dask', 'distributed', 'sklearn', 'matplotlib', 'zarr', 'pandas', 'pyarrow'})\n"
        "print(rc, heavy)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert run.stdout.split("\n")[-2] == "0 []", run.stdout + run.stderr
    assert len(out.read_text().splitlines()) == 1 + 3 * N_EL  # it did process every frame



def test_noise_map_from_a_baseline_stack():
    """A stack baseline raises the threshold where the background is noisy, and only there."""
    rng = np.random.default_rng(4)
    noisy = np.zeros(SMALL.shape, bool)
    noisy[40:60, 50:90] = True
    sigma = np.where(noisy, 6.0, 0.3)
    stack = np.clip(np.rint(30 + rng.normal(0, 1, (8,) + SMALL.shape) * sigma), 0, 255).astype(np.uint8)
    pipe = Pipeline(SENSOR, SMALL, baseline=stack)
    assert pipe.threshold_map.shape == SMALL.shape
    inner = np.zeros_like(noisy)
    inner[44:56, 54:86] = True  # away from the 3 x 3 + blur spread at the border
    # 3 sigma sqrt(1 + 1/8) = 19.1 where sigma = 6; the variance is pooled over neighbouring pixels
    # (about 198 degrees of freedom from 8 frames: Student's t gives 3.05 sigma for k = 3) and its 3 x 3
    # maximum taken, so a little above, never far below
    ratio = pipe.threshold_map[inner] / (3 * 6.0 * np.sqrt(1.125))
    assert ratio.min() > 0.9 and ratio.max() < 1.3 and 0.95 < np.median(ratio) < 1.15
    quiet = ~noisy & (np.abs(np.arange(SMALL.width) - 70) > 30)[None]
    assert np.all(pipe.threshold_map >= pipe.threshold)
    assert np.all(pipe.threshold_map[quiet] < 3.5)  # 3 x ~0.4 grey levels after rounding, x 1.3 (max)
    fresh = np.clip(np.rint(30 + rng.normal(0, 1, (20,) + SMALL.shape) * sigma), 0, 255)
    r = pipe.process(fresh.astype(np.uint8))
    assert r.contact.mean() < 0.01  # the noisy patch does not read as contact
    fast, ref = _fast_ref(pipe)
    assert_same_readings(fast.process(fresh[:3].astype(np.uint8)), ref.process(fresh[:3].astype(np.uint8)),
                         g_rtol=1e-12, u_atol=1e-12)
    single = Pipeline(SENSOR, SMALL, baseline=stack[0])
    assert single.threshold_map is None
    assert single.replace(k=2.0).threshold_map is None
    assert pipe.replace(k=2.0).threshold_map is not None


def test_poisson_cdf_is_scipys_without_importing_it():
    """The impulse floor's Poisson CDF (no scipy.special at start-up) equals scipy.special.pdtr."""
    from scipy.special import pdtr

    from optitact.pipeline.baseline import poisson_cdf

    k = np.arange(0, 250)
    mean = np.array([0.0, 1e-9, 0.02, 0.7, 4.0, 23.5, 90.0])
    np.testing.assert_allclose(poisson_cdf(k, mean), pdtr(k[None, :], mean[:, None]), rtol=0, atol=1e-13)


@pytest.mark.parametrize("method, kernel", [("fast", "numba"), ("fast", "numpy"), ("reference", "auto")])
def test_tail_gaussian_adds_back_what_the_threshold_clips(method, kernel):
    """Analytic Gaussian spots on the dome (true G = A 2 pi s^2, 2-3 pixels wide on this small camera)
    thresholded at a tenth and a fifth of their peak: G alone misses 8-25 %; with tail='gaussian' what
    is left is the pixels' coarseness (lit area counted in whole pixels, the dewarp's interpolation):
    within 10 % in every ring and on average under a third of the miss. u and the contact flags do not
    change. (On the noise sweep's spots it takes the bias from -2.4 % to +0.1 % at the nominal noise.)"""
    if kernel == "numba":
        pytest.importorskip("numba")
    spots = [(e, (0.1, -0.05), 0.35, 40.0) for e in RING_ELEMENTS]
    frame = spot_frame(CAM, spots)
    truth = true_g(40.0, 0.35)
    for threshold in (4.0, 8.0):
        plain = Pipeline(SENSOR, CAM, noise_sigma=threshold / 3.0, k=3.0, min_pixels=1, method=method,
                         kernel=kernel)
        tail = plain.replace(tail="gaussian")
        a, b = plain.process(frame), tail.process(frame)
        before = np.abs(a.G[RING_ELEMENTS] / truth - 1.0)
        after = np.abs(b.G[RING_ELEMENTS] / truth - 1.0)
        assert np.all(a.G[RING_ELEMENTS] < 0.93 * truth)
        assert after.max() <= 0.10 and after.mean() < before.mean() / 3.0, (before, after)
        np.testing.assert_array_equal(b.u, a.u)
        np.testing.assert_array_equal(b.contact, a.contact)
    with pytest.raises(ValueError, match="tail must be one of"):
        Pipeline(SENSOR, SMALL, tail="exponential")


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 1000, 1001])
def test_start_up_median_and_quantile_are_numpys_to_the_bit(n):
    """The baseline's noise and impulse statistics use NumPy's median and quantile, re-done without numpy.ma."""
    from optitact.pipeline.baseline import _quantile
    from optitact.pipeline.imageops import _median

    rng = np.random.default_rng(n)
    for _ in range(20):
        for x in (rng.normal(size=n) * 10.0 ** rng.uniform(-4, 4), rng.integers(0, 4, n).astype(float)):
            assert _median(x) == np.median(x)
            for q in (0.0, 0.1, 0.5, 0.9, 1.0):
                assert _quantile(x, q) == np.quantile(x, q)
