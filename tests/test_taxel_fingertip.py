import dataclasses
import doctest
import json
import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.sources import Indenter, Scenario, TactileSource, make_source
from optitact.taxels import fingertip
from optitact.taxels.fingertip import (OBJECTS, PLANE_AXIS, UNIT_PLANE, UNIT_SIDE, DecouplingMatrix,
                                       Fingertip25, Fingertip25Config, GraspObject, ObjectDataset, decouple,
                                       detection_ranges, force_from_resistance, grasp, hidden_units,
                                       object_dataset, plane_resultants, recognise_objects, repeatability_error,
                                       resistance_from_force, resistance_law)

PUBLISHED_ANGLES = (0.0, 77.25, 62.09, 46.47, 9.03)
PUBLISHED_UNITS = (8, 4, 2, 2, 3)
AXIS = {"x": 0, "y": 1, "z": 2}


@pytest.fixture(scope="module")
def result():
    return fingertip.experiment(seed=0, full=False, progress=False)


@pytest.fixture(scope="module")
def quiet():
    """Noise- and scatter-free sensor without crosstalk: only threshold, quantisation and saturation remain."""
    return Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0, crosstalk=0.0))


def scenario(force, direction=(0.0, 0.0, 1.0), n=5, rate=100.0):
    return Scenario(Indenter("point"), t_s=np.arange(n) / rate, force_n=force, extra={"direction": direction})


def test_docstring_examples():
    assert doctest.testmod(fingertip, optionflags=doctest.ELLIPSIS).failed == 0


# ---- source and geometry -------------------------------------------------------------------------
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


# ---- resistance law ------------------------------------------------------------------------------
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
    resp = fingertip.step_response(src, unit_force_n=4.0, rate_hz=1000.0)
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


# ---- decoupling ----------------------------------------------------------------------------------
def test_detection_ranges_from_the_formula():
    r = detection_ranges()
    n = np.array(PUBLISHED_UNITS, dtype=float)
    factor = n * np.cos(np.radians(PUBLISHED_ANGLES))                    # independent: n_k cos(theta_k)
    np.testing.assert_allclose(r["low_n"], 0.2 * factor, rtol=1e-12, atol=0)
    np.testing.assert_allclose(r["high_n"], 5.0 * factor, rtol=1e-12, atol=0)
    assert r["axis"].tolist() == list(PLANE_AXIS)
    assert (r["low_n"][0], r["high_n"][0]) == pytest.approx((1.6, 40.0), abs=1e-12)   # F1 = 8 F_s
    assert r["low_n"][1] == pytest.approx(0.17, abs=0.01) and r["high_n"][1] == pytest.approx(4.41, abs=0.005)
    wide = detection_ranges(config=Fingertip25Config(force_high_n=10.0, r_high_kohm=0.5))
    np.testing.assert_allclose(wide["high_n"], 10.0 * factor, rtol=1e-12, atol=0)
    ax = fingertip.axis_ranges()
    assert ax["x"][1] == pytest.approx(r["high_n"][1] + r["high_n"][2], rel=1e-12)


def test_plane_resultants_match_published_formula():
    fs = 1.7
    units = np.where(UNIT_SIDE > 0, fs, 0.0)                              # every + side unit reads F_s
    res = plane_resultants(units)
    cos = np.cos(np.radians(PUBLISHED_ANGLES))
    expect = [8 * fs, 4 * fs * cos[1], 2 * fs * cos[2], 2 * fs * cos[3], 3 * fs * cos[4]]
    np.testing.assert_allclose([res[f"F{k}"] for k in range(1, 6)], expect, rtol=1e-12, atol=0)
    mirrored = plane_resultants(np.where(UNIT_SIDE < 0, fs, 0.0))
    assert mirrored["F2"] == pytest.approx(-4 * fs * cos[1], rel=1e-12)


def test_decouple_inverts_the_design_model(quiet):
    rng = np.random.default_rng(0)
    forces = rng.uniform([-8.0, 0.0, 2.0], [8.0, 20.0, 38.0], size=(50, 3))
    np.testing.assert_allclose(decouple(quiet.unit_forces(forces)), forces, rtol=0, atol=1e-12)
    # through the whole chain (kOhm frames, threshold, 0.2 N quantisation): each unit is off by <= 0.1 N
    f = np.array([3.0, 6.0, 17.0])
    frames = quiet.frames(scenario(np.linalg.norm(f), direction=f, n=3), seed=0)
    est = decouple(frames[-1], units="kOhm")
    bound = 0.1 * np.array([2 * (4 + 2), 2 + 3, 8])                     # units per axis x 0.1 N
    assert np.all(np.abs(est - f) <= bound)
    assert decouple(np.zeros((2, 3, 5, 5), dtype=np.float32)).dtype == np.float32
    with pytest.raises(ShapeError, match=r"values must have shape \(..., 5, 5\)"):
        decouple(np.zeros((5, 4)))
    with pytest.raises(InputError, match="units must be one of"):
        decouple(np.zeros((5, 5)), units="ohm")
    with pytest.raises(InputError, match="unit forces must be >= 0"):
        decouple(-np.ones((5, 5)))


