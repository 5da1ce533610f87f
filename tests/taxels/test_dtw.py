"""DTW distances against a direct dynamic programme; k-NN cross validation."""

import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.dtw import cv_folds, dtw_distance, dtw_matrix, knn_cv


def dtw_reference(a, b):
    """Direct O(nm) dynamic programme: sqrt of the least summed squared distance along a warping path."""
    return dtw_band_reference(a, b)


def test_dtw_matches_dynamic_programming_reference():
    rng = np.random.default_rng(7)
    for d in (1, 2):
        series = [rng.normal(size=(n, d)).squeeze(axis=1) if d == 1 else rng.normal(size=(n, d))
                  for n in (5, 9, 12, 7, 1)]
        mat = dtw_matrix(series)
        ref = np.array([[dtw_reference(a, b) for b in series] for a in series])
        np.testing.assert_allclose(mat, ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(dtw_distance(series[1], series[2]), ref[1, 2], rtol=1e-10, atol=0)
    # warping absorbs repeated samples; unequal values add up in quadrature
    assert dtw_distance([0, 1, 1, 1, 2], [0, 1, 2]) == 0.0
    np.testing.assert_allclose(dtw_distance(np.zeros((2, 2)), np.full((3, 2), 1.0)), math.sqrt(6), rtol=1e-12)


@pytest.mark.parametrize("bad, exc, match", [
    ([[0.0, np.nan], [1.0]], InputError, "must be finite"),
    ([np.zeros(3), np.zeros((3, 2))], ShapeError, "same d"),
    ([np.zeros((2, 2, 2)), np.zeros(2)], ShapeError, "non-empty"),
    ([np.zeros(3)], InputError, "at least two"),
    ("abc", TypeError, "sequence"),
])
def test_dtw_bad_input(bad, exc, match):
    with pytest.raises(exc, match=match):
        dtw_matrix(bad)


def test_cv_folds_disjoint_stratified_and_seeded():
    labels = np.repeat(np.arange(4), 10)
    folds = cv_folds(labels, n_folds=10, seed=3)
    tests = [te for _, te in folds]
    assert len(folds) == 10
    np.testing.assert_array_equal(np.sort(np.concatenate(tests)), np.arange(40))   # disjoint, cover all
    for tr, te in folds:
        assert np.intersect1d(tr, te).size == 0 and tr.size + te.size == 40
        np.testing.assert_array_equal(np.bincount(labels[te], minlength=4), [1, 1, 1, 1])  # equal shares
    again = cv_folds(labels, n_folds=10, seed=3)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(folds, again, strict=True))
    other = cv_folds(labels, n_folds=10, seed=4)
    assert not all(np.array_equal(a[1], b[1]) for a, b in zip(folds, other, strict=True))
    with pytest.raises(InputError, match="at least n_folds = 10 samples"):
        cv_folds(np.repeat([0, 1], 5), n_folds=10)
    with pytest.raises(TypeError, match="integer array"):
        cv_folds(np.array([0.0, 1.0]))


