"""The friction coefficient of a sliding contact from its estimated forces.

:func:`friction_coefficient` -- ``mu = |F_t| / F_n`` over the steady part of
a sliding contact, found automatically; mean and spread (the published
procedure of the sensor's inventors). Slip detection is in
:mod:`optitact.forces.slip`, contact events in
:mod:`optitact.forces.contact_events`.

Convention
----------
Forces in N, times in s. A shear given as vectors ``(T, 2)`` or ``(T, 3)``
is reduced to its magnitude ``|F_t|``; a scalar series is used as is
(e.g. one signed component).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from optitact._validate import integer, positive
from optitact.errors import InputError, ShapeError

from optitact.forces.series import fraction, series, times

__all__ = ["FrictionEstimate", "friction_coefficient"]


@dataclass(frozen=True)
class FrictionEstimate:
    """The friction coefficient of the steady part of a sliding contact.

    Attributes
    ----------
    mean, std, median : float
        Of ``mu`` over the steady samples (``std`` with ``ddof=1``).
    sem : float
        Standard error of the mean, ``std / sqrt(n)`` (samples treated as
        independent).
    n : int
        Steady samples.
    start, stop : int
        The steady part is ``mu[start:stop]``.
    t_start, t_stop : float
        Times of its first and last sample (sample indices when no times
        were given).
    level : float
        The plateau level the steady part was grown around (its median).
    band : float
        Half-width of the band around ``level`` that bounded it.
    mu : (T,) ndarray
        ``|F_t| / F_n`` per sample; 0 where ``valid`` is False.
    valid : (T,) ndarray of bool
        Samples in contact (``F_n > fn_min``).
    """

    mean: float
    std: float
    median: float
    sem: float
    n: int
    start: int
    stop: int
    t_start: float
    t_stop: float
    level: float
    band: float
    mu: np.ndarray = field(repr=False)
    valid: np.ndarray = field(repr=False)

    @property
    def steady(self) -> slice:
        """``slice(start, stop)``: the steady samples."""
        return slice(self.start, self.stop)

    def as_dict(self) -> dict:
        """The scalar figures as plain Python values (JSON-ready)."""
        return {k: getattr(self, k) for k in ("mean", "std", "median", "sem", "n", "start", "stop",
                                              "t_start", "t_stop", "level", "band")}


def _running_median(x: np.ndarray, window: int) -> np.ndarray:
    """Centred running median (the window shrinks at the ends)."""
    from scipy.ndimage import median_filter

    if window <= 1 or len(x) < 3:
        return x.copy()
    return median_filter(x, size=min(window, len(x) | 1), mode="nearest")


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """``(start, stop)`` of the longest run of True (``(0, 0)`` when none)."""
    if not mask.any():
        return 0, 0
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    starts, stops = edges[::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])


def friction_coefficient(ft, fn, *, t=None, fn_min: float | None = None, window: int = 9,
                         n_sigma: float = 3.0, rel_band: float = 0.05, min_level: float = 0.5,
                         trim: float = 0.1, min_samples: int = 5) -> FrictionEstimate:
    r"""Friction coefficient ``mu = |F_t| / F_n`` over the steady part of a sliding contact.

    Parameters
    ----------
    ft : (T,) or (T, k) array_like
        Shear force (N): magnitudes, or vectors whose norm is used.
    fn : (T,) array_like
        Normal force (N).
    t : (T,) array_like, optional
        Sample times (s), strictly increasing; only reported (``t_start``,
        ``t_stop``).
    fn_min : float, optional
        Samples with ``F_n <= fn_min`` are not in contact and never steady;
        default 20 % of the 90th percentile of ``fn``.
    window : int
        Samples of the centred running median that smooths ``mu`` before
        the plateau search (default 9; odd). Transients shorter than half of
        it (a static-friction peak) do not break the plateau.
    n_sigma, rel_band : float
        The steady band around the plateau level ``L`` is
        ``max(n_sigma * sigma, rel_band * L)``, ``sigma`` the per-sample noise
        of ``mu`` (defaults 3 and 5 %).
    min_level : float
        Plateaus below ``min_level`` times the largest smoothed ``mu`` are
        not sliding (the dwell before the stage moves, the stick ramp);
        default 0.5.
    trim : float
        Fraction of the steady run dropped at each end (default 0.1), where
        the smoothing blurs the transitions.
    min_samples : int
        Fewest steady samples accepted (default 5).

    Returns
    -------
    FrictionEstimate

    Raises
    ------
    TypeError
        Non-numeric inputs.
    ShapeError
        ``ft``, ``fn`` and ``t`` of different lengths or wrong dimensions.
    InputError
        Non-finite values, bad options, or no steady part of at least
        ``min_samples`` samples (the message says how many contact samples
        there were and the longest run found).

    Notes
    -----
    ``mu_i = |F_t,i| / F_n,i`` on the contact samples, smoothed by the
    running median into ``m_i``. The per-sample noise is estimated robustly
    from first differences, ``sigma = 1.4826 MAD(diff(mu)) / sqrt(2)``.
    Every smoothed value ``L >= min_level * max(m)`` is a candidate plateau
    level; the one whose band ``|m_i - L| <= b(L)`` holds over the longest
    contiguous run of contact samples wins (a sliding contact is the longest
    stretch at one friction level). The level is then re-centred on the
    median of the run's raw ``mu`` and the run regrown, until it no longer
    changes (at most 5 times); ``trim`` of it is dropped at each end.
    Mean, standard deviation and median are of the raw ``mu`` on what
    remains.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> fn = np.r_[np.linspace(0, 0.1, 10), np.full(80, 0.1)]
    >>> ft = np.r_[np.zeros(10), np.linspace(0, 0.04, 10), np.full(70, 0.04)] + rng.normal(0, 5e-4, 90)
    >>> est = friction_coefficient(ft, fn)
    >>> round(est.mean, 2), est.start >= 20
    (0.4, True)
    """
    ft = np.abs(series(ft, "ft"))
    fn = series(fn, "fn")
    if fn.ndim != 1 or len(fn) != len(ft):
        raise ShapeError(f"fn must have shape ({len(ft)},) like ft, got {fn.shape}")
    n_t = len(ft)
    tt = np.arange(n_t, dtype=float) if t is None else times(t, n_t)
    window = integer(window, "window", minimum=1)
    n_sigma = positive(n_sigma, "n_sigma", allow_zero=True)
    rel_band = positive(rel_band, "rel_band", allow_zero=True)
    min_level = fraction(min_level, "min_level")
    trim = fraction(trim, "trim", upper=0.45)
    min_samples = integer(min_samples, "min_samples", minimum=2)
    if fn_min is None:
        top = float(np.percentile(fn, 90)) if n_t else 0.0
        fn_min = 0.2 * max(top, 0.0)
    else:
        fn_min = positive(fn_min, "fn_min", allow_zero=True)
    valid = fn > fn_min
    mu = np.zeros(n_t)
    mu[valid] = ft[valid] / fn[valid]
    n_valid = int(valid.sum())
    if n_valid < min_samples:
        raise InputError(f"friction_coefficient needs at least {min_samples} contact samples "
                         f"(F_n > {fn_min:.3g} N), got {n_valid}")
    idx = np.flatnonzero(valid)
    # Smooth within contact runs only (no median across a lift-off).
    m = np.zeros(n_t)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    for r in runs:
        m[r] = _running_median(mu[r], window)
    d = np.concatenate([np.diff(mu[r]) for r in runs if len(r) > 1] or [np.zeros(1)])
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)

    def band(level: float) -> float:
        return max(n_sigma * sigma, rel_band * abs(level), 1e-12)

    def run_at(level: float) -> tuple[int, int]:
        return _longest_run(valid & (np.abs(m - level) <= band(level)))

    top = float(m[valid].max())
    levels = np.unique(m[valid & (m >= min_level * top)])
    if len(levels) > 400:  # a grid is enough to find the longest plateau
        levels = np.quantile(levels, np.linspace(0, 1, 400))
    lengths = [np.subtract(*run_at(L)[::-1]) for L in levels]
    level = float(levels[int(np.argmax(lengths))])
    start, stop = run_at(level)
    for _ in range(5):
        new_level = float(np.median(mu[start:stop]))
        new = run_at(new_level)
        if new[1] - new[0] < min_samples:
            break
        level = new_level
        if new == (start, stop):
            break
        start, stop = new
    cut = int(math.floor(trim * (stop - start)))
    start, stop = start + cut, stop - cut
    if stop - start < min_samples:
        raise InputError(f"no steady sliding part of at least {min_samples} samples: the longest run "
                         f"within the band around mu = {level:.3g} has {stop - start} samples after "
                         f"trimming ({n_valid} contact samples)")
    steady = mu[start:stop]
    std = float(np.std(steady, ddof=1))
    mu.flags.writeable = False
    valid.flags.writeable = False
    return FrictionEstimate(mean=float(steady.mean()), std=std, median=float(np.median(steady)),
                            sem=std / math.sqrt(len(steady)), n=len(steady), start=start, stop=stop,
                            t_start=float(tt[start]), t_stop=float(tt[stop - 1]), level=level,
                            band=band(level), mu=mu, valid=valid)
