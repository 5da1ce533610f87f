"""Tests for the contact model in optitact.optics.contact."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import optitact.calib
import optitact.forces
import pytest

import optitact
import optitact.pipeline.frame_pipeline
from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera
from optitact.optics.contact import TIP_MARGIN, Contacts, cone_loads, contact_patches
from optitact.optics.camera import pixel_from_dome
from optitact.optics.sensor import DomeSensor

N = 41
K = 8


@pytest.fixture(scope="module")
def sensor():
    return DomeSensor.default()


def _support(sensor, direction):
    """Distance from the centre to the edge of the regular cone polygon along ``direction``."""
    half = math.pi / sensor.n_cones
    # Nearest edge normal; edge normals lie at pi/k + 2 pi j/k, between cone directions.
    edge_normal = half + 2 * half * round((direction - half) / (2 * half))
    return sensor.cone_circle_radius * math.cos(half) / math.cos(direction - edge_normal)


def _random_untipped_forces(sensor, rng, *, fraction=0.9):
    """Random loads whose centre of pressure lies inside ``fraction`` of the tip limit."""
    fz = rng.uniform(0.05, 3.0, N)
    ang = rng.uniform(0.0, 2 * np.pi, N)
    frac = rng.uniform(0.0, fraction, N)
    limit = np.array([TIP_MARGIN * _support(sensor, a) for a in ang])
    ft = frac * limit * fz / sensor.lever_arm
    return np.stack([ft * np.cos(ang), ft * np.sin(ang), fz], axis=1)


def _normal(fz):
    f = np.zeros((N, 3))
    f[:, 2] = fz
    return f


def test_support_helper_is_regular_octagon(sensor):
    rho = sensor.cone_circle_radius
    assert _support(sensor, 0.0) == pytest.approx(rho, abs=1e-12)
    assert _support(sensor, math.pi / 4) == pytest.approx(rho, abs=1e-12)
    assert _support(sensor, math.pi / 8) == pytest.approx(rho * math.cos(math.pi / 8), abs=1e-12)
    assert _support(sensor, -math.pi / 8) == pytest.approx(rho * math.cos(math.pi / 8), abs=1e-12)


# --------------------------------------------------------------------------- #
# Balance of the columnar feeler
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("preload", [0.0, 0.2])
def test_force_balance(sensor, seed, preload):
    s = dataclasses.replace(sensor, preload=preload)
    rng = np.random.default_rng(seed)
    f = rng.uniform(-1.0, 1.0, (N, 3))
    f[:, 2] = rng.uniform(0.0, 4.0, N)
    loads, _ = cone_loads(s, f)
    assert loads.shape == (N, K)
    np.testing.assert_allclose(loads.sum(axis=1), f[:, 2] + preload, rtol=0, atol=1e-9)
    assert np.all(loads >= 0)


@pytest.mark.parametrize("seed", [3, 4, 5, 6])
def test_moment_balance_untipped(sensor, seed):
    rng = np.random.default_rng(seed)
    f = _random_untipped_forces(sensor, rng, fraction=0.999)
    loads, tipped = cone_loads(sensor, f)
    assert not tipped.any()
    moment = loads @ sensor.cone_offsets
    np.testing.assert_allclose(moment, sensor.lever_arm * f[:, :2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(loads.sum(axis=1), f[:, 2], rtol=0, atol=1e-9)


def test_moment_balance_with_preload(sensor):
    s = dataclasses.replace(sensor, preload=0.3)
    rng = np.random.default_rng(8)
    f = _random_untipped_forces(s, rng, fraction=0.5)
    loads, tipped = cone_loads(s, f)
    assert not tipped.any()
    np.testing.assert_allclose(loads @ s.cone_offsets, s.lever_arm * f[:, :2], rtol=0,
                               atol=1e-6)


@pytest.mark.parametrize("seed", [10, 11])
def test_loads_follow_rigid_feeler_on_sneddon_cones(sensor, seed):
    # P_j ~ max(d0 + theta . r_j, 0)^2: sqrt(P) is affine in r_j on touching cones and the
    # same affine function is <= 0 on lifted cones.
    rng = np.random.default_rng(seed)
    f = _random_untipped_forces(sensor, rng, fraction=0.95)
    loads, _ = cone_loads(sensor, f)
    r = sensor.cone_offsets
    for i in range(N):
        on = loads[i] > 1e-12 * f[i, 2]
        assert on.sum() >= 3
        a = np.column_stack([np.ones(on.sum()), r[on]])
        coef, *_ = np.linalg.lstsq(a, np.sqrt(loads[i, on]), rcond=None)
        np.testing.assert_allclose(a @ coef, np.sqrt(loads[i, on]), rtol=0, atol=1e-7)
        if (~on).any():
            d_off = coef[0] + r[~on] @ coef[1:]
            assert np.all(d_off <= 1e-7)


# --------------------------------------------------------------------------- #
# Pure normal load: Sneddon
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("fz", [0.01, 0.5, 1.0, 3.0])
def test_pure_normal_load_equal_shares(sensor, fz):
    loads, tipped = cone_loads(sensor, _normal(fz))
    np.testing.assert_allclose(loads, fz / K, rtol=0, atol=1e-12)
    assert not tipped.any()


@pytest.mark.parametrize("fz", [0.1, 0.5, 1.0, 2.0, 3.0])
def test_pure_normal_area_sneddon(sensor, fz):
    assert fz / K < sensor.max_cone_load
    c = contact_patches(sensor, _normal(fz))
    expected = 2.0 * fz * math.tan(sensor.cone_half_angle) / sensor.effective_modulus
    np.testing.assert_allclose(c.area_mm2.sum(axis=1), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(c.radii, math.sqrt(expected / K / math.pi), rtol=0, atol=1e-12)
    assert not c.saturated.any()
    np.testing.assert_allclose(c.slide, 0.0, rtol=0, atol=0)


def test_area_linear_in_load(sensor):
    fz = np.linspace(0.1, 3.0, N)
    c = contact_patches(sensor, _normal(fz))
    area = c.area_mm2.sum(axis=1)
    slope = 2.0 * math.tan(sensor.cone_half_angle) / sensor.effective_modulus
    np.testing.assert_allclose(area / fz, slope, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.diff(area), slope * np.diff(fz), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("youngs", "nu", "apex"), [(2.0, 0.3, 60.0), (0.5, 0.0, 120.0)])
def test_sneddon_area_other_materials(youngs, nu, apex):
    s = DomeSensor(youngs_modulus=youngs, poisson_ratio=nu, cone_apex_deg=apex)
    fz = 0.5 * K * s.max_cone_load
    c = contact_patches(s, _normal(fz))
    e_star = youngs / (1 - nu**2)
    np.testing.assert_allclose(c.area_mm2.sum(axis=1),
                               2 * fz * math.tan(math.radians(apex / 2)) / e_star,
                               rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- #
# No load, pull, preload
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("fz", [0.0, -0.5, -10.0])
def test_no_contact_without_compression(sensor, fz):
    f = _normal(fz)
    f[:, 0] = 0.3
    f[:, 1] = -0.2
    loads, tipped = cone_loads(sensor, f)
    np.testing.assert_array_equal(loads, 0.0)
    assert not tipped.any()
    c = contact_patches(sensor, f)
    np.testing.assert_array_equal(c.radii, 0.0)
    assert not c.in_contact.any()
    assert not c.saturated.any()
    np.testing.assert_array_equal(c.slide, 0.0)
    assert np.all(np.isfinite(c.centers))


def test_preload_makes_zero_load_touch(sensor):
    s = dataclasses.replace(sensor, preload=0.1)
    c = contact_patches(s, np.zeros((N, 3)))
    assert c.in_contact.all()
    np.testing.assert_allclose(c.loads, 0.1 / K, rtol=0, atol=1e-12)
    expected = 2.0 * 0.1 * math.tan(s.cone_half_angle) / s.effective_modulus
    np.testing.assert_allclose(c.area_mm2.sum(axis=1), expected, rtol=0, atol=1e-12)


def test_preload_and_pull(sensor):
    s = dataclasses.replace(sensor, preload=0.1)
    f = _normal(0.0)
    f[0, 2] = -0.05   # pull smaller than the preload: still touching
    f[1, 2] = -0.1    # pull equal to the preload: lifts off
    f[2, 2] = -1.0
    loads, _ = cone_loads(s, f)
    np.testing.assert_allclose(loads[0], 0.05 / K, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loads[1:3], 0.0)


def test_mixed_elements_independent(sensor):
    f = _normal(0.0)
    f[7] = (0.05, 0.02, 1.0)
    loads, _ = cone_loads(sensor, f)
    alone, _ = cone_loads(sensor, np.where(np.arange(N)[:, None] == 7, f, 0.0))
    np.testing.assert_array_equal(loads, alone)
    assert np.count_nonzero(loads.sum(axis=1)) == 1


# --------------------------------------------------------------------------- #
# Shear: load transfer and Mindlin slide
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("direction_deg", [0.0, 90.0, 135.0, 200.0, 300.0])
def test_shear_loads_shear_side(sensor, direction_deg):
    phi = math.radians(direction_deg)
    f = _normal(1.0)
    f[:, 0], f[:, 1] = 0.1 * math.cos(phi), 0.1 * math.sin(phi)
    loads, _ = cone_loads(sensor, f)
    u = sensor.cone_offsets / sensor.cone_circle_radius
    towards = u @ np.array([math.cos(phi), math.sin(phi)])
    row = loads[3]
    assert np.all(row[towards > 0.1] > 1.0 / K)
    assert np.all(row[towards < -0.1] < 1.0 / K)
    # Load is a non-decreasing function of how far a cone lies towards the shear.
    order = np.argsort(towards)
    assert np.all(np.diff(row[order]) >= -1e-12)


def test_shear_along_x_explicit(sensor):
    f = _normal(1.0)
    f[:, 0] = 0.1
    loads, _ = cone_loads(sensor, f)
    row = loads[0]
    assert row[0] > 1 / K > row[4]
    assert row[0] == row.max() and row[4] == row.min()
    # Mirror symmetry about local x.
    np.testing.assert_allclose(row[1:], row[1:][::-1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("ft", [0.05, 0.2, 0.5])
@pytest.mark.parametrize("direction_deg", [0.0, 30.0, 250.0])
def test_mindlin_slide(sensor, ft, direction_deg):
    phi = math.radians(direction_deg)
    f = _normal(2.0)
    f[:, 0], f[:, 1] = ft * math.cos(phi), ft * math.sin(phi)
    c = contact_patches(sensor, f)
    assert not c.tipped.any()
    # Mindlin: k_j = 8 G* a_j with the actual (possibly capped) radii, G* = G / (2 - nu).
    g_star = sensor.youngs_modulus / (2 * (1 + sensor.poisson_ratio)) / (2 - sensor.poisson_ratio)
    expected = f[:, :2] / (8.0 * g_star * c.radii.sum(axis=1))[:, None]
    np.testing.assert_allclose(c.slide, expected, rtol=0, atol=1e-12)
    # Parallel to the shear and pointing the same way.
    cross = c.slide[:, 0] * f[:, 1] - c.slide[:, 1] * f[:, 0]
    np.testing.assert_allclose(cross, 0.0, rtol=0, atol=1e-12)
    assert np.all(np.einsum("ni,ni->n", c.slide, f[:, :2]) > 0)


def test_patch_centres_follow_slide(sensor):
    f = _normal(1.5)
    f[:, 0], f[:, 1] = 0.1, -0.05
    c = contact_patches(sensor, f)
    for i in (0, 12, 40):
        expected = sensor.dome_point(np.full(K, i), sensor.cone_offsets + c.slide[i])
        np.testing.assert_allclose(c.centers[i], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("element", [0, 4, 20])
@pytest.mark.parametrize("shift", [1, 2, 3])
def test_rotating_shear_permutes_cones(sensor, element, shift):
    rng = np.random.default_rng(element + 100 * shift)
    ft = rng.uniform(0.05, 0.3)
    phi = rng.uniform(0, 2 * np.pi)
    step = shift * 2 * math.pi / K
    f = _normal(1.0)
    g = _normal(1.0)
    f[element, :2] = ft * math.cos(phi), ft * math.sin(phi)
    g[element, :2] = ft * math.cos(phi + step), ft * math.sin(phi + step)
    lf, _ = cone_loads(sensor, f)
    lg, _ = cone_loads(sensor, g)
    np.testing.assert_allclose(lg[element], np.roll(lf[element], shift), rtol=0, atol=1e-9)


def test_mirroring_shear_mirrors_cones(sensor):
    f = _normal(1.0)
    f[:, 0], f[:, 1] = 0.07, 0.12
    g = f.copy()
    g[:, 1] *= -1
    lf, _ = cone_loads(sensor, f)
    lg, _ = cone_loads(sensor, g)
    mirror = (-np.arange(K)) % K
    np.testing.assert_allclose(lg, lf[:, mirror], rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- #
# Saturation and tipping
# --------------------------------------------------------------------------- #
def test_saturation_caps_radii(sensor):
    c = contact_patches(sensor, _normal(100.0))
    np.testing.assert_allclose(c.radii, sensor.cone_base_radius, rtol=0, atol=1e-15)
    assert c.saturated.all()
    np.testing.assert_allclose(c.loads.sum(axis=1), 100.0, rtol=0, atol=1e-9)


def test_saturation_threshold_is_max_cone_load(sensor):
    p = sensor.max_cone_load
    f = _normal(0.0)
    f[0, 2] = K * p * (1 - 1e-6)
    f[1, 2] = K * p * (1 + 1e-6)
    c = contact_patches(sensor, f)
    assert not c.saturated[0].any()
    assert c.saturated[1].all()
    assert c.radii[0].max() < sensor.cone_base_radius
    np.testing.assert_allclose(c.radii[0], sensor.cone_base_radius, rtol=1e-6, atol=0)


def test_partial_saturation_under_shear(sensor):
    f = _normal(0.0)
    f[0] = (0.6, 0.0, 3.0)
    c = contact_patches(sensor, f)
    sat = c.saturated[0]
    assert sat[0] and not sat[4]
    np.testing.assert_allclose(c.radii[0, sat], sensor.cone_base_radius, rtol=0, atol=1e-15)
    assert np.all(c.loads[0, sat] > sensor.max_cone_load)


@pytest.mark.parametrize(("ft", "fz"), [(10.0, 1.0), (1.0, 0.01), (0.5, 0.3)])
@pytest.mark.parametrize("direction_deg", [0.0, 22.5, 77.0])
def test_tipping(sensor, ft, fz, direction_deg):
    phi = math.radians(direction_deg)
    f = _normal(fz)
    f[:, 0], f[:, 1] = ft * math.cos(phi), ft * math.sin(phi)
    loads, tipped = cone_loads(sensor, f)
    assert tipped.all()
    assert np.all(np.isfinite(loads)) and np.all(loads >= 0)
    np.testing.assert_allclose(loads.sum(axis=1), fz, rtol=0, atol=1e-9)
    # Centre of pressure capped at the tip limit, along the shear direction.
    cop = loads @ sensor.cone_offsets / fz
    limit = TIP_MARGIN * _support(sensor, phi)
    np.testing.assert_allclose(cop, np.broadcast_to(limit * np.array([math.cos(phi),
                                                                      math.sin(phi)]),
                                                    cop.shape), rtol=0, atol=1e-6)
    c = contact_patches(sensor, f)
    assert c.tipped.all()
    assert np.all(np.isfinite(c.centers)) and np.all(np.isfinite(c.slide))


def test_just_below_and_above_tip_limit(sensor):
    limit = TIP_MARGIN * sensor.cone_circle_radius  # along a cone direction
    f = _normal(1.0)
    f[0, 0] = (1 - 1e-6) * limit / sensor.lever_arm
    f[1, 0] = (1 + 1e-6) * limit / sensor.lever_arm
    _, tipped = cone_loads(sensor, f)
    assert not tipped[0] and tipped[1]


# --------------------------------------------------------------------------- #
# Contacts container
# --------------------------------------------------------------------------- #
def test_contacts_shapes_and_surface(sensor):
    rng = np.random.default_rng(21)
    f = _random_untipped_forces(sensor, rng)
    c = contact_patches(sensor, f)
    assert isinstance(c, Contacts)
    assert c.centers.shape == (N, K, 3)
    for name in ("radii", "loads", "saturated", "in_contact", "area_mm2"):
        assert getattr(c, name).shape == (N, K)
    assert c.tipped.shape == (N,) and c.slide.shape == (N, 2)
    assert c.saturated.dtype == bool and c.tipped.dtype == bool
    np.testing.assert_allclose(np.linalg.norm(c.centers, axis=-1), sensor.outer_radius, rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(c.area_mm2, np.pi * c.radii**2, rtol=0, atol=0)
    np.testing.assert_array_equal(c.in_contact, c.radii > 0)


def test_unloaded_patch_centres_are_cone_positions(sensor):
    c = contact_patches(sensor, _normal(1.0))
    element = np.repeat(np.arange(N)[:, None], K, axis=1)
    expected = sensor.dome_point(element, np.broadcast_to(sensor.cone_offsets, (N, K, 2)))
    np.testing.assert_allclose(c.centers, expected, rtol=0, atol=1e-12)
    # Apex cone 0 lies towards +x at arc length cone_circle_radius.
    ang = sensor.cone_circle_radius / sensor.outer_radius
    np.testing.assert_allclose(c.centers[0, 0], sensor.outer_radius * np.array(
        [math.sin(ang), 0.0, math.cos(ang)]), rtol=0, atol=1e-12)


def test_as_dict_table(sensor):
    f = _normal(1.0)
    f[:, 0] = 0.05
    c = contact_patches(sensor, f)
    d = c.as_dict()
    assert set(d) == {"element", "cone", "x", "y", "z", "radius_mm", "load_n", "saturated"}
    lengths = {len(v) for v in d.values()}
    assert lengths == {N * K}
    np.testing.assert_array_equal(d["element"], np.repeat(np.arange(N), K))
    np.testing.assert_array_equal(d["cone"], np.tile(np.arange(K), N))
    np.testing.assert_array_equal(d["radius_mm"], c.radii.ravel())
    np.testing.assert_array_equal(d["load_n"], c.loads.ravel())
    row = 5 * K + 3
    np.testing.assert_array_equal([d["x"][row], d["y"][row], d["z"][row]], c.centers[5, 3])


def test_contacts_frozen(sensor):
    c = contact_patches(sensor, _normal(1.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.radii = np.zeros((N, K))  # type: ignore[misc]


# --------------------------------------------------------------------------- #
# Inputs and errors
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("func", [cone_loads, contact_patches])
def test_inputs_not_mutated(sensor, func):
    rng = np.random.default_rng(5)
    f = _random_untipped_forces(sensor, rng)
    f[0, 2] = -1.0
    f[1] = (50.0, 0.0, 1.0)
    before = f.copy()
    func(sensor, f)
    np.testing.assert_array_equal(f, before)
    f.setflags(write=False)
    func(sensor, f)  # read-only input is fine


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32, np.int64, np.uint8])
def test_real_dtypes_accepted(sensor, dtype):
    f = np.zeros((N, 3), dtype=dtype)
    f[:, 2] = 2
    loads, _ = cone_loads(sensor, f)
    assert loads.dtype == np.float64
    np.testing.assert_allclose(loads, 2.0 / K, rtol=0, atol=1e-12)


def test_list_input_accepted(sensor):
    f = [[0.0, 0.0, 1.0]] * N
    c = contact_patches(sensor, f)
    np.testing.assert_allclose(c.loads, 1.0 / K, rtol=0, atol=1e-12)


@pytest.mark.parametrize("func", [cone_loads, contact_patches])
@pytest.mark.parametrize("shape", [(N, 2), (N - 1, 3), (N, 3, 1), (3,), (N * 3,), (1, N, 3)])
def test_wrong_shape(sensor, func, shape):
    with pytest.raises(ShapeError, match=r"forces must have shape \(41, 3\)") as info:
        func(sensor, np.ones(shape))
    assert isinstance(info.value, ValueError)


def test_wrong_shape_custom_sensor():
    s = DomeSensor(ring_counts=(1, 6), ring_polar_deg=(0, 30))
    with pytest.raises(ShapeError, match=r"forces must have shape \(7, 3\).*got \(41, 3\)"):
        cone_loads(s, np.ones((N, 3)))


@pytest.mark.parametrize("func", [cone_loads, contact_patches])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite(sensor, func, bad):
    f = _normal(1.0)
    f[4, 1] = bad
    with pytest.raises(InputError, match=r"forces must be finite, got .* at index \(4, 1\)") as info:
        func(sensor, f)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("func", [cone_loads, contact_patches])
@pytest.mark.parametrize(
    ("value", "dtype_name"),
    [(np.ones((N, 3), dtype=bool), "bool"),
     (np.ones((N, 3), dtype=complex), "complex128"),
     (np.ones((N, 3), dtype=object), "object"),
     (np.full((N, 3), "1"), "<U1")],
)
def test_wrong_dtype(sensor, func, value, dtype_name):
    with pytest.raises(TypeError, match=rf"forces must be a real numeric array, got dtype "
                                        rf"{dtype_name}"):
        func(sensor, value)


# A sensor or camera of the wrong kind is a TypeError naming the argument (it was an AttributeError).
_S, _CAM = DomeSensor.default(), FisheyeCamera(width=80, height=60)
_Z = np.zeros((41, 3))


@pytest.mark.parametrize("call, name", [
    (lambda: optitact.optics.contact.contact_patches("dome", _Z), "sensor"),
    (lambda: optitact.optics.contact.cone_loads("dome", _Z), "sensor"),
    (lambda: __import__("optitact.optics.loads").optics.loads.indenter_load("dome"), "sensor"),
    (lambda: __import__("optitact.optics.loads").optics.loads.random_load("dome"), "sensor"),
    (lambda: optitact.optics.force_frames.global_from_local("dome", _Z), "sensor"),
    (lambda: optitact.optics.force_frames.local_from_global("dome", _Z), "sensor"),
    (lambda: pixel_from_dome(_S.element_positions[:2], sensor="dome", camera=_CAM), "sensor"),
    (lambda: pixel_from_dome(_S.element_positions[:2], sensor=_S, camera="cam"), "camera"),
    (lambda: optitact.optics.camera.dome_from_pixel([[30.0, 40.0]], sensor="dome", camera=_CAM), "sensor"),
    (lambda: optitact.optics.camera.dome_from_pixel([[30.0, 40.0]], sensor=_S, camera="cam"), "camera"),
    (lambda: _CAM.max_polar_angle("dome"), "sensor"),
    (lambda: _CAM.dome_mask("dome"), "sensor"),
    (lambda: optitact.pipeline.regions.split_regions("dome", _CAM), "sensor"),
    (lambda: optitact.pipeline.regions.split_regions(_S, "cam"), "camera"),
    (lambda: optitact.pipeline.imageops.check_frames(np.zeros((60, 80)), "cam"), "camera"),
    (lambda: optitact.pipeline.frame_pipeline.Pipeline("dome", _CAM), "sensor"),
    (lambda: optitact.calib.document.fingerprint("dome", _CAM, {}), "sensor"),
])
def test_wrong_sensor_or_camera_kind_is_a_type_error_naming_it(call, name):
    with pytest.raises(TypeError, match=rf"^{name} must be a \w+, got str"):
        call()
