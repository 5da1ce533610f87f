"""Tests for the frame changes in optitact.forces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.optics.force_frames import global_from_local, local_from_global
from optitact.optics.sensor import DomeSensor

N = 41


@pytest.fixture(scope="module")
def sensor():
    return DomeSensor.default()


def _normal_of(polar_deg, azimuth_deg):
    th, ph = math.radians(polar_deg), math.radians(azimuth_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trips(sensor, seed):
    rng = np.random.default_rng(seed)
    local = rng.normal(size=(N, 3))
    np.testing.assert_allclose(local_from_global(sensor, global_from_local(sensor, local)),
                               local, rtol=0, atol=1e-12)
    glob = rng.normal(size=(N, 3))
    np.testing.assert_allclose(global_from_local(sensor, local_from_global(sensor, glob)),
                               glob, rtol=0, atol=1e-12)


def test_magnitudes_preserved(sensor):
    rng = np.random.default_rng(3)
    local = rng.uniform(-2.0, 2.0, (N, 3))
    glob = global_from_local(sensor, local)
    np.testing.assert_allclose(np.linalg.norm(glob, axis=1), np.linalg.norm(local, axis=1),
                               rtol=0, atol=1e-12)
    # Angles between forces on the same element are preserved too.
    other = rng.uniform(-2.0, 2.0, (N, 3))
    np.testing.assert_allclose(np.einsum("ni,ni->n", glob, global_from_local(sensor, other)),
                               np.einsum("ni,ni->n", local, other), rtol=0, atol=1e-12)


def test_apex(sensor):
    f = np.zeros((N, 3))
    f[0] = (0.1, 0.0, 1.0)
    np.testing.assert_allclose(global_from_local(sensor, f)[0], [0.1, 0.0, -1.0], rtol=0,
                               atol=1e-15)
    f[0] = (0.0, 0.2, 0.0)
    np.testing.assert_allclose(global_from_local(sensor, f)[0], [0.0, 0.2, 0.0], rtol=0,
                               atol=1e-15)
    g = np.zeros((N, 3))
    g[0] = (0.3, -0.4, -2.0)
    np.testing.assert_allclose(local_from_global(sensor, g)[0], [0.3, -0.4, 2.0], rtol=0,
                               atol=1e-15)


@pytest.mark.parametrize(
    ("element", "polar_deg", "azimuth_deg"),
    [(1, 22.5, 0.0), (3, 22.5, 90.0), (13, 45.0, 90.0), (33, 67.5, 180.0), (27, 67.5, 45.0)],
)
def test_normal_force_points_into_dome(sensor, element, polar_deg, azimuth_deg):
    f = np.zeros((N, 3))
    f[element, 2] = 2.5
    g = global_from_local(sensor, f)
    np.testing.assert_allclose(g[element], -2.5 * _normal_of(polar_deg, azimuth_deg), rtol=0,
                               atol=1e-12)
    np.testing.assert_array_equal(np.delete(g, element, axis=0), 0.0)


def test_shear_directions_explicit(sensor):
    th = math.radians(22.5)
    f = np.zeros((N, 3))
    f[1] = (1.0, 0.0, 0.0)   # element on +x: local x tilts down the dome
    f[3] = (1.0, 0.0, 0.0)   # element on +y: local x is global x
    f[5] = (0.0, 1.0, 0.0)   # element on -x: local y = z x x is global +y
    g = global_from_local(sensor, f)
    np.testing.assert_allclose(g[1], [math.cos(th), 0.0, -math.sin(th)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(g[3], [1.0, 0.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(g[5], [0.0, 1.0, 0.0], rtol=0, atol=1e-12)


def test_matches_frames_directly(sensor):
    rng = np.random.default_rng(4)
    local = rng.normal(size=(N, 3))
    fr = sensor.element_frames
    expected = (local[:, 0:1] * fr[:, 0] + local[:, 1:2] * fr[:, 1]
                - local[:, 2:3] * fr[:, 2])
    np.testing.assert_allclose(global_from_local(sensor, local), expected, rtol=0, atol=1e-12)


def test_linear(sensor):
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(2, N, 3))
    np.testing.assert_allclose(global_from_local(sensor, 2.0 * a - 3.0 * b),
                               2.0 * global_from_local(sensor, a)
                               - 3.0 * global_from_local(sensor, b), rtol=0, atol=1e-12)


def test_custom_sensor():
    s = DomeSensor(ring_counts=(4, 8), ring_polar_deg=(20.0, 50.0))
    rng = np.random.default_rng(6)
    local = rng.normal(size=(12, 3))
    np.testing.assert_allclose(local_from_global(s, global_from_local(s, local)), local,
                               rtol=0, atol=1e-12)
    f = np.zeros((12, 3))
    f[6, 2] = 1.0
    np.testing.assert_allclose(global_from_local(s, f)[6], -_normal_of(50.0, 90.0), rtol=0,
                               atol=1e-12)


@pytest.mark.parametrize("func", [global_from_local, local_from_global])
def test_inputs_not_mutated_and_new_array(sensor, func):
    rng = np.random.default_rng(7)
    f = rng.normal(size=(N, 3))
    before = f.copy()
    out = func(sensor, f)
    np.testing.assert_array_equal(f, before)
    assert not np.shares_memory(out, f)
    assert out.shape == (N, 3) and out.dtype == np.float64


@pytest.mark.parametrize("dtype", [np.float32, np.int64])
def test_real_dtypes(sensor, dtype):
    f = np.ones((N, 3), dtype=dtype)
    np.testing.assert_allclose(global_from_local(sensor, f),
                               global_from_local(sensor, np.ones((N, 3))), rtol=0, atol=0)


@pytest.mark.parametrize(
    ("func", "name"), [(global_from_local, "forces"), (local_from_global, "forces_global")]
)
@pytest.mark.parametrize("shape", [(N, 2), (N + 1, 3), (3,), (2, N, 3)])
def test_wrong_shape(sensor, func, name, shape):
    with pytest.raises(ShapeError, match=rf"^{name} must have shape \(41, 3\)"):
        func(sensor, np.zeros(shape))


@pytest.mark.parametrize(
    ("func", "name"), [(global_from_local, "forces"), (local_from_global, "forces_global")]
)
def test_non_finite(sensor, func, name):
    f = np.zeros((N, 3))
    f[2, 2] = np.nan
    with pytest.raises(InputError, match=rf"^{name} must be finite, got nan at index \(2, 2\)"):
        func(sensor, f)


@pytest.mark.parametrize(
    ("func", "name"), [(global_from_local, "forces"), (local_from_global, "forces_global")]
)
@pytest.mark.parametrize("dtype", [bool, complex, object])
def test_wrong_dtype(sensor, func, name, dtype):
    with pytest.raises(TypeError, match=rf"^{name} must be a real numeric array"):
        func(sensor, np.zeros((N, 3), dtype=dtype))
