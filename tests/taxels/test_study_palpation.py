"""The palpation study (optitact.studies.palpation): dataset, distances, recognition table, figure."""

import json

import numpy as np
import pytest

from optitact import studies
from optitact.errors import InputError
from optitact.studies import palpation
from optitact.studies.palpation import palpation_dataset, palpation_distances
from optitact.taxels.dtw import classify, dtw_matrix
from optitact.taxels.grasp import OBJECTS, frame_features


@pytest.fixture
def result(palpation_result):
    return palpation_result


def test_dataset_seed_and_table():
    objs = (OBJECTS[0], OBJECTS[3])
    a = palpation_dataset(n_per_object=2, seed=1, objects=objs)
    b = palpation_dataset(n_per_object=2, seed=1, objects=objs)
    assert len(a) == 4 and a.names == ("rigid block", "wooden bar")
    np.testing.assert_array_equal(a.labels, [0, 0, 1, 1])
    for fa, fb in zip(a.left + a.right, b.left + b.right, strict=True):
        np.testing.assert_array_equal(fa, fb)
    table = a.as_dict()
    assert len({len(v) for v in table.values()}) == 1 and list(table["object"][:1]) == ["rigid block"]
    f = a.features("left")[0]
    ff = frame_features(a.left[0])
    np.testing.assert_allclose(f, np.stack([ff["mu"], ff["sigma"]], axis=1), rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="unique"):
        palpation_dataset(n_per_object=1, objects=(OBJECTS[0], OBJECTS[0]))


def test_experiment_table_far_above_chance(result, tmp_path):
    back = json.loads(json.dumps(result))
    table = back["table"]
    assert len(table["metric"]) == 9 * 3 and len({len(v) for v in table.values()}) == 1
    assert set(table["metric"]) == {f"{f}/{s}" for f in palpation.FEATURES for s in palpation.SENSORS}
    assert back["chance"] == 0.25 and back["n_folds"] == 5
    mean = np.array(table["mean"])
    assert np.all(np.array(table["ci_low"]) <= mean + 1e-12)
    assert np.all(mean <= np.array(table["ci_high"]) + 1e-12)
    assert mean.mean() >= 0.85 and mean.min() >= 0.6                                  # chance: 0.25
    best = [v for m, k, v in zip(table["metric"], table["k"], mean, strict=True)
            if (m, k) == ("mu+sigma/both", 1)]
    assert len(best) == 1 and best[0] >= 0.9
    path = tmp_path / "palpation.png"
    studies.save_plot("palpation", back, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the figure marks each published range over k, and that range +- 5 points, on its metric's bars
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure()
    palpation.draw(fig, back)
    bars = fig.axes[-1]
    names = [t.get_text() for t in bars.get_xticklabels()]
    bands = {names[round(r.get_x() + r.get_width() / 2)]: (r.get_y(), r.get_y() + r.get_height())
             for r in bars.patches if isinstance(r, Rectangle) and r.get_alpha() == 0.08}
    pub = back["published"]["recognition"]
    assert set(bands) == set(pub)
    for metric, (lo, hi) in pub.items():
        assert bands[metric] == pytest.approx((100 * lo - 5, 100 * hi + 5), abs=1e-9)
    with pytest.raises(InputError, match="result is not a complete 'palpation' study result"):
        studies.save_plot("palpation", {"table": {}}, path)


def test_distances_normalised_and_classify_shape():
    data = palpation_dataset(n_per_object=2, seed=2, objects=(OBJECTS[1], OBJECTS[3]))
    dist = palpation_distances(data)
    assert list(dist) == [f"{f}/{s}" for f in palpation.FEATURES for s in palpation.SENSORS]
    for d in dist.values():
        assert d.shape == (4, 4) and np.isclose(d.max(), 1.0) and np.all(np.diag(d) == 0)
        np.testing.assert_allclose(d, d.T, rtol=0, atol=0)
    mu = [f[:, 0] for f in data.features("left")]
    raw = dtw_matrix(mu)
    np.testing.assert_allclose(dist["mu/left"], raw / raw.max(), rtol=1e-12, atol=0)
    table = classify({"mu/left": dist["mu/left"]}, data.labels, ks=(1,), n_folds=2, seed=0)
    assert table["metric"] == ["mu/left"] and table["k"] == [1] and len(table["fold_rates"][0]) == 2


def test_published_figures_next_to_ours(result):
    pub = result["published"]
    assert "reference" in pub and pub["ks"] == [1, 3, 5] and pub["n_folds"] == 10
    assert pub["recognition"]["mu/left"] == [0.707, 0.781]
    assert pub["recognition"]["mu+sigma/both"] == [0.9, 0.92]


def test_quick_figures_with_every_effect(result):
    """Quick study (4 objects x 5 grasps, 5 folds, seed 0) with the effects of issue 35, recorded figures."""
    rec = result["recognition"]
    expected = {"mu/left": [0.85, 0.95], "mu/right": [0.80, 0.90], "mu/both": [0.80, 0.85],
                "sigma/left": [0.70, 0.85], "mu+sigma/left": [1.0, 1.0], "mu+sigma/both": [1.0, 1.0]}
    for metric, (lo, hi) in expected.items():               # one grasp of 20 is 0.05: allow one
        assert abs(rec[metric][0] - lo) <= 0.051 and abs(rec[metric][1] - hi) <= 0.051, metric
    assert result["ablation"] is None and result["ablation_size"] is None            # full runs only
    left, right = result["jaws"]
    assert left["mount_tilt_rad"] > right["mount_tilt_rad"] > 0


def test_ablation_switches_each_effect_off():
    sensors, proto = palpation.without("drift")
    assert all(s.config.drift_gain_spread == 0 for s in sensors) and proto == palpation.GraspProtocol()
    sensors, proto = palpation.without("object pose")
    assert proto.offset_mm == 0 and proto.angle_range_rad == 0 and sensors[0].config.drift_gain_spread > 0
    with pytest.raises(InputError, match="effect"):
        palpation.without("gravity")
    abl = palpation.palpation_ablation(objects=(OBJECTS[1], OBJECTS[9]), n_per_object=4, n_folds=4, seed=0,
                                       effects=("drift",))
    assert list(abl) == ["all on", "no drift"]
    for rates in abl.values():
        assert set(rates) == {f"{f}/{s}" for f in ("mu", "mu+sigma") for s in palpation.SENSORS}
        assert all(len(v) == 3 and all(0.0 <= x <= 1.0 for x in v) for v in rates.values())
    # a rigid cylinder and a soft ball are told apart whatever the drift
    assert min(min(v) for v in abl["no drift"].values()) >= 0.8
    rows = palpation.key_figures({"published": palpation.PUBLISHED, "recognition": {}, "ks": [1, 3, 5],
                                  "n_folds": 10, "ablation": abl})
    assert rows[-1][0].startswith("ablation no drift") and len(rows[-1][1]) == 6 and rows[-1][2] is None
