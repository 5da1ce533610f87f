"""The fingertip study: decoupling accuracy, repeatability, object recognition, hardness cues, figure."""

import json
import math

import numpy as np
import pytest

from optitact import studies
from optitact.errors import InputError, ShapeError
from optitact.studies.fingertip import repeated_loadings
from optitact.studies.fingertip_objects import (
    OBJECTS,
    GraspObject,
    ObjectDataset,
    _solve_depth,
    grasp,
    hidden_units,
    object_dataset,
    recognise_objects,
)
from optitact.taxels.decoupling import repeatability_error
from optitact.taxels.fingertip25 import Fingertip25, Fingertip25Config

PUBLISHED_ANGLES = (0.0, 77.25, 62.09, 46.47, 9.03)


@pytest.fixture
def result(fingertip_result):
    """``studies.run("fingertip", seed=0, size="quick")`` (session fixture)."""
    return fingertip_result


def test_decoupling_study_in_experiment(result):
    dec = result["decoupling"]
    pub, cal = dec["published"], dec["calibrated"]
    assert pub["rms_n"][0] < 0.15 and pub["rms_n"][2] < 0.4             # x and z: quantisation-limited
    assert pub["bias_n"][1] > 0.1                                        # y: crosstalk bias
    assert cal["rms_n"][1] < 0.5 * pub["rms_n"][1]                       # calibration removes it


def test_repeatability_of_simulated_loadings(result):
    rep = result["repeatability"]
    assert len(rep["per_unit_pct"]) == 8
    assert 0.3 < rep["mean_pct"] < 3.0                                   # near the published 1.5 %
    quiet = Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0))
    reads = repeated_loadings(quiet, n_cycles=3, seed=0, hold_s=0.8)
    assert reads.shape == (3, 5, 8)
    assert repeatability_error(reads[:, :, 0], 5.0) == 0.0               # no scatter: perfectly repeatable


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
    d = _solve_depth(c, w, target)
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


def test_experiment_json_and_plot(result, tmp_path):
    text = json.dumps(result)
    assert json.loads(text)["config"]["plane_angles_deg"] == list(PUBLISHED_ANGLES)
    assert result["ranges"]["low_n"][1] == pytest.approx(0.2 * 4 * math.cos(math.radians(77.25)), rel=1e-12)
    path = tmp_path / "fingertip.png"
    studies.save_plot("fingertip", result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="not a complete 'fingertip' study result"):
        studies.save_plot("fingertip", {"law": {}}, tmp_path / "bad.png")
    with pytest.raises(InputError, match="a study needs an integer seed"):
        studies.run("fingertip", seed=None)