def test_crosstalk_cancels_on_x_and_is_removed_by_calibration():
    src = Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0, crosstalk=0.1))
    pure_z = decouple(src.unit_forces([0.0, 0.0, 20.0]))
    assert pure_z[0] == pytest.approx(0.0, abs=1e-12) and pure_z[2] == pytest.approx(20.0, abs=1e-12)
    assert pure_z[1] > 0.1                                               # y planes feel the normal force
    rng = np.random.default_rng(1)
    forces = rng.uniform([-6.0, 0.0, 2.0], [6.0, 15.0, 30.0], size=(80, 3))
    units = src.unit_forces(forces)
    m = DecouplingMatrix.fit(units[:60], forces[:60])
    err_cal = np.abs(m.apply(units[60:]) - forces[60:]).max()
    err_pub = np.abs(decouple(units[60:]) - forces[60:]).max()
    assert err_cal < 1e-8 < err_pub                                      # the model is linear in the domain
    with pytest.raises(ShapeError, match="at least 26 loads"):
        DecouplingMatrix.fit(units[:10], forces[:10])
    with pytest.raises(ShapeError, match=r"matrix must have shape \(3, 25\)"):
        DecouplingMatrix(np.zeros((3, 24)), np.zeros(3))


def test_decoupling_study_in_experiment(result):
    dec = result["decoupling"]
    pub, cal = dec["published"], dec["calibrated"]
    assert pub["rms_n"][0] < 0.15 and pub["rms_n"][2] < 0.4             # x and z: quantisation-limited
    assert pub["bias_n"][1] > 0.1                                        # y: crosstalk bias
    assert cal["rms_n"][1] < 0.5 * pub["rms_n"][1]                       # calibration removes it


# ---- repeatability -------------------------------------------------------------------------------
def test_repeatability_error_on_known_data():
    # s = 1 at the first point, 0 at the second: 3 * 1 / 100 * 100 % = 3 %
    assert repeatability_error([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]], 100.0) == pytest.approx(3.0, abs=1e-12)
    x = np.random.default_rng(0).normal(10.0, 0.2, size=(12, 4))
    expect = 3 * x.std(axis=0, ddof=1).max() / 50.0 * 100
    assert repeatability_error(x, 50.0) == pytest.approx(expect, rel=1e-12)
    assert repeatability_error(x[:, 0], 50.0, z=2.0) == pytest.approx(2 * x[:, 0].std(ddof=1) * 2, rel=1e-12)
    with pytest.raises(ShapeError, match="n >= 2 repetitions"):
        repeatability_error([[1.0, 2.0]], 10.0)
    with pytest.raises(InputError, match="full_scale must be finite and > 0"):
        repeatability_error([1.0, 2.0], 0.0)
    with pytest.raises(InputError, match="samples must be finite"):
        repeatability_error([1.0, np.nan], 1.0)


def test_repeatability_of_simulated_loadings(result):
    rep = result["repeatability"]
    assert len(rep["per_unit_pct"]) == 8
    assert 0.3 < rep["mean_pct"] < 3.0                                   # near the published 1.5 %
    quiet = Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0))
    reads = fingertip.repeated_loadings(quiet, n_cycles=3, seed=0, hold_s=0.8)
    assert reads.shape == (3, 5, 8)
    assert repeatability_error(reads[:, :, 0], 5.0) == 0.0               # no scatter: perfectly repeatable


# ---- object recognition --------------------------------------------------------------------------
def test_catalogue_and_grasp_objects():
    assert len(OBJECTS) == 9 and len({o.name for o in OBJECTS}) == 9
    names = {o.name for o in OBJECTS}
    assert {"sponge", "ping-pong ball", "paper cup", "egg", "steel cylinder"} <= names
    assert any(o.rigid for o in OBJECTS) and any(not o.rigid for o in OBJECTS)
    with pytest.raises(InputError, match="shape must be one of"):
        GraspObject("cone", "cone", 10.0, 10.0, 1.0, False, 5.0, 3)
    with pytest.raises(InputError, match=r"fingers must be in \[2, 5\]"):
        GraspObject("x", "box", 10.0, 10.0, 1.0, False, 5.0, 6)
    with pytest.raises(InputError, match="stiffness_n_per_mm must be a number > 0"):
        GraspObject("x", "box", 10.0, 10.0, 0.0, False, 5.0, 3)


