"""Active tracing with a taxel pad: traces, the combined distribution, its features, the width classifier.

1. the finger presses a pipe and traces across its axis in ``N`` steps of
   ``W/N`` (:func:`trace`);
2. the outputs of the pipe-radial grid line with the highest output
   (:func:`radial_line`) are interleaved into one combined distribution,
   ``(e₁(0..N−1), e₂(0..N−1), …)`` (:func:`combined_distribution`): ``N``
   times finer sampling than the electrode pitch;
3. features: its width (number of non-zero elements) and the mean absolute
   difference between neighbours (:func:`features`);
4. the diameter from the width with thresholds learned on training traces
   (:class:`WidthClassifier`), and the diameter resolution
   (:func:`pair_separation`, :func:`diameter_resolution`).

The pad is :class:`~optitact.taxels.piezo16.Piezo16` by default (any source
that simulates ``cylinder`` works); the published study is
``optitact.studies.tracing``.

Examples
--------
>>> from optitact.taxels.sources import make_source
>>> frames = trace(make_source("piezo16"), 20.0, 4, seed=0)
>>> frames.shape
(4, 16, 16)
>>> width, mad = features(combined_distribution(frames, 4))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from optitact._validate import finite, integer, positive, real_array, seed_value
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import Indenter, Layout, Scenario, TactileSource
from optitact.taxels.base import freeze_fields
from optitact.taxels.piezo16 import Piezo16

__all__ = ["trace", "finger_errors", "tracing_direction", "radial_line", "combined_distribution", "features",
           "WidthClassifier", "pair_separation", "diameter_resolution"]


def _n_steps(n_steps) -> int:
    return integer(n_steps, "n_steps", minimum=1)


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def tracing_direction(angle_rad: float) -> np.ndarray:
    """The finger's (2,) direction across a pipe with axis ``angle_rad``: the unit normal, main component > 0.

    Examples
    --------
    >>> tracing_direction(0.0).tolist()
    [-0.0, 1.0]
    """
    n = np.array([-math.sin(angle_rad), math.cos(angle_rad)])
    main = int(np.argmax(np.abs(n) + np.array([1e-12, 0.0])))   # x wins a 45° tie
    return n if n[main] > 0 else -n


def finger_errors(rng: np.random.Generator, shape, *, depth_spread_mm: float = 0.0,
                  step_jitter_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    r"""The finger's pressing-depth and position errors at each step: independent Gaussians.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    shape : int or tuple of int
        One draw per step (e.g. ``(n_traces, n_steps)``).
    depth_spread_mm : float
        1-sigma of the pressing depth about its set value, mm (>= 0; 0: exact).
    step_jitter_mm : float
        1-sigma of the finger's position about each nominal step, along the
        tracing direction, mm (>= 0; 0: exact).

    Returns
    -------
    depth_error_mm, position_error_mm : ndarray
        Arrays of ``shape``; zeros (and no draw from ``rng``) where the spread is 0.

    Notes
    -----
    The finger re-presses at every step (it moves, then presses to the set
    depth and samples): the depth and the position errors of consecutive
    steps are independent, each the finger's positioning repeatability.

    Examples
    --------
    >>> import numpy as np
    >>> d, x = finger_errors(np.random.default_rng(0), (2, 3), depth_spread_mm=0.02)
    >>> d.shape, bool(np.all(x == 0))
    ((2, 3), True)
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
    sd = positive(depth_spread_mm, "depth_spread_mm", allow_zero=True)
    sx = positive(step_jitter_mm, "step_jitter_mm", allow_zero=True)
    dz = sd * rng.standard_normal(shape) if sd > 0 else np.zeros(shape)
    dx = sx * rng.standard_normal(shape) if sx > 0 else np.zeros(shape)
    return dz, dx


