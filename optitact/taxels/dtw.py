"""Dynamic time warping distances and k-NN cross validation on precomputed distances.

:func:`dtw_distance` and :func:`dtw_matrix` use the C core of
``dtaidistance`` (the ``taxels`` extra) without pruning, so every distance is
the exact dynamic programme; :func:`cv_folds`, :func:`knn_cv` and
:func:`classify` (scikit-learn) give the recognition rate of k-NN on such
matrices with stratified k-fold cross validation and a t-interval over the
folds.
"""

from __future__ import annotations

import math

import numpy as np

from optitact._optional import require
from optitact._validate import finite, integer, real_array, seed_value
from optitact.errors import InputError, ShapeError

__all__ = ["dtw_distance", "dtw_matrix", "cv_folds", "knn_cv", "classify"]


def _series_list(series, name: str = "series") -> list[np.ndarray]:
    if isinstance(series, np.ndarray):
        series = list(series)
    if not isinstance(series, (list, tuple)):
        raise TypeError(f"{name} must be a sequence of 1-D or 2-D arrays, got {type(series).__name__}")
    out = []
    for i, s in enumerate(series):
        a = finite(real_array(s, f"{name}[{i}]"), f"{name}[{i}]")
        if a.ndim not in (1, 2) or a.shape[0] < 1 or (a.ndim == 2 and a.shape[1] < 1):
            raise ShapeError(f"{name}[{i}] must be a non-empty (T,) or (T, d) array, got shape {a.shape}")
        out.append(np.ascontiguousarray(a, dtype=np.float64))
    if len(out) >= 2:
        dims = {1 if a.ndim == 1 else a.shape[1] for a in out}
        kinds = {a.ndim for a in out}
        if len(dims) > 1 or len(kinds) > 1:
            raise ShapeError(f"{name} must all be (T,) or all (T, d) with the same d, got shapes "
                             f"{sorted({a.shape[1:] for a in out})}")
    return out


def _window(window) -> int | None:
    """``window`` as dtaidistance's argument: its band keeps ``|j - i| < window`` (ours: ``<=``)."""
    return None if window is None else integer(window, "window", minimum=0) + 1


def dtw_distance(a, b, *, window: int | None = None) -> float:
    r"""Dynamic time warping distance between two series (``dtaidistance``, C core).

    Parameters
    ----------
    a, b : (T,) or (T, d) array
        Series of any lengths; 2-D for several features per sample (same ``d``).
    window : int, optional
        Sakoe–Chiba band half width :math:`w` in samples (>= 0); None for
        unconstrained warping. With :math:`n = ` ``len(a)`` and
        :math:`m = ` ``len(b)``, a path may visit the cells :math:`(i, j)` with
        :math:`-w - \max(0, n - m) \le j - i \le w + \max(0, m - n)`: the
        band of half width :math:`w` around the diagonals through
        :math:`(0, 0)` and :math:`(n-1, m-1)` (``window=0`` on equal lengths:
        the diagonal alone, the Euclidean distance).

    Returns
    -------
    float
        Every path is costed exactly (no pruning or early abandoning).

    Notes
    -----
    :math:`D(a, b) = \sqrt{\min_\pi \sum_{(i, j) \in \pi} \lVert a_i - b_j \rVert^2}`
    over monotone, continuous warping paths :math:`\pi` from :math:`(0, 0)`
    to :math:`(n-1, m-1)`, i.e. the square root of the dynamic programme
    :math:`C_{ij} = \lVert a_i - b_j\rVert^2 + \min(C_{i-1,j}, C_{i,j-1}, C_{i-1,j-1})`.

    Examples
    --------
    >>> dtw_distance([0.0, 1.0, 2.0], [0.0, 0.0, 1.0, 2.0])
    0.0
    >>> dtw_distance([0.0, 0.0], [3.0, 4.0])
    5.0
    """
    dtw = require("dtaidistance.dtw", purpose="DTW distances")
    dtw_ndim = require("dtaidistance.dtw_ndim", purpose="DTW distances")

    sa, sb = _series_list([a, b], "series (a, b)")
    w = _window(window)
    # dtaidistance's distance_fast prunes by default (use_pruning=True), which returned inf for short
    # series such as ([0], [0.1, 1]); the exact programme needs it off.
    if sa.ndim == 1:
        return float(dtw.distance_fast(sa, sb, window=w, use_pruning=False))
    return float(dtw_ndim.distance_fast(sa, sb, window=w, use_pruning=False))