def test_grasp_features_deterministic_and_physical():
    g1, g2, g3 = grasp("egg", seed=5), grasp("egg", seed=5), grasp("egg", seed=6)
    assert g1.shape == (125,)
    np.testing.assert_array_equal(g1, g2)
    assert not np.array_equal(g1, g3)
    assert np.all(g1 >= 0) and np.all(g1 <= 5.0)
    egg = next(o for o in OBJECTS if o.name == "egg")                    # 3 fingers: ring and little are idle
    assert np.all(grasp(egg, seed=1, jitter=0.0)[75:] == 0.0)
    ball = {"shape": "sphere", "size_mm": 60.0, "length_mm": 60.0, "fragile": False, "grasp_force_n": 10.0,
            "fingers": 4}
    soft = grasp(GraspObject("soft", stiffness_n_per_mm=0.8, **ball), seed=2, force_n=15.0, jitter=0.0)
    hard = grasp(GraspObject("hard", stiffness_n_per_mm=math.inf, **ball), seed=2, force_n=15.0, jitter=0.0)
    assert np.sum(soft >= 0.1) > 2 * np.sum(hard >= 0.1)                 # soft objects wrap onto more units
    assert hard.max() > soft.max()
    assert np.all(grasp("sponge", seed=0, force_n=0.0) == 0.0)
    with pytest.raises(InputError, match="unknown object 'brick'; valid names: sponge"):
        grasp("brick")
    with pytest.raises(TypeError, match="obj must be a GraspObject"):
        grasp(3)


def test_contact_depth_solver_is_exact():
    rng = np.random.default_rng(0)
    c = rng.normal(0.0, 1.0, size=(40, 25))
    w = rng.uniform(0.1, 2.0, size=25)
    target = rng.uniform(0.0, 30.0, size=40)
    d = fingertip._solve_depth(c, w, target)
    got = np.sum(w * np.clip(d[:, None] - c, 0.0, None), axis=1)
    np.testing.assert_allclose(got, target, rtol=0, atol=1e-9)


def test_recognition_beats_chance_deterministically(result):
    rec = result["recognition"]
    assert rec["hidden"] == 13 == hidden_units(125, 9)
    assert rec["n_test"] == round(0.3 * 9 * rec["n_per_object"]) and rec["chance"] == pytest.approx(1 / 9)
    assert rec["accuracy"] >= 4 * rec["chance"]                          # wide margin over 11 %
    cm = np.array(rec["confusion"])
    assert cm.shape == (9, 9) and cm.sum() == rec["n_test"]
    assert np.trace(cm) == round(rec["accuracy"] * rec["n_test"])
    data = object_dataset(n_per_object=5, seed=1)
    again = object_dataset(n_per_object=5, seed=1)
    np.testing.assert_array_equal(data.features, again.features)
    assert recognise_objects(data, seed=2, max_iter=200) == recognise_objects(again, seed=2, max_iter=200)
    table = data.as_dict()
    assert len({len(v) for v in table.values()}) == 1 and len(table) == 5 + 125
    with pytest.raises(InputError, match=r"test_size must be in \(0, 1\)"):
        recognise_objects(data, test_size=1.5)
    with pytest.raises(TypeError, match="dataset must be an ObjectDataset"):
        recognise_objects(data.features)
    with pytest.raises(ShapeError, match="features must be"):
        ObjectDataset(np.zeros((3, 125)), np.zeros(2, dtype=int), ("a",), np.zeros(2))


def test_hardness_cues(result):
    hard = result["hardness"]
    assert len(hard["rigid_mean"]) == len(hard["forces_n"]) == len(hard["elastic_mean"])
    assert hard["elastic_mean"][-1] > 1.5 * hard["rigid_mean"][-1]
    assert hard["elastic_slope_per_n"] > 1.5 * hard["rigid_slope_per_n"] > 0
    assert set(hard["objects"]) == {o.name for o in OBJECTS}


# ---- the study -----------------------------------------------------------------------------------
def test_experiment_json_and_plot(result, tmp_path):
    text = json.dumps(result)
    assert json.loads(text)["config"]["plane_angles_deg"] == list(PUBLISHED_ANGLES)
    assert result["ranges"]["low_n"][1] == pytest.approx(0.2 * 4 * math.cos(math.radians(77.25)), rel=1e-12)
    path = tmp_path / "fingertip.png"
    fingertip.plot_experiment(result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="result must be a dict returned by experiment"):
        fingertip.plot_experiment({"law": {}}, tmp_path / "bad.png")
    with pytest.raises(InputError, match="experiment needs an integer seed"):
        fingertip.experiment(seed=None)


def test_config_replace_keeps_validation():
    with pytest.raises(InputError, match="crosstalk"):
        dataclasses.replace(Fingertip25Config(), crosstalk=-0.1)