def trace(source: TactileSource, diameter_mm: float, n_steps: int, *, depth_mm: float = 0.7,
          offset_mm: float = 0.0, angle_rad: float = 0.0, stroke_mm: float = 2.0, samples_per_step: int = 1,
          seed: int | None = None, depth_spread_mm: float = 0.0, step_jitter_mm: float = 0.0) -> np.ndarray:
    r"""Frames of one active trace across a pipe: ``n_steps`` steps of ``stroke_mm / n_steps``.

    Parameters
    ----------
    source : TactileSource
        The pad (:class:`Piezo16`; any source that simulates ``cylinder`` works).
    diameter_mm : float
        Pipe diameter, mm (a rigid ``cylinder`` of radius ``diameter_mm / 2``, longer than the pad).
    n_steps : int
        Number of steps N (>= 1).
    depth_mm : float
        Pressing depth, mm.
    offset_mm : float
        Position of the pipe's axis at the first step, along the tracing
        direction from the grid centre, mm.
    angle_rad : float
        Direction of the pipe's axis, from +x towards +y (layout frame).
    stroke_mm : float
        Tracing distance W covered by the N steps, mm (step ``W/N``).
    samples_per_step : int
        Frames recorded while the finger rests at each step.
    seed : int, optional
        Seed of the readout noise (and of the finger's errors).
    depth_spread_mm, step_jitter_mm : float
        The finger's pressing-depth and position repeatability, 1-sigma per
        step, mm (:func:`finger_errors`; 0, the default: an exact finger).

    Returns
    -------
    ndarray
        (N·samples_per_step, rows, cols) frames in step order.

    Notes
    -----
    The finger moves along the pipe's normal :math:`\hat n` whose larger
    component is positive (``angle_rad = 0``: axis along x, tracing along +y,
    across grid rows; ``angle_rad = π/2``: tracing along +x). At step
    :math:`j` the finger has moved :math:`j W/N`, so the pipe's axis sits at
    :math:`(o - j W/N)\,\hat n` on the pad (:math:`o` = ``offset_mm``), and
    electrode :math:`i` of a radial grid line samples the pipe at
    :math:`x_i + j W/N` in the pipe's frame. Frame times are
    ``arange(T) · sample_period``. With a finger's errors, step :math:`j`
    presses to ``depth_mm`` + :math:`\delta_j` at :math:`o - jW/N + \xi_j`
    (both drawn from ``default_rng((seed, 1))``, so the readout noise of a
    seed is unchanged); depths are clipped at 0.
    """
    if not isinstance(source, TactileSource):
        raise TypeError(f"source must be a TactileSource, got {type(source).__name__}")
    n = _n_steps(n_steps)
    k = integer(samples_per_step, "samples_per_step", minimum=1)
    radius = positive(diameter_mm, "diameter_mm") / 2
    depth = positive(depth_mm, "depth_mm", allow_zero=True)
    stroke = positive(stroke_mm, "stroke_mm", allow_zero=True)
    offset, angle = _number(offset_mm, "offset_mm"), _number(angle_rad, "angle_rad")
    seed = seed_value(seed)
    normal = tracing_direction(angle)
    dz, dx = finger_errors(np.random.default_rng(None if seed is None else (seed, 1)), n,
                           depth_spread_mm=depth_spread_mm, step_jitter_mm=step_jitter_mm)
    pos = np.repeat(offset - np.arange(n) * stroke / n + dx, k)
    depths = np.repeat(np.clip(depth + dz, 0.0, None), k)
    scenario = Scenario(Indenter("cylinder", size_mm=radius), np.arange(n * k) / source.layout.rate_hz,
                        x_mm=pos * normal[0], y_mm=pos * normal[1], angle_rad=angle,
                        depth_mm=depths)
    return source.frames(scenario, seed=seed)


@lru_cache(maxsize=1)
def _default_layout() -> Layout:
    return Piezo16().layout


def _step_frames(frames, n_steps, layout: Layout | None) -> tuple[np.ndarray, Layout]:
    if layout is None:
        layout = _default_layout()
    if not isinstance(layout, Layout):
        raise TypeError(f"layout must be a Layout, got {type(layout).__name__}")
    n = _n_steps(n_steps)
    arr = layout.check_frames(frames)
    if arr.shape[0] % n:
        raise ShapeError(f"the number of frames must be a multiple of n_steps = {n} (samples per step), "
                         f"got {arr.shape[0]} frames")
    k = arr.shape[0] // n
    steps = arr.reshape(n, k, *layout.shape).mean(axis=1)
    return np.where(layout.mask, steps, 0.0), layout


