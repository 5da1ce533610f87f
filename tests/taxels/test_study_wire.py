"""The wire study: grasp sets, the three diameter classifiers, normalisation matters, its figure."""

import json

import numpy as np
import pytest

from optitact import studies
from optitact.errors import InputError
from optitact.studies.wire import classify_wires, wire_dataset

DIAMETERS = [1.5, 2.0, 2.5, 3.0, 3.5, 4.0]


@pytest.fixture
def result(wire_result):
    """``studies.run("wire", seed=0, size="quick")`` (session fixture)."""
    return wire_result


def test_dataset_and_classifiers_are_deterministic_by_seed():
    a = wire_dataset(n_per_class=10, seed=3)
    b = wire_dataset(n_per_class=10, seed=3)
    np.testing.assert_array_equal(a.features(), b.features())
    assert a.features().shape == (70, 26) and sorted(set(a.diameter_mm)) == [0.0, *DIAMETERS]
    assert not np.array_equal(a.features(), wire_dataset(n_per_class=10, seed=4).features())
    assert classify_wires(a, seed=1) == classify_wires(b, seed=1)
    with pytest.raises(InputError, match="finger_range"):
        wire_dataset(n_per_class=2, finger_range=(200, 300))
    with pytest.raises(InputError, match="n_per_class must be >= 2"):
        wire_dataset(n_per_class=1)


def test_experiment_classifiers_beat_chance(result):
    cls = result["classification"]
    assert cls["classes_mm"] == [0.0, *DIAMETERS] and cls["chance"] == pytest.approx(1 / 7)
    for key in ("lookup_table", "svm", "mlp"):
        assert cls[key]["accuracy"] > 4 * cls["chance"]              # > 0.57
        cm = np.asarray(cls[key]["confusion"])
        assert cm.shape == (7, 7) and cm.sum() == cls["n_test"] == 140
        assert cls[key]["accuracy"] == pytest.approx(np.trace(cm) / cm.sum())
    assert cls["svm"]["accuracy"] > 0.85 and cls["mlp"]["accuracy"] > 0.85
    json.dumps(result)


def test_experiment_normalisation_matters(result, tmp_path):
    flat = result["normalisation"]["flat"]
    assert flat["raw_cv"] > 0.3 and flat["normalised_cv"] < 0.1
    edge = result["normalisation"]["edge_wire"]
    assert edge["normalised_mean_rms_mm"] < edge["raw_mean_rms_mm"]
    assert edge["ideal_mean_rms_mm"] < 0.3
    path = tmp_path / "opto5.png"
    studies.save_plot("wire", result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="not a complete 'wire' study result"):
        studies.save_plot("wire", {}, path)
