"""The piezo16 finger pad: response law, config, layout and simulated frames."""

import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.piezo16 import FINGER_PAD_MASK, Piezo16, Piezo16Config, unit_voltage
from optitact.taxels.sources import Indenter, Scenario, TactileSource, make_source

PITCH = 2.2
FULL_MASK = ("#" * 16,) * 16


def scenario(indenter, depth, *, n=1, **pose):
    return Scenario(indenter, np.arange(n) / 1000.0, depth_mm=depth, **pose)


@pytest.fixture
def src(piezo16_source):
    return piezo16_source


@pytest.fixture
def ideal(piezo16_ideal):
    return piezo16_ideal


def test_law_published_values():
    assert unit_voltage(1.0, 1.0) == pytest.approx(3.06, rel=0, abs=1e-12)
    assert unit_voltage(0.25, 1.0) == pytest.approx(0.4725, rel=0, abs=1e-12)   # "0.47 V for 25 %"
    # 50 % area: silent below q = 0.39 / (3.45 * 0.5) = 0.2261 mm ("about 0.23 mm")
    q = np.array([0.0, 0.1, 0.2, 0.226, 0.227, 0.25])
    v = unit_voltage(0.5, q)
    assert np.all(v[:4] == 0.0) and np.all(v[4:] > 0)
    np.testing.assert_allclose(v[4:], 3.45 * 0.5 * q[4:] - 0.39, rtol=0, atol=1e-12)
    assert unit_voltage(0.0, 5.0) == 0.0


def test_law_vectorised_broadcast():
    p = np.linspace(0, 1, 5)[:, None]
    q = np.linspace(0, 1.5, 7)[None, :]
    v = unit_voltage(p, q)
    assert v.shape == (5, 7) and v.dtype == np.float64
    np.testing.assert_allclose(v, np.maximum(0.0, 3.45 * p * q - 0.39), rtol=0, atol=1e-12)
    assert unit_voltage(1.0, 1.0, gain_v_per_mm=1.0, offset_v=0.0) == 1.0


@pytest.mark.parametrize("p,q,exc,match", [
    (1.1, 0.5, InputError, "p .pressed area fraction. must be in"),
    (-0.1, 0.5, InputError, "p .pressed area fraction"),
    (0.5, -0.1, InputError, "q .compression. must be >= 0"),
    (np.nan, 0.5, InputError, "p must be finite"),
    (0.5, np.inf, InputError, "q must be finite"),
    ([0.5, 0.5], [0.1, 0.2, 0.3], ShapeError, "must broadcast"),
    ("a", 0.5, TypeError, "p must be a real numeric array"),
])
def test_law_bad_input(p, q, exc, match):
    with pytest.raises(exc, match=match):
        unit_voltage(p, q)


def test_registered_source_and_layout():
    s = make_source("piezo16")
    assert isinstance(s, TactileSource) and isinstance(s, Piezo16) and s.name == "piezo16"
    lay = s.layout
    assert lay.shape == (16, 16) and lay.units == "V" and lay.rate_hz == 1000.0
    np.testing.assert_allclose(lay.pitch_mm, (PITCH, PITCH), rtol=0, atol=1e-12)
    assert lay.n_cells == 204
    m = lay.mask
    assert np.array_equal(m, m[:, ::-1])                        # left-right symmetric pad
    assert m[8:12].all() and not m[0, 0] and not m[15, 15]       # full middle rows, rounded corners
    assert m[0].sum() < m[15].sum()                              # rounder at the fingertip than at the base
    assert make_source("piezo16", noise_v=0.0).config.noise_v == 0.0
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("piezo16", colour=1)