def test_knn_cv_rates_and_t_interval():
    from scipy.stats import t as student_t

    rng = np.random.default_rng(1)
    labels = np.repeat(np.arange(3), 10)
    x = labels + rng.normal(scale=0.45, size=labels.size)
    d = np.abs(x[:, None] - x[None, :])
    res = knn_cv(d, labels, ks=(1, 3, 5), n_folds=10, seed=0)
    assert list(res["k"]) == [1, 3, 5] and res["fold_rates"].shape == (3, 10)
    r = res["fold_rates"][0]
    half = student_t.ppf(0.975, 9) * r.std(ddof=1) / math.sqrt(10)
    np.testing.assert_allclose(res["mean"][0], r.mean(), rtol=0, atol=1e-15)
    np.testing.assert_allclose([res["ci_low"][0], res["ci_high"][0]],
                               [max(0, r.mean() - half), min(1, r.mean() + half)], rtol=0, atol=1e-12)
    assert np.all(res["mean"] > 0.6)
    # 1-NN by hand on the first fold
    tr, te = cv_folds(labels, n_folds=10, seed=0)[0]
    pred = labels[tr][np.argmin(d[np.ix_(te, tr)], axis=1)]
    np.testing.assert_allclose(r[0], np.mean(pred == labels[te]), rtol=0, atol=1e-15)
    with pytest.raises(ShapeError, match="square"):
        knn_cv(np.zeros((3, 4)), [0, 1, 2])
    with pytest.raises(InputError, match="symmetric"):
        knn_cv(np.triu(np.ones((20, 20))), np.repeat([0, 1], 10), n_folds=2)
    with pytest.raises(ShapeError, match=r"labels must have shape \(30,\)"):
        knn_cv(d, labels[:-1])
    with pytest.raises(InputError, match="smallest training fold"):
        knn_cv(d, labels, ks=(28,), n_folds=10)


def dtw_band_reference(a, b, window=None):
    """Direct O(nm) programme over the cells -w - max(0, n - m) <= j - i <= w + max(0, m - n) (all for None)."""
    a = np.asarray(a, dtype=float).reshape(len(a), -1)
    b = np.asarray(b, dtype=float).reshape(len(b), -1)
    n, m = len(a), len(b)
    c = np.full((n + 1, m + 1), np.inf)
    c[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            if window is not None and not -window - max(0, n - m) <= j - i <= window + max(0, m - n):
                continue
            cost = float(np.sum((a[i - 1] - b[j - 1]) ** 2))
            c[i, j] = cost + min(c[i - 1, j], c[i, j - 1], c[i - 1, j - 1])
    return math.sqrt(c[n, m])


def test_dtw_short_series_are_not_pruned():
    # dtaidistance's distance_fast prunes by default and returned inf here
    assert dtw_distance([0.0], [0.1, 1.0]) == pytest.approx(math.sqrt(1.01), rel=1e-12, abs=0)
    rng = np.random.default_rng(11)
    for _ in range(500):
        n, m = rng.integers(1, 7, size=2)
        a, b = rng.normal(size=n), rng.normal(size=m)
        got = dtw_distance(a, b)
        assert math.isfinite(got)
        np.testing.assert_allclose(got, dtw_band_reference(a, b), rtol=1e-10, atol=1e-12)
    walks = [np.cumsum(rng.normal(size=k)) for k in rng.integers(1, 25, size=20)]
    ref = np.array([[dtw_band_reference(a, b) for b in walks] for a in walks])
    np.testing.assert_allclose(dtw_matrix(walks), ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("d", [1, 2])
def test_dtw_window_is_the_documented_band(d):
    rng = np.random.default_rng(5 + d)
    for window in (0, 1, 2, 3):
        for _ in range(60):
            n, m = rng.integers(1, 9, size=2)
            shape_a, shape_b = ((n,), (m,)) if d == 1 else ((n, d), (m, d))
            a, b = rng.normal(size=shape_a), rng.normal(size=shape_b)
            want = dtw_band_reference(a, b, window)
            np.testing.assert_allclose(dtw_distance(a, b, window=window), want, rtol=1e-10, atol=1e-12)
        series = [rng.normal(size=(k,) if d == 1 else (k, d)) for k in (1, 4, 6, 9)]
        ref = np.array([[dtw_band_reference(a, b, window) for b in series] for a in series])
        np.testing.assert_allclose(dtw_matrix(series, window=window), ref, rtol=1e-10, atol=1e-12)
    # window 0 on equal lengths: the diagonal alone, the Euclidean distance
    a, b = rng.normal(size=7), rng.normal(size=7)
    assert dtw_distance(a, b, window=0) == pytest.approx(float(np.linalg.norm(a - b)), rel=1e-12)
    with pytest.raises(InputError, match="window must be >= 0"):
        dtw_distance(a, b, window=-1)
