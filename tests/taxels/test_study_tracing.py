"""The tracing study (optitact.studies.tracing): dataset, table behaviour, figure."""

import json
import math

import numpy as np
import pytest

from optitact import studies
from optitact.errors import InputError
from optitact.studies import tracing
from optitact.studies.tracing import tracing_dataset


@pytest.fixture
def src(piezo16_source):
    return piezo16_source


@pytest.fixture
def result(tracing_result):
    return tracing_result


def test_tracing_dataset_deterministic(src):
    a = tracing_dataset(src, [20.0], 2, 2, seed=1)
    b = tracing_dataset(src, [20.0], 2, 2, seed=1)
    assert set(a) == {"diameter_mm", "offset_mm", "width", "mean_abs_diff", "combined"}
    assert a["combined"].shape == (2, 32) and np.all((a["offset_mm"] >= 0) & (a["offset_mm"] < 2.0))
    for k in a:
        assert np.array_equal(a[k], b[k])
    assert not np.array_equal(a["offset_mm"], tracing_dataset(src, [20.0], 2, 2, seed=2)["offset_mm"])


def test_experiment_table_behaviour(result):
    back = json.loads(json.dumps(result))
    assert back["table"] == result["table"]
    t = {k: np.asarray(v) for k, v in result["table"].items() if k != "n_traces"}
    diam = result["protocol"]["diameters_mm"]
    assert len(t["n_steps"]) == 4 * len(diam)

    def cell(key, n, d):
        return float(t[key][(t["n_steps"] == n) & (t["diameter_mm"] == d)][0])

    for d in diam:
        w1 = cell("width_mean", 1, d)
        for n in (2, 4, 8):
            assert 0.7 * n * w1 <= cell("width_mean", n, d) <= 1.3 * n * w1     # about N-fold
        mads = [cell("mad_mean", n, d) for n in (1, 2, 4, 8)]
        assert all(b < a for a, b in zip(mads, mads[1:], strict=False))           # falls with N
    w8 = [cell("width_mean", 8, d) for d in diam]
    assert all(b > a for a, b in zip(w8, w8[1:], strict=False))                  # grows with diameter at N=8
    assert cell("mad_mean", 8, diam[-1]) < cell("mad_mean", 8, diam[0])         # falls with diameter
    cls = result["classification"]
    assert cls["n_steps"] == [1, 2, 4, 8]
    assert all(0 <= a <= 1 for a in cls["accuracy"])
    res = [math.inf if r is None else r for r in cls["resolution_mm"]]
    assert res[-1] <= res[0]


def test_plot_experiment(result, tmp_path):
    path = tmp_path / "tracing.png"
    studies.save_plot("tracing", result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the published neighbour-difference ranges are bands on the difference panel
    from matplotlib.figure import Figure

    fig = Figure()
    tracing.draw(fig, result)
    spans = sorted((p.get_y(), p.get_y() + p.get_height()) for p in fig.axes[1].patches)
    published = sorted(tuple(v) for v in result["published"]["mad_range_v"].values())
    np.testing.assert_allclose(spans, published, rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="result is not a complete 'tracing' study result"):
        studies.save_plot("tracing", {}, tmp_path / "x.png")


def test_published_figures_next_to_ours(result):
    pub = result["published"]
    assert "reference" in pub and pub["mad_range_v"]["1"] == [0.41, 0.52]
    assert pub["mad_range_v"]["8"] == [0.079, 0.103]
    for n in ("1", "2", "4", "8"):
        lo, hi = result["mad_range_v"][n]
        assert 0 < lo <= hi


def test_quick_study_figures(result):
    # the quick study (seed 0, ⌀10/25/40 mm, 6 traces): figures pinned with explicit tolerances
    t1, t2 = result["table1"], result["table2"]
    assert result["ablation"] is None and result["finger"] == {"depth_spread_mm": 0.02, "step_jitter_mm": 0.02}
    assert result["config"]["spread_depth_mm"] == 2.5 and result["config"]["rubber_leak_mm"] == 0.5
    want_w = {"2": 6.5, "4": 13.2, "8": 26.8}                               # ⌀10 mm
    for n, w in want_w.items():
        assert t1[n]["10"] == pytest.approx(w, abs=1.0)
    for d in ("10", "25", "40"):
        assert 0.55 <= t2["1"][d] <= 0.80                                   # published 0.41-0.52
        assert 0.085 <= t2["8"][d] <= 0.125                                 # published 0.079-0.103


def test_ablation_switches_each_effect():
    from optitact.studies.tracing import EFFECTS, ablation

    ab = ablation(0, diameters=(10.0,), n_traces=2)
    assert set(ab) == {"all on", *(f"no {k}" for k in EFFECTS)}
    for tabs in ab.values():
        assert set(tabs["table1"]) == {"1", "2", "4", "8"} and set(tabs["table1"]["8"]) == {"10"}
    on = ab["all on"]
    # narrower spreading (Boussinesq at 2 mm, no leak) raises the N = 1 neighbour difference
    for off in ("no spreading through the rubber", "no rubber lateral leak"):
        assert ab[off]["table2"]["1"]["10"] > on["table2"]["1"]["10"]
    # the finger's depth spread roughens the finely sampled distribution: N = 8 difference falls without it
    assert ab["no pressing-depth spread"]["table2"]["8"]["10"] < on["table2"]["8"]["10"]