def dtw_matrix(series, *, window: int | None = None) -> np.ndarray:
    """Symmetric matrix of DTW distances between all pairs of ``series`` (``dtaidistance``, C, OpenMP).

    Parameters
    ----------
    series : sequence of (T_i,) or (T_i, d) arrays
        At least two series; lengths may differ, ``d`` may not.
    window : int, optional
        See :func:`dtw_distance`.

    Returns
    -------
    (n, n) float64
        Zero diagonal; entry ``(i, j)`` equals ``dtw_distance(series[i], series[j])``.
    """
    from scipy.spatial.distance import squareform

    dtw = require("dtaidistance.dtw", purpose="DTW distances")
    dtw_ndim = require("dtaidistance.dtw_ndim", purpose="DTW distances")

    s = _series_list(series)
    if len(s) < 2:
        raise InputError(f"series must hold at least two series, got {len(s)}")
    w = _window(window)
    if s[0].ndim == 1:
        cond = dtw.distance_matrix_fast(s, compact=True, window=w, use_pruning=False)
    else:
        cond = dtw_ndim.distance_matrix_fast(s, compact=True, window=w)   # never prunes
    return squareform(np.asarray(cond, dtype=np.float64), checks=False)


def _labels(labels, n: int | None = None) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.dtype.kind not in "iu":
        raise TypeError(f"labels must be an integer array, got dtype {arr.dtype}")
    if arr.ndim != 1 or (n is not None and arr.size != n):
        want = f"({n},)" if n is not None else "(n,)"
        raise ShapeError(f"labels must have shape {want}, got {arr.shape}")
    return arr


