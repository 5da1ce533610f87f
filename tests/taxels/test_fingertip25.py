"""The 25-unit fingertip as a source: unit map, config, resistance law, transduction, dynamics."""

import dataclasses
import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.studies.fingertip import step_response
from optitact.taxels.fingertip25 import (
    PLANE_AXIS,
    UNIT_PLANE,
    UNIT_SIDE,
    Fingertip25,
    Fingertip25Config,
    force_from_resistance,
    resistance_from_force,
    resistance_law,
)
from optitact.taxels.sources import Indenter, Scenario, TactileSource, make_source

PUBLISHED_ANGLES = (0.0, 77.25, 62.09, 46.47, 9.03)
PUBLISHED_UNITS = (8, 4, 2, 2, 3)
AXIS = {"x": 0, "y": 1, "z": 2}


@pytest.fixture
def quiet(fingertip_quiet):
    """Noise- and scatter-free sensor without crosstalk (session fixture)."""
    return fingertip_quiet


def scenario(force, direction=(0.0, 0.0, 1.0), n=5, rate=100.0):
    return Scenario(Indenter("point"), t_s=np.arange(n) / rate, force_n=force, extra={"direction": direction})


def test_registered_source_and_layout():
    src = make_source("fingertip25")
    assert isinstance(src, TactileSource) and src.name == "fingertip25"
    lay = src.layout
    assert lay.shape == (5, 5) and lay.units == "kOhm" and lay.rate_hz == 100.0 and lay.n_cells == 25
    assert lay.positions_mm.shape == (5, 5, 3) and lay.normals.shape == (5, 5, 3)
    assert make_source("fingertip25", noise_n=0.0).config.noise_n == 0.0
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("fingertip25", colour=1)


def test_unit_map_counts_and_angles():
    src = Fingertip25()
    for k, n in enumerate(PUBLISHED_UNITS, start=1):
        assert np.sum((UNIT_PLANE == k) & (UNIT_SIDE > 0)) == n
    assert UNIT_PLANE.size == 25 and np.sum(UNIT_SIDE < 0) == 6       # planes 2 and 3 mirrored on -x
    normals = src.layout.normals
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, rtol=0, atol=1e-12)
    for (r, c), k in np.ndenumerate(UNIT_PLANE):
        axis = np.zeros(3)
        axis[AXIS[PLANE_AXIS[k - 1]]] = UNIT_SIDE[r, c]
        angle = math.degrees(math.acos(float(normals[r, c] @ axis)))
        assert angle == pytest.approx(PUBLISHED_ANGLES[k - 1], abs=1e-9)
    assert np.all(normals[..., 2] > 0)                                 # every unit faces the pad side
    p = src.layout.positions_mm.reshape(-1, 3)
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(25) * 1e3
    assert dist.min() >= src.config.unit_diameter_mm                   # Ø 2.5 mm units do not overlap
    table = src.unit_table()
    assert len({len(v) for v in table.values()}) == 1 and table["unit"].tolist() == list(range(25))
    np.testing.assert_array_equal(table["plane"], UNIT_PLANE.ravel())


@pytest.mark.parametrize("field, value, error, match", [
    ("pitch_mm", 2.0, InputError, "pitch_mm must be >= unit_diameter_mm"),
    ("plane_angles_deg", (5.0, 77.25, 62.09, 46.47, 9.03), InputError, "must be 0 for plane 1"),
    ("plane_angles_deg", (0.0, 90.0, 62.09, 46.47, 9.03), InputError, r"in \(0, 90\)"),
    ("plane_angles_deg", (0.0, 77.25), ShapeError, "5 finite angles"),
    ("plane_units", (8, 4, 2, 2, 9), InputError, "plane_units must be"),
    ("plane_units", (8, 4, 2, 2, 3.0), TypeError, "plane_units must be integers"),
    ("force_low_n", 6.0, InputError, "force_low_n must be < force_high_n"),
    ("r_high_kohm", 50.0, InputError, "resistance falls"),
    ("resolution_n", 0.5, InputError, "resolution_n must be <= force_low_n"),
    ("tau_load_s", 0.0, InputError, "tau_load_s must be finite and > 0"),
    ("repeatability", 0.5, InputError, r"repeatability must be in \[0, 0.3\)"),
    ("crosstalk", 1.5, InputError, r"crosstalk must be in \[0, 1\]"),
    ("noise_n", "0.1", TypeError, "noise_n must be a real number"),
])
def test_config_validation(field, value, error, match):
    with pytest.raises(error, match=match):
        Fingertip25Config(**{field: value})
    with pytest.raises(TypeError, match="config must be a Fingertip25Config"):
        Fingertip25({"noise_n": 0.0})


def test_config_replace_keeps_validation():
    with pytest.raises(InputError, match="crosstalk"):
        dataclasses.replace(Fingertip25Config(), crosstalk=-0.1)