def _line(steps: np.ndarray, layout: Layout, radial_axis: str | None) -> tuple[str, int]:
    if radial_axis is None:
        from optitact.taxels.sources import moments

        m = moments(steps.sum(axis=0), layout)
        radial_axis = "x" if m["sxx"][0] <= m["syy"][0] else "y"
    if radial_axis not in ("x", "y"):
        raise InputError(f"radial_axis must be 'x', 'y' or None (auto), got {radial_axis!r}")
    total = steps.sum(axis=0)
    line = total.sum(axis=1) if radial_axis == "x" else total.sum(axis=0)
    return radial_axis, int(np.argmax(line))


def radial_line(frames, *, layout: Layout | None = None, radial_axis: str | None = None) -> tuple[str, int]:
    """The pipe-radial grid line with the highest output: ``(axis, index)``.

    Parameters
    ----------
    frames : (T, rows, cols) or (rows, cols) array
        A trace (see :func:`combined_distribution`).
    layout : Layout, optional
        The frames' layout (default: the default :class:`Piezo16`'s).
    radial_axis : {"x", "y"}, optional
        ``"x"``: the radial line is a grid row (pipe along y); ``"y"``: a grid
        column (pipe along x). Default: the axis along which the summed output's
        second moment is smaller (across the pipe's stripe).

    Returns
    -------
    (str, int)
        The axis and the index of the row (``"x"``) or column (``"y"``) with
        the largest summed output over all frames (the first on ties).
    """
    steps, lay = _step_frames(frames, 1, layout)
    return _line(steps, lay, radial_axis)


def combined_distribution(frames, n_steps: int, *, layout: Layout | None = None,
                          radial_axis: str | None = None) -> np.ndarray:
    r"""Interleave a trace's radial-line outputs into one N-times finer distribution.

    Parameters
    ----------
    frames : (T, rows, cols) or (rows, cols) array
        The trace in step order; ``T = N·k`` frames: ``k`` consecutive samples
        per step, averaged.
    n_steps : int
        Steps N of the trace.
    layout : Layout, optional
        The frames' layout (default: the default :class:`Piezo16`'s); cells
        outside its mask count as 0.
    radial_axis : {"x", "y"}, optional
        See :func:`radial_line`.

    Returns
    -------
    ndarray
        (N·L,) float64, L the line's length: ``combined[i·N + j] = e_i(j)``,
        the output of element ``i`` of the selected line at step ``j``
        (``frames[j, row, i]`` for ``"x"``, ``frames[j, i, col]`` for ``"y"``).

    Raises
    ------
    TypeError
        For non-numeric frames, a non-integer ``n_steps`` or a wrong ``layout``.
    ShapeError
        If the frames do not fit the layout or their number is not a multiple of ``n_steps``.
    InputError
        For NaN/inf frames, ``n_steps < 1`` or a bad ``radial_axis``.

    Notes
    -----
    The trace moves the finger along +i (see :func:`trace`), so element
    :math:`i` at step :math:`j` sampled the pipe at :math:`x_i + jW/N`: the
    order :math:`(e_1(0..N-1), e_2(0..N-1), \ldots)` is the order along the
    pipe's radius (exactly uniform when W equals the pitch).

    Examples
    --------
    >>> import numpy as np
    >>> from optitact.taxels.sources import Layout
    >>> lay = Layout(shape=(2, 3), pitch_mm=(2.2, 2.2), units="V", rate_hz=1000.0)
    >>> f = np.zeros((2, 2, 3))
    >>> f[0, 1] = [1, 2, 3]
    >>> f[1, 1] = [10, 20, 30]
    >>> combined_distribution(f, 2, layout=lay, radial_axis="x").tolist()
    [1.0, 10.0, 2.0, 20.0, 3.0, 30.0]
    """
    steps, lay = _step_frames(frames, n_steps, layout)
    axis, idx = _line(steps, lay, radial_axis)
    line = steps[:, idx, :] if axis == "x" else steps[:, :, idx]
    return np.ascontiguousarray(line.T).ravel()


