"""The tracing study (optitact.studies.tracing): dataset, table behaviour, figure."""

import json
import math

import numpy as np
import pytest

from optitact import studies
from optitact.errors import InputError
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
    with pytest.raises(InputError, match="result is not a complete 'tracing' study result"):
        studies.save_plot("tracing", {}, tmp_path / "x.png")


def test_published_figures_next_to_ours(result):
    pub = result["published"]
    assert "reference" in pub and pub["mad_range_v"]["1"] == [0.41, 0.52]
    assert pub["mad_range_v"]["8"] == [0.079, 0.103]
    for n in ("1", "2", "4", "8"):
        lo, hi = result["mad_range_v"][n]
        assert 0 < lo <= hi