def cv_folds(labels, *, n_folds: int = 10, seed: int | None = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stratified ``n_folds``-fold split with equal class shares per fold (shuffled with ``seed``).

    Parameters
    ----------
    labels : (n,) int array
    n_folds : int
        Number of folds (>= 2); every class needs at least ``n_folds`` samples.
    seed : int, optional
        Seed of the shuffle.

    Returns
    -------
    list of (train_index, test_index)
        Test folds are disjoint and cover every sample once; each holds
        ``count(class) // n_folds`` or one more of every class.

    Raises
    ------
    InputError
        If a class has fewer than ``n_folds`` samples.
    """
    StratifiedKFold = require("sklearn.model_selection", purpose="cross validation").StratifiedKFold

    y = _labels(labels)
    n_folds = integer(n_folds, "n_folds", minimum=2)
    seed = seed_value(seed)
    classes, counts = np.unique(y, return_counts=True)
    if classes.size < 2:
        raise InputError(f"labels must hold at least two classes, got {classes.size}")
    if counts.min() < n_folds:
        raise InputError(f"every class needs at least n_folds = {n_folds} samples, got "
                         f"{int(counts.min())} for class {int(classes[np.argmin(counts)])}")
    skf = StratifiedKFold(n_splits=n_folds, shuffle=True, random_state=seed)
    return [(tr, te) for tr, te in skf.split(np.zeros((y.size, 1)), y)]


def _t_interval(rates: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    from scipy.stats import t as student_t

    m = float(rates.mean())
    if rates.size < 2:
        return m, m, m
    half = float(student_t.ppf(0.5 + level / 2, rates.size - 1) * rates.std(ddof=1) / math.sqrt(rates.size))
    return m, max(0.0, m - half), min(1.0, m + half)


def knn_cv(distance, labels, *, ks=(1, 3, 5), n_folds: int = 10, seed: int | None = 0) -> dict[str, np.ndarray]:
    r"""k-NN recognition rate on a precomputed distance matrix, stratified k-fold cross validation.

    Parameters
    ----------
    distance : (n, n) array
        Symmetric, finite, non-negative distances between all samples.
    labels : (n,) int array
    ks : sequence of int
        Neighbour counts.
    n_folds : int
        Folds of :func:`cv_folds`.
    seed : int, optional
        Seed of the fold shuffle.

    Returns
    -------
    dict
        Table-shaped, one row per k: ``k``, ``mean`` (mean recognition rate over
        the folds), ``ci_low``, ``ci_high`` (95 % interval), ``std`` (over folds)
        and ``fold_rates`` ((n_k, n_folds)).

    Notes
    -----
    Each test sample gets the majority label of its ``k`` nearest training
    samples (scikit-learn ``KNeighborsClassifier(metric="precomputed")``, uniform
    weights; a tie goes to the smallest label). The interval is
    :math:`\bar r \pm t_{0.975,\,F-1}\, s/\sqrt F` over the :math:`F` fold rates
    (Student t), clipped to [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> x = np.r_[np.zeros(4), np.ones(4)]
    >>> d = np.abs(x[:, None] - x[None, :])
    >>> knn_cv(d, np.repeat([0, 1], 4), ks=(1,), n_folds=2)["mean"]
    array([1.])
    """
    KNeighborsClassifier = require("sklearn.neighbors", purpose="k-NN classification").KNeighborsClassifier

    d = finite(real_array(distance, "distance"), "distance")
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise ShapeError(f"distance must be a square (n, n) matrix, got shape {d.shape}")
    if np.any(d < 0):
        raise InputError(f"distance must be >= 0, got minimum {d.min()}")
    if not np.allclose(d, d.T, rtol=1e-9, atol=1e-12):
        raise InputError("distance must be symmetric")
    y = _labels(labels, d.shape[0])
    ks = [integer(k, "k", minimum=1) for k in np.atleast_1d(np.asarray(ks, dtype=object))]
    if not ks:
        raise InputError("ks must hold at least one k, got none")
    folds = cv_folds(y, n_folds=n_folds, seed=seed)
    min_train = min(tr.size for tr, _ in folds)
    if max(ks) > min_train:
        raise InputError(f"k must be <= the smallest training fold ({min_train} samples), got {max(ks)}")
    rates = np.empty((len(ks), len(folds)))
    for j, (tr, te) in enumerate(folds):
        for i, k in enumerate(ks):
            clf = KNeighborsClassifier(n_neighbors=k, metric="precomputed").fit(d[np.ix_(tr, tr)], y[tr])
            rates[i, j] = float(np.mean(clf.predict(d[np.ix_(te, tr)]) == y[te]))
    stats = np.array([_t_interval(r) for r in rates])
    return {"k": np.array(ks), "mean": stats[:, 0], "ci_low": stats[:, 1], "ci_high": stats[:, 2],
            "std": rates.std(axis=1, ddof=1), "fold_rates": rates}


def classify(distances: dict[str, np.ndarray], labels, *, ks=(1, 3, 5), n_folds: int = 10,
             seed: int | None = 0) -> dict[str, list]:
    """The study's table: :func:`knn_cv` for every metric of :func:`palpation_distances`.

    Parameters
    ----------
    distances : dict
        ``"{feature}/{sensor}"`` → (n, n) distance matrix.
    labels : (n,) int array
    ks, n_folds, seed
        See :func:`knn_cv`; every metric uses the same folds.

    Returns
    -------
    dict
        Table-shaped (lists, JSON-serialisable), one row per (metric, k):
        ``metric``, ``feature``, ``sensor``, ``k``, ``mean``, ``ci_low``,
        ``ci_high``, ``std``, ``fold_rates``.
    """
    if not isinstance(distances, dict) or not distances:
        raise TypeError("distances must be a non-empty dict of metric name -> (n, n) matrix")
    table: dict[str, list] = {key: [] for key in ("metric", "feature", "sensor", "k", "mean", "ci_low",
                                                  "ci_high", "std", "fold_rates")}
    for metric, d in distances.items():
        feature, _, sensor = str(metric).partition("/")
        res = knn_cv(d, labels, ks=ks, n_folds=n_folds, seed=seed)
        for i, k in enumerate(res["k"]):
            table["metric"].append(str(metric))
            table["feature"].append(feature)
            table["sensor"].append(sensor)
            table["k"].append(int(k))
            for key in ("mean", "ci_low", "ci_high", "std"):
                table[key].append(float(res[key][i]))
            table["fold_rates"].append([float(v) for v in res["fold_rates"][i]])
    return table

