"""The thread8 array: config, contact mechanics, film response, ADC frames."""

import math

import numpy as np
import pytest

from optitact.errors import InputError
from optitact.taxels.grasp import OBJECTS
from optitact.taxels.sources import Indenter, Scenario, TactileSource, make_source
from optitact.taxels.thread8 import Thread8, Thread8Config

KP = 100.0  # kPa/mm, default pad: 0.5 MPa / 5 mm


def scenario(indenter, depth, *, rate=100.0, **pose):
    depth = np.asarray(depth, dtype=float)
    return Scenario(indenter, np.arange(depth.size) / rate, depth_mm=depth, **pose)


@pytest.fixture
def src(thread8_source):
    return thread8_source


def test_registered_source_and_layout():
    s = make_source("thread8")
    assert isinstance(s, TactileSource) and isinstance(s, Thread8) and s.name == "thread8"
    lay = s.layout
    assert lay.shape == (8, 8) and lay.pitch_mm == (2.5, 2.5) and lay.units == "DN" and lay.rate_hz == 100.0
    assert s.pad_area_mm2 == 400.0 and s.full_scale == 255
    assert make_source("thread8", unit_seed=4).config.unit_seed == 4
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("thread8", colour=1)
    with pytest.raises(TypeError, match="Thread8Config"):
        Thread8(object())


@pytest.mark.parametrize("field, value, exc, match", [
    ("pitch_mm", 0.0, InputError, "pitch_mm must be finite and > 0"),
    ("r_pressed_ohm", 2e6, InputError, "r_pressed_ohm must be < r_free_ohm"),
    ("hysteresis", 0.5, InputError, r"hysteresis must be in \[0, 0.5\)"),
    ("creep_fraction", 1.0, InputError, r"creep_fraction must be in \[0, 1\)"),
    ("grid_mm", 0.3, InputError, "pitch_mm / grid_mm must be a positive integer"),
    ("adc_bits", 8.0, TypeError, "adc_bits must be an integer"),
    ("adc_bits", 20, InputError, "adc_bits must be <= 16"),
    ("noise_v", -0.1, InputError, "noise_v must be finite and >= 0"),
])
def test_config_validation(field, value, exc, match):
    with pytest.raises(exc, match=match):
        Thread8Config(**{field: value})


def test_resistance_law(src):
    c = src.config
    p = np.linspace(0.0, 2000.0, 4001)
    r = src.resistance_ohm(p)
    assert np.all(np.diff(r) < 0)                                                     # falls monotonically
    np.testing.assert_allclose(src.resistance_ohm(0.0), c.r_free_ohm, rtol=1e-3, atol=0)
    np.testing.assert_allclose(src.resistance_ohm(c.threshold_kpa - 5 * c.transition_kpa), c.r_free_ohm,
                               rtol=0.05, atol=0)
    assert 100e3 < float(src.resistance_ohm(c.threshold_kpa)) < 1e6                   # smooth onset
    np.testing.assert_allclose(src.resistance_ohm(1e9), c.r_pressed_ohm, rtol=1e-3, atol=0)
    # well above threshold: R - R_pressed = 1 / (1/(R_free - R_pressed) + e/rho), e = p - threshold
    e = 130.0
    want = c.r_pressed_ohm + 1.0 / (1.0 / (c.r_free_ohm - c.r_pressed_ohm) + e / c.r_coeff_ohm_kpa)
    np.testing.assert_allclose(src.resistance_ohm(c.threshold_kpa + e), want, rtol=1e-9, atol=0)
    with pytest.raises(InputError, match="pressure_kpa must be >= 0"):
        src.resistance_ohm(-1.0)


def test_flat_contact_and_divider_analytic(src):
    c = src.config
    depth = np.array([0.0, 0.2, 0.5, 1.0])
    st = src.contact(scenario(Indenter("flat"), depth))
    np.testing.assert_allclose(st["taxel_kpa"], (KP * depth)[:, None, None] * np.ones((1, 8, 8)),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(st["force_n"], KP * depth * 400.0 * 1e-3, rtol=1e-12, atol=1e-12)
    # loading, below creep: V = V+ R / (R_s(p) + R) with the per-taxel sensitivities
    v = src.voltage(st["taxel_kpa"])
    r_s = src.resistance_ohm(st["taxel_kpa"], sensitivity=src.sensitivity)
    np.testing.assert_allclose(v, c.v_plus * c.r_divider_ohm / (r_s + c.r_divider_ohm), rtol=1e-12, atol=0)
    # soft object in series with the pad: kappa = 1 / (1/kp + 1/ko), ko = k / A_pad
    soft = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=4.0), depth))
    kappa = 1.0 / (1.0 / KP + 400.0 / 4e3)
    np.testing.assert_allclose(soft["taxel_kpa"][:, 3, 3], kappa * depth, rtol=1e-12, atol=1e-12)


def test_sphere_force_matches_winkler_cap_volume(src):
    radius, d = 10.0, 1.0
    st = src.contact(scenario(Indenter("sphere", size_mm=radius), [d]))
    cap = math.pi * d * d * (3 * radius - d) / 3                                      # mm³
    np.testing.assert_allclose(st["force_n"][0], KP * cap * 1e-3, rtol=0.01, atol=0)
    np.testing.assert_allclose(st["peak_kpa"][0], KP * d, rtol=0.01, atol=0)
    tax = st["taxel_kpa"][0]
    np.testing.assert_allclose(tax, tax[::-1, ::-1], rtol=0, atol=1e-9)             # centred: symmetric
    assert tax[0, 0] == 0.0 and tax[3, 3] > 0