@pytest.mark.parametrize("kwargs,exc,match", [
    ({"mask": FINGER_PAD_MASK[:15]}, ShapeError, "mask must be 16 strings of 16 characters"),
    ({"mask": ("#" * 15,) * 16}, ShapeError, "mask must be 16 strings"),
    ({"mask": ("x" * 16,) * 16}, InputError, "mask characters must be"),
    ({"mask": ("." * 16,) * 16}, InputError, "at least one unit"),
    ({"mask": "#" * 256}, TypeError, "mask must be a tuple of row strings"),
    ({"grid_mm": 0.3}, InputError, "electrode_mm / grid_mm must be an integer"),
    ({"noise_v": -0.1}, InputError, "noise_v must be finite and >= 0"),
    ({"elastomer_mm": 0.0}, InputError, "elastomer_mm must be finite and > 0"),
    ({"unit_seed": 1.5}, TypeError, "unit_seed must be an integer"),
    ({"grid": (16,)}, TypeError, "grid must be a pair"),
])
def test_config_validation(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        Piezo16Config(**kwargs)


def test_unit_gains_deterministic():
    a, b = Piezo16(Piezo16Config(unit_seed=3)), Piezo16(Piezo16Config(unit_seed=3))
    assert np.array_equal(a.unit_gain, b.unit_gain)
    assert not np.array_equal(a.unit_gain, Piezo16(Piezo16Config(unit_seed=4)).unit_gain)
    g = a.unit_gain[a.layout.mask]
    assert np.all(a.unit_gain[~a.layout.mask] == 0) and 0.1 > abs(np.log(g).std() - 0.1)


@pytest.mark.parametrize("depth", [0.3, 0.7, 1.2])
def test_flat_press_follows_law_exactly(ideal, depth):
    # a flat plate compresses every electrode fully by the pressing depth (the kernel conserves it)
    sc = scenario(Indenter("flat"), depth)
    state = ideal.compression(sc)
    mask = ideal.layout.mask
    np.testing.assert_allclose(state["pressed_fraction"][0][mask], 1.0, rtol=0, atol=0)
    np.testing.assert_allclose(state["compression_mm"][0][mask], depth, rtol=0, atol=1e-12)
    f = ideal.frames(sc)
    assert f.shape == (1, 16, 16) and f.dtype == np.float64
    np.testing.assert_allclose(f[0][mask], 3.45 * depth - 0.39, rtol=0, atol=1e-12)
    assert np.all(f[0][~mask] == 0)


def test_small_compression_in_dead_zone():
    # 0.1 mm everywhere: 3.45 * 0.1 - 0.39 = -0.045 V, 9 noise sigmas below 0 -> exactly 0 despite the noise
    s = Piezo16(Piezo16Config(unit_gain_spread=0.0))
    assert np.all(s.frames(scenario(Indenter("flat"), 0.1, n=5), seed=1) == 0.0)
    assert np.all(s.frames(scenario(Indenter("flat"), 0.0), seed=1) == 0.0)
    # 0.2 mm: 0.3 V above zero; the noise shows
    v = s.frames(scenario(Indenter("flat"), 0.2, n=5), seed=1)[:, s.layout.mask]
    assert abs(v.mean() - (0.69 - 0.39)) < 0.001 and 0.004 < v.std() < 0.006


def _line_kernel(h, cutoff, x):
    """Line integral along y of the Boussinesq kernel 3h^3 / (2 pi (r^2 + h^2)^2.5), cut at r = cutoff h."""
    a2 = x * x + h * h
    ymax = np.sqrt(np.clip((cutoff * h) ** 2 - x * x, 0.0, None))
    prim = ymax * (2 * ymax ** 2 + 3 * a2) / (3 * a2 ** 2 * (a2 + ymax ** 2) ** 1.5)
    return 2 * prim


def test_pipe_compression_matches_line_spreading(ideal):
    # independent truth: the pipe's 1-D indentation profile convolved with the analytic line kernel
    radius, depth, x0, h, cut = 10.0, 0.7, 0.37, 2.0, 4.0
    sc = scenario(Indenter("cylinder", size_mm=radius), depth, x_mm=x0, angle_rad=math.pi / 2)
    state = ideal.compression(sc)
    pq = state["mean_compression_mm"][0]
    mask = ideal.layout.mask
    for r in range(16):                         # a long pipe along y: every row reads the same
        np.testing.assert_allclose(pq[r][mask[r]], pq[9][mask[r]], rtol=0, atol=1e-9)
    g = 0.005
    xs = np.arange(-40, 40 + g / 2, g)
    surface = radius - np.sqrt(np.clip(radius ** 2 - (xs - x0) ** 2, 0, None))
    u = np.where(np.abs(xs - x0) < radius, np.clip(depth - surface, 0, None), 0.0)
    kx = np.arange(-cut * h, cut * h + g / 2, g)
    k = _line_kernel(h, cut, kx)
    w = np.convolve(u, k / k.sum(), mode="same")
    centres = (np.arange(16) - 7.5) * PITCH
    expected = np.array([w[np.abs(xs - c) <= 1.0].mean() for c in centres])
    np.testing.assert_allclose(pq[9], expected, rtol=0, atol=1.5e-3)   # untruncated Flamant differs by 3e-3
    # the elastomer spreads: electrodes wholly outside the rigid contact (half width sqrt(2 R d) = 3.74 mm)
    # are compressed, and the peak is lower than the pressing depth
    assert pq[9].max() < depth - 0.05
    assert np.any((np.abs(centres - x0) - 1.0 > math.sqrt(2 * radius * depth)) & (pq[9] > 0.03))
    # p·q is the electrode-mean compression, and p is a fraction
    p, q = state["pressed_fraction"][0], state["compression_mm"][0]
    assert np.all((p >= 0) & (p <= 1))
    np.testing.assert_allclose(p * q, pq, rtol=0, atol=1e-12)


def test_sphere_position_convention(ideal):
    # a sphere over cell (row 9, col 12): x along columns, y along rows, origin at the grid centre
    x, y = (12 - 7.5) * PITCH, (9 - 7.5) * PITCH
    f = ideal.frames(scenario(Indenter("sphere", size_mm=5.0), 0.8, x_mm=x, y_mm=y))[0]
    assert np.unravel_index(np.argmax(f), f.shape) == (9, 12)
    np.testing.assert_allclose(f[9, 11], f[9, 13], rtol=0, atol=1e-9)
    np.testing.assert_allclose(f[8, 12], f[10, 12], rtol=0, atol=1e-9)


@pytest.mark.parametrize("sc,match", [
    (scenario(Indenter("box"), 0.5), "simulates indenters"),
    (Scenario(Indenter("flat"), np.arange(2) / 1e3, force_n=1.0), "needs depth_mm"),
    (scenario(Indenter("sphere", size_mm=5.0), 2.5), "depth_mm must be < the pad thickness 2.5"),
    (scenario(Indenter("sphere", size_mm=5.0, stiffness_n_per_mm=10.0), 0.5), "rigid indenters"),
    (Scenario(Indenter("flat"), [0.0], depth_mm=0.5, extra={"colour": 1}), "unknown Scenario.extra"),
])
def test_frames_bad_scenario(src, sc, match):
    with pytest.raises(InputError, match=match):
        src.frames(sc)


def test_frames_not_a_scenario(src):
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        src.frames("pipe")
