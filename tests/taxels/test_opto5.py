"""The 5×5 optoelectronic pad as a source: config, sensor instance, finger distance, contact, hysteresis."""

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.opto5 import Opto5, Opto5Config, grasp_scenario
from optitact.taxels.sources import Indenter, Scenario, TactileSource, make_source
from optitact.taxels.wire import hold_response


def grasp(src, indenter, depth, *, seed=0, **pose):
    sc = grasp_scenario(src, indenter, depth, n_base=50, n_ramp=10, n_hold=10, **pose)
    return hold_response(src, sc, n_base=50, n_hold=10, seed=seed)


def test_registered_source_and_layout():
    src = make_source("opto5")
    assert isinstance(src, TactileSource) and src.name == "opto5"
    lay = src.layout
    assert lay.shape == (5, 5) and lay.pitch_mm == (3.55, 3.55) and lay.units == "V" and lay.rate_hz == 500
    assert make_source("opto5", unit_seed=3).config.unit_seed == 3
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("opto5", colour=1)


@pytest.mark.parametrize("field, value, match", [
    ("pitch_mm", 0.0, "pitch_mm must be finite and > 0"),
    ("hysteresis", 0.6, r"hysteresis must be in \[0, 0.5\)"),
    ("flex", 1.0, r"flex must be in \[0, 1\)"),
    ("shape_range", (2.0, 1.0), "low <= high"),
    ("offset_range_v", (0.1, 5.0), "v_ref"),
    ("pad_mm", 10.0, "must cover the taxel grid"),
])
def test_config_validation(field, value, match):
    with pytest.raises(InputError, match=match):
        Opto5Config(**{field: value})
    with pytest.raises(TypeError, match="adc_bits must be an integer"):
        Opto5Config(adc_bits=12.0)


def test_sensor_instance_fixed_by_unit_seed_and_frames_by_seed():
    a, b, c = Opto5(Opto5Config(unit_seed=1)), Opto5(Opto5Config(unit_seed=1)), Opto5(Opto5Config(unit_seed=2))
    np.testing.assert_array_equal(a.gain, b.gain)
    assert not np.allclose(a.gain, c.gain)
    sc = Scenario(Indenter("wire", 1.0), t_s=np.arange(5) / 500, depth_mm=[0, 0.2, 0.5, 0.5, 0.1],
                  angle_rad=0.3)
    f1, f2, f3 = a.frames(sc, seed=4), a.frames(sc, seed=4), a.frames(sc, seed=5)
    assert f1.shape == (5, 5, 5)
    np.testing.assert_array_equal(f1, f2)
    assert not np.array_equal(f1, f3)
    np.testing.assert_allclose(f1 / a.lsb_v, np.rint(f1 / a.lsb_v), rtol=0, atol=1e-9)   # on the 12-bit grid


def test_finger_distance_mapping():
    src = Opto5()
    np.testing.assert_allclose(src.gap_mm([0, 255]), [8.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(src.depth_from_finger_distance(218, 2.5), 0.5 * (2.5 - 8.0 * 37 / 255),
                               rtol=0, atol=1e-12)
    assert src.depth_from_finger_distance(100, 2.5) == 0          # gap 4.9 mm: not touching
    assert src.finger_distance_at_contact(2.5) == pytest.approx(255 * (1 - 2.5 / 8))
    with pytest.raises(InputError, match=r"finger_distance must be in \[0, 255\]"):
        src.gap_mm(256)
    with pytest.raises(InputError, match="thickness_mm must be >= 0"):
        src.depth_from_finger_distance(200, -1.0)


def test_force_scenario_solves_the_depth():
    src = Opto5()
    t = np.arange(3) / 500
    depth = Scenario(Indenter("wire", 1.25), t_s=t, depth_mm=[0.0, 0.4, 1.1], y_mm=1.0, angle_rad=0.2)
    state = src.contact(depth)
    assert state["force_n"][0] == 0 and np.all(np.diff(state["force_n"]) > 0)
    force = Scenario(Indenter("wire", 1.25), t_s=t, force_n=state["force_n"], y_mm=1.0, angle_rad=0.2)
    np.testing.assert_allclose(src.contact(force)["depth_mm"], [0.0, 0.4, 1.1], rtol=1e-7, atol=1e-9)
    # flat: total force = E/t * mean compression * area, with compression falling linearly to the tip
    flat = src.contact(Scenario(Indenter("flat"), t_s=[0.0], depth_mm=1.0))
    c = src.config
    expected = c.pad_modulus_mpa / c.pad_thickness_mm * 1.0 * (1 - c.flex / 2) * c.pad_mm ** 2
    np.testing.assert_allclose(flat["force_n"], [expected], rtol=1e-9)


def test_hysteresis_band_and_repeatability():
    src = Opto5(Opto5Config(noise_v=0.0))
    up = np.linspace(0, 4, 41)
    f = np.concatenate([up, up[::-1][1:]])[:, None, None] * np.ones((1, 5, 5))
    dv = src.response_v(f)
    loading, unloading = dv[:41], dv[40:][::-1]
    peak = dv[40]
    gap = unloading - loading
    assert np.all(gap >= -1e-15) and np.all(gap <= 0.05 * peak + 1e-15)
    np.testing.assert_allclose(gap[20], 0.05 * peak, rtol=1e-12)      # widest at half the peak force
    np.testing.assert_allclose(dv[-1], 0.0, atol=1e-15)                 # back to the offset when unloaded
    # repeatability: per-trial gain scatter ~3 % (1 sigma) of each taxel's response
    hold = np.stack([grasp(src, Indenter("flat"), 1.5, seed=s) for s in range(30)])
    rel = hold.std(axis=0, ddof=1) / hold.mean(axis=0)
    assert 0.025 < np.sqrt(np.mean(rel ** 2)) < 0.036


def test_source_errors():
    src = Opto5()
    t = np.arange(2) / 500
    with pytest.raises(InputError, match="simulates indenters"):
        src.frames(Scenario(Indenter("point"), t_s=t, depth_mm=0.1))
    with pytest.raises(InputError, match="unknown Scenario.extra key"):
        src.frames(Scenario(Indenter("wire"), t_s=t, depth_mm=0.1, extra={"twist": 1}))
    with pytest.raises(ShapeError, match="curvature_per_mm"):
        src.frames(Scenario(Indenter("wire"), t_s=t, depth_mm=0.1, extra={"curvature_per_mm": [0.1, 0.2, 0.3]}))
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        src.frames("wire")
    with pytest.raises(TypeError, match="Opto5Config"):
        Opto5({"pitch_mm": 3.55})