def features(combined) -> tuple[int, float]:
    """Width and mean neighbour difference of a combined distribution.

    Parameters
    ----------
    combined : (n,) array
        A combined distribution (:func:`combined_distribution`).

    Returns
    -------
    width : int
        Number of non-zero elements.
    mean_abs_diff : float
        Mean of :math:`|c_{k+1} - c_k|` over the neighbouring pairs inside the
        distribution's span (first to last non-zero element); 0.0 when the
        width is 0 or 1 (no pair).

    Raises
    ------
    TypeError
        For non-numeric input.
    ShapeError
        If ``combined`` is not a non-empty 1-D array.
    InputError
        For NaN or infinite values.

    Examples
    --------
    >>> features([0, 0, 1.0, 3.0, 2.0, 0, 0])
    (3, 1.5)
    """
    c = finite(real_array(combined, "combined"), "combined")
    if c.ndim != 1 or c.size == 0:
        raise ShapeError(f"combined must be a non-empty 1-D array, got shape {c.shape}")
    nz = np.flatnonzero(c)
    if nz.size < 2:
        return int(nz.size), 0.0
    span = c[nz[0]:nz[-1] + 1]
    return int(nz.size), float(np.abs(np.diff(span)).mean())


def _labelled(widths, diameters) -> tuple[np.ndarray, np.ndarray]:
    w = finite(real_array(widths, "widths"), "widths")
    d = finite(real_array(diameters, "diameters"), "diameters")
    if w.ndim != 1 or d.shape != w.shape or w.size == 0:
        raise ShapeError(f"widths and diameters must be non-empty 1-D arrays of one length, got {w.shape} "
                         f"and {d.shape}")
    return w, d


@dataclass(frozen=True, eq=False)
class WidthClassifier:
    r"""Diameter from the width of a combined distribution: thresholds between class mean widths.

    Parameters
    ----------
    diameters : (K,) array
        The classes, ordered by their mean width (ties: by diameter).
    mean_widths : (K,) array
        Mean training width of each class (non-decreasing).
    thresholds : (K−1,) array
        Midpoints between consecutive mean widths.

    Notes
    -----
    A width :math:`w` gets class :math:`k` = the number of thresholds
    :math:`\le w` (a width on a threshold goes to the wider class).

    Examples
    --------
    >>> clf = WidthClassifier.fit([3, 3, 5, 5, 9], [10, 10, 20, 20, 30])
    >>> clf.thresholds.tolist(), clf.predict([3.9, 4.0, 6.9, 7.1]).tolist()
    ([4.0, 7.0], [10.0, 20.0, 20.0, 30.0])
    """

    diameters: np.ndarray
    mean_widths: np.ndarray
    thresholds: np.ndarray

    def __post_init__(self) -> None:
        d = finite(real_array(self.diameters, "diameters"), "diameters")
        m = finite(real_array(self.mean_widths, "mean_widths"), "mean_widths")
        t = finite(real_array(self.thresholds, "thresholds"), "thresholds")
        if d.ndim != 1 or d.size < 2 or np.unique(d).size != d.size:
            raise InputError(f"diameters must hold at least 2 distinct classes, got {d.tolist()}")
        if m.shape != d.shape or t.shape != (d.size - 1,):
            raise ShapeError(f"mean_widths must have shape {d.shape} and thresholds ({d.size - 1},), got "
                             f"{m.shape} and {t.shape}")
        if np.any(np.diff(m) < 0) or np.any(np.diff(t) < 0):
            raise InputError("mean_widths and thresholds must be non-decreasing")
        freeze_fields(self, diameters=d, mean_widths=m, thresholds=t)

    @classmethod
    def fit(cls, widths, diameters) -> WidthClassifier:
        """Learn the thresholds from training traces.

        Parameters
        ----------
        widths : (n,) array
            Widths of the training traces' combined distributions.
        diameters : (n,) array
            Their pipe diameters (the classes), mm.

        Raises
        ------
        ShapeError
            For arrays of different lengths or not 1-D.
        InputError
            For NaN/inf or fewer than two classes.
        """
        w, d = _labelled(widths, diameters)
        classes, idx = np.unique(d, return_inverse=True)
        if classes.size < 2:
            raise InputError(f"training needs at least two diameters, got {classes.tolist()}")
        means = np.bincount(idx, weights=w) / np.bincount(idx)
        order = np.lexsort((classes, means))
        m = means[order]
        return cls(classes[order], m, (m[1:] + m[:-1]) / 2)

    def predict(self, widths) -> np.ndarray:
        """Diameter (mm) of each width."""
        w = finite(real_array(widths, "widths"), "widths")
        return self.diameters[np.searchsorted(self.thresholds, w, side="right")]

    def score(self, widths, diameters) -> float:
        """Fraction of traces whose diameter is predicted exactly."""
        w, d = _labelled(widths, diameters)
        return float(np.mean(self.predict(w) == d))

    def as_dict(self) -> dict[str, list]:
        """Table-shaped: one row per class: ``diameter_mm``, ``mean_width``, ``upper_threshold`` (None last)."""
        return {"diameter_mm": self.diameters.tolist(), "mean_width": self.mean_widths.tolist(),
                "upper_threshold": [*self.thresholds.tolist(), None]}