@pytest.mark.parametrize("obj", [o for o in OBJECTS if o.indenter.shape != "flat"], ids=lambda o: o.name)
def test_moving_pose_path_matches_static_path(src, obj):
    depth = np.r_[np.linspace(0, 3, 40), np.linspace(3, 0.5, 40)]
    a = src.contact(scenario(obj.indenter, depth, x_mm=1.0, y_mm=-0.7, angle_rad=0.4))
    b = src.contact(scenario(obj.indenter, depth, x_mm=np.r_[1.0 + 1e-12, np.ones(79)], y_mm=-0.7,
                             angle_rad=0.4))
    np.testing.assert_allclose(a["taxel_kpa"], b["taxel_kpa"], rtol=0, atol=1e-9)


def test_plastic_object_unloads_faster(src):
    k, phi, dmax = 4.0, 0.5, 3.0
    depth = np.r_[np.linspace(0, dmax, 31), np.linspace(dmax, 0, 31)[1:]]
    elastic = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=k), depth))["taxel_kpa"][:, 4, 4]
    plastic = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=k, plasticity=phi),
                                   depth))["taxel_kpa"][:, 4, 4]
    kappa = 1.0 / (1.0 / KP + 400.0 / (1e3 * k))
    set_ = phi * kappa / (1e3 * k / 400.0) * dmax                                      # residual set, mm
    unload = kappa * dmax * np.clip((depth - set_) / (dmax - set_), 0, 1)
    want = np.r_[kappa * depth[:31], unload[31:]]
    np.testing.assert_allclose(plastic, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(elastic, kappa * depth, rtol=0, atol=1e-9)
    assert plastic[-1] == 0 and np.all(plastic[31:] <= elastic[31:] + 1e-12)


def test_force_mode_round_trip(src):
    ind = Indenter("sphere", size_mm=15.0, stiffness_n_per_mm=8.0, plasticity=0.6)
    depth = np.r_[np.linspace(0, 2, 8), np.linspace(2, 0.8, 6)]
    st = src.contact(scenario(ind, depth, x_mm=0.5))
    sc = Scenario(ind, np.arange(depth.size) / 100.0, x_mm=0.5, force_n=st["force_n"])
    back = src.contact(sc)
    loaded = st["force_n"] > 0
    np.testing.assert_allclose(back["depth_mm"][loaded], depth[loaded], rtol=1e-7, atol=0)
    np.testing.assert_allclose(back["taxel_kpa"], st["taxel_kpa"], rtol=0, atol=1e-6)


def test_hysteresis_and_creep_analytic(src):
    c = src.config
    p = np.r_[np.linspace(0, 100, 11), np.linspace(100, 0, 11)[1:]]
    eff = src.effective_kpa(p[:, None, None] * np.ones((1, 8, 8)))[:, 0, 0]
    np.testing.assert_allclose(eff[:11], p[:11], rtol=0, atol=1e-12)                # loading branch
    np.testing.assert_allclose(eff[15], 50 + c.hysteresis * 100, rtol=0, atol=1e-9)  # q = 0.5: widest gap
    # hold at 400 kPa: first-order drift to p (1 + f (1 - p_c / p)) with tau
    hold = np.full((200, 8, 8), 400.0)
    eff = src.effective_kpa(hold)[:, 0, 0]
    c_inf = c.creep_fraction * (1 - c.creep_kpa / 400.0)
    n = int(round(c.creep_tau_s * c.rate_hz))
    np.testing.assert_allclose(eff[n - 1], 400 * (1 + c_inf * (1 - math.exp(-1))), rtol=1e-12, atol=0)
    assert np.all(np.diff(eff) > 0) and eff[-1] < 400 * (1 + c_inf)
    below = src.effective_kpa(np.full((50, 8, 8), 150.0))
    np.testing.assert_allclose(below, 150.0, rtol=0, atol=1e-12)                    # no creep below p_c


def test_frames_dtype_baseline_and_seed(src):
    sc = scenario(OBJECTS[1].indenter, np.r_[np.zeros(100), np.linspace(0, 2, 50)], x_mm=0.3)
    a = src.frames(sc, seed=5)
    assert a.dtype == np.uint8 and a.shape == (150, 8, 8)
    np.testing.assert_array_equal(a, src.frames(sc, seed=5))
    assert not np.array_equal(a, src.frames(sc, seed=6))
    free = 255 * 10e3 / (1e6 + 10e3)                                                   # R / (R_free + R)
    assert abs(a[:100].mean() - free) < 0.1
    assert a[-1].max() > 150


@pytest.mark.parametrize("bad, exc, match", [
    (lambda: Scenario(Indenter("wire"), [0.0], depth_mm=0.0), InputError, "simulates indenters"),
    (lambda: Scenario(Indenter("flat"), [0.0], depth_mm=0.0, extra={"spin": 1}), InputError, "extra"),
    (lambda: "scenario", TypeError, "scenario must be a Scenario"),
    (lambda: Scenario(Indenter("sphere", size_mm=1.0), [0.0], x_mm=50.0, force_n=1.0), InputError,
     "cannot be reached"),
])
def test_frames_bad_input(src, bad, exc, match):
    with pytest.raises(exc, match=match):
        src.frames(bad(), seed=0)