def test_resistance_law_through_published_points_and_round_trip():
    a, b = resistance_law()
    assert b == pytest.approx(math.log(38.5 / 1.2) / math.log(25.0), rel=1e-12)
    np.testing.assert_allclose(resistance_from_force([0.2, 5.0]), [38.5, 1.2], rtol=1e-12, atol=0)
    f = np.linspace(0.2, 5.0, 49)
    r = resistance_from_force(f)
    assert np.all(np.diff(r) < 0)                                          # falls with force
    np.testing.assert_allclose(force_from_resistance(r), f, rtol=1e-12, atol=0)
    assert force_from_resistance([1000.0, 5000.0]).tolist() == [0.0, 0.0]  # open units
    with pytest.raises(InputError, match="force_n must be > 0"):
        resistance_from_force([0.0, 1.0])
    with pytest.raises(InputError, match="resistance_kohm must be > 0"):
        force_from_resistance(-1.0)
    with pytest.raises(TypeError, match="real numeric array"):
        force_from_resistance("1.2")


def test_threshold_quantisation_and_saturation(quiet):
    t = np.arange(3) / 100.0
    f = np.zeros((3, 5, 5))
    f[:, 0, 0], f[:, 0, 1], f[:, 0, 2], f[:, 0, 3], f[:, 0, 4] = 0.19, 0.21, 1.27, 6.0, 2.0
    r = quiet.transduce(f, t, seed=0)[-1]
    assert r[0, 0] == 1000.0 and r[1, 1] == 1000.0                     # below threshold / unloaded: open
    np.testing.assert_allclose(r[0, 1:], resistance_from_force([0.2, 1.2, 5.0, 2.0]), rtol=1e-12, atol=0)


def test_first_order_dynamics_and_response_times():
    src = Fingertip25()
    resp = step_response(src, unit_force_n=4.0, rate_hz=1000.0)
    # quantisation to 0.2 N moves the crossings by at most a few ms from tau and tau*ln(10)
    assert resp["t63_load_ms"] == pytest.approx(80.0, abs=5.0)
    assert resp["t63_unload_ms"] == pytest.approx(160.0, abs=8.0)
    assert resp["t90_load_ms"] == pytest.approx(80.0 * math.log(10), abs=25.0)
    assert resp["t90_unload_ms"] < 160.0 * math.log(10) + 10
    # an independent loop on one unit, no quantisation: y_n = y_{n-1} + (1 - exp(-dt/tau)) (x_n - y_{n-1})
    cfg = Fingertip25Config(noise_n=0.0, repeatability=0.0, resolution_n=1e-6, force_high_n=50.0,
                            r_low_kohm=38.5, r_high_kohm=0.1)
    s = Fingertip25(cfg)
    t = np.cumsum(np.r_[0.0, np.full(30, 0.01), np.full(30, 0.013)])
    x = np.r_[np.zeros(11), np.full(25, 4.0), np.full(25, 1.0)]
    f = np.zeros((t.size, 5, 5))
    f[:, 2, 2] = x
    got = force_from_resistance(s.transduce(f, t, seed=0), config=cfg)[:, 2, 2]
    y = np.empty_like(x)
    y[0] = x[0]
    for n in range(1, x.size):
        tau = 0.08 if x[n] > y[n - 1] else 0.16
        y[n] = y[n - 1] + (1 - math.exp(-(t[n] - t[n - 1]) / tau)) * (x[n] - y[n - 1])
    expect = np.where(y >= 0.2, np.round(y / 1e-6) * 1e-6, 0.0)
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-5)


def test_frames_deterministic_by_seed_and_in_range():
    src = Fingertip25()
    sc = scenario(np.linspace(0.0, 20.0, 8), direction=(0.3, 0.4, 1.0), n=8)
    f1, f2, f3 = src.frames(sc, seed=3), src.frames(sc, seed=3), src.frames(sc, seed=4)
    assert f1.shape == (8, 5, 5) and f1.dtype == np.float64
    np.testing.assert_array_equal(f1, f2)
    assert not np.array_equal(f1, f3)
    on = f1 < 1000.0
    assert on.any() and np.all((f1[on] >= 1.2 - 1e-12) & (f1[on] <= 38.5 + 1e-12))


def test_scenario_errors():
    src = Fingertip25()
    with pytest.raises(InputError, match="needs a force-driven scenario"):
        src.frames(Scenario(Indenter("sphere"), t_s=[0.0, 0.01], depth_mm=0.1))
    with pytest.raises(InputError, match=r"unknown Scenario.extra key\(s\) \['tilt'\]"):
        src.frames(Scenario(Indenter("point"), t_s=[0.0], force_n=1.0, extra={"tilt": 1}))
    with pytest.raises(InputError, match="direction must be non-zero"):
        src.frames(scenario(1.0, direction=(0.0, 0.0, 0.0)))
    with pytest.raises(ShapeError, match=r"direction must have shape \(3,\) or \(5, 3\)"):
        src.frames(scenario(1.0, direction=np.ones((4, 3))))
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        src.frames({"force_n": 1.0})
    with pytest.raises(ShapeError, match=r"unit_force_n must have shape \(T, 5, 5\)"):
        src.transduce(np.ones((5, 5)), [0.0])
    with pytest.raises(InputError, match="unit forces must be >= 0"):
        src.transduce(-np.ones((2, 5, 5)), [0.0, 0.1])
    with pytest.raises(InputError, match="t_s must be strictly increasing"):
        src.transduce(np.ones((2, 5, 5)), [0.1, 0.1])
    with pytest.raises(ShapeError, match=r"force_xyz must have shape \(..., 3\)"):
        src.unit_forces([1.0, 2.0])