def pair_separation(classifier: WidthClassifier, widths, diameters) -> dict[str, np.ndarray]:
    r"""How well the width tells every pair of diameters apart on test traces.

    Parameters
    ----------
    classifier : WidthClassifier
        Fitted on training traces (its class mean widths).
    widths, diameters : (n,) arrays
        Test traces.

    Returns
    -------
    dict
        Table-shaped, one row per pair of classes (smaller diameter first):
        ``d_small``, ``d_large``, ``delta_mm``, ``accuracy`` (balanced
        accuracy of the pair's threshold on the test traces of the two).

    Notes
    -----
    For a pair (a, b) the threshold is the midpoint of their training mean
    widths; a test trace is right when it falls on its class's side (the
    side of the class with the larger mean width is :math:`w \ge t`). The
    accuracy is the mean of the two classes' right fractions; a pair with
    equal mean widths, or with no test trace of either class, scores 0.5.
    """
    if not isinstance(classifier, WidthClassifier):
        raise TypeError(f"classifier must be a WidthClassifier, got {type(classifier).__name__}")
    w, d = _labelled(widths, diameters)
    mean = dict(zip(classifier.diameters.tolist(), classifier.mean_widths.tolist(), strict=True))
    classes = sorted(mean)
    rows: dict[str, list] = {"d_small": [], "d_large": [], "delta_mm": [], "accuracy": []}
    for i, a in enumerate(classes):
        for b in classes[i + 1:]:
            wa, wb = w[d == a], w[d == b]
            if mean[a] == mean[b] or wa.size == 0 or wb.size == 0:
                acc = 0.5
            else:
                t = (mean[a] + mean[b]) / 2
                hi_a = mean[a] > mean[b]
                ra = np.mean((wa >= t) == hi_a)
                rb = np.mean((wb >= t) != hi_a)
                acc = float((ra + rb) / 2)
            rows["d_small"].append(a)
            rows["d_large"].append(b)
            rows["delta_mm"].append(b - a)
            rows["accuracy"].append(acc)
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def diameter_resolution(classifier: WidthClassifier, widths, diameters, *, reliability: float = 0.95) -> float:
    r"""Smallest diameter difference that the width separates reliably across the whole range.

    Parameters
    ----------
    classifier : WidthClassifier
        Fitted on training traces.
    widths, diameters : (n,) arrays
        Test traces.
    reliability : float
        Balanced accuracy a pair must reach (0.5 < reliability <= 1).

    Returns
    -------
    float
        The smallest :math:`\Delta` among the pairs' differences such that every
        pair of classes at least :math:`\Delta` apart reaches ``reliability``
        in :func:`pair_separation`, mm; ``inf`` when not even the two extreme
        classes do.

    Examples
    --------
    >>> clf = WidthClassifier.fit([3, 3, 4, 4, 5, 5], [10, 10, 20, 20, 30, 30])
    >>> diameter_resolution(clf, [3, 3, 3, 4, 5, 5], [10, 10, 20, 20, 30, 30])
    20.0
    """
    r = positive(reliability, "reliability")
    if not 0.5 < r <= 1:
        raise InputError(f"reliability must be in (0.5, 1], got {reliability!r}")
    table = pair_separation(classifier, widths, diameters)
    best = math.inf
    for delta in sorted(set(table["delta_mm"].tolist()), reverse=True):
        if np.all(table["accuracy"][table["delta_mm"] >= delta] >= r - 1e-12):
            best = delta
        else:
            break
    return float(best)

