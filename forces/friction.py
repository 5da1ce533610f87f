"""Force-derived quantities of a sliding or manipulating contact: friction, slip and contact events.

The three tools a robot finger with the dome sensor uses on its estimated
forces (the published procedure of the sensor's inventors):

* :func:`friction_coefficient` -- ``mu = |F_t| / F_n`` over the steady part
  of a sliding contact, found automatically; mean and spread.
* :class:`SlipDetector` / :func:`detect_slip` -- the time derivative of the
  shear force (a causal least-squares slope: the smoothing is explained
  there) compared with a band, published ``+-0.06 N/s``; slip events with
  onset times, online (frame by frame) or on recorded arrays, with
  identical results.
* :class:`ContactDetector` / :func:`detect_contact` -- per-element normal
  force thresholds with hysteresis (published: 0.2 N to find a table, 0.3 N
  for contour contact), so that noise near a threshold does not chatter.

Convention
----------
Forces in N, times in s. A shear given as vectors ``(T, 2)`` or ``(T, 3)``
is reduced to its magnitude ``|F_t|``; a scalar series is used as is
(e.g. one signed component).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from optitact._validate import finite, integer, positive, real_array, real_number
from optitact.errors import InputError, ShapeError

__all__ = ["SLIP_THRESHOLD", "TABLE_THRESHOLD", "CONTOUR_THRESHOLD", "FrictionEstimate",
           "friction_coefficient", "SlipEvent", "SlipResult", "SlipDetector", "detect_slip",
           "ContactDetector", "detect_contact"]

#: Published slip band on the shear-force derivative (N/s).
SLIP_THRESHOLD = 0.06
#: Published normal-force threshold that detects the table (N).
TABLE_THRESHOLD = 0.2
#: Published normal-force threshold of contour contact (N).
CONTOUR_THRESHOLD = 0.3


def _series(values, name: str) -> np.ndarray:
    """A finite 1-D float series; (T, k) vectors become their magnitudes."""
    arr = finite(real_array(values, name), name)
    if arr.ndim == 2:
        arr = np.sqrt(np.sum(arr * arr, axis=1))
    elif arr.ndim != 1:
        raise ShapeError(f"{name} must have shape (T,) or (T, k) (one value or vector per sample), "
                         f"got {arr.shape}")
    return arr


def _times(t, n: int, name: str = "t") -> np.ndarray:
    arr = finite(real_array(t, name), name)
    if arr.shape != (n,):
        raise ShapeError(f"{name} must have shape ({n},) like the forces, got {arr.shape}")
    if n > 1 and not np.all(np.diff(arr) > 0):
        bad = int(np.argmin(np.diff(arr)))
        raise InputError(f"{name} must be strictly increasing, got {arr[bad]!r} then {arr[bad + 1]!r} "
                         f"at index {bad}")
    return arr


def _fraction(value, name: str, *, upper: float = 1.0, allow_zero: bool = True) -> float:
    v = positive(value, name, allow_zero=allow_zero)
    if v > upper:
        raise InputError(f"{name} must be in [0, {upper:g}], got {value!r}")
    return v


# ============================================================================ friction
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
    ft = np.abs(_series(ft, "ft"))
    fn = _series(fn, "fn")
    if fn.ndim != 1 or len(fn) != len(ft):
        raise ShapeError(f"fn must have shape ({len(ft)},) like ft, got {fn.shape}")
    n_t = len(ft)
    tt = np.arange(n_t, dtype=float) if t is None else _times(t, n_t)
    window = integer(window, "window", minimum=1)
    n_sigma = positive(n_sigma, "n_sigma", allow_zero=True)
    rel_band = positive(rel_band, "rel_band", allow_zero=True)
    min_level = _fraction(min_level, "min_level")
    trim = _fraction(trim, "trim", upper=0.45)
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


# ============================================================================ slip
@dataclass(frozen=True)
class SlipEvent:
    """One slip event: the shear derivative left the band.

    Attributes
    ----------
    onset : float
        Time of the first sample whose derivative was out of the band (the
        detection time; an online detector can know no earlier).
    end : float
        Time of the last out-of-band sample.
    onset_index, end_index : int
        Their sample indices (counted over every update).
    peak_rate : float
        The largest derivative in magnitude during the event, signed (N/s).
    sign : int
        -1 when the event started with the shear falling (the typical slip:
        the grip gives way), +1 when rising.
    """

    onset: float
    end: float
    onset_index: int
    end_index: int
    peak_rate: float
    sign: int

    def as_dict(self) -> dict:
        """Plain Python values (JSON-ready)."""
        return {"onset": self.onset, "end": self.end, "onset_index": self.onset_index,
                "end_index": self.end_index, "peak_rate": self.peak_rate, "sign": self.sign}


@dataclass(frozen=True)
class SlipResult:
    """What :func:`detect_slip` found on a recorded stream.

    Attributes
    ----------
    events : list of SlipEvent
    derivative : (T,) ndarray
        Smoothed shear derivative (N/s); 0 where ``ready`` is False.
    ready : (T,) ndarray of bool
        The derivative had enough samples in its window (and the detector
        was active).
    slipping : (T,) ndarray of bool
        Inside an event.
    threshold : float
        The band's half-width (N/s).
    """

    events: list
    derivative: np.ndarray = field(repr=False)
    ready: np.ndarray = field(repr=False)
    slipping: np.ndarray = field(repr=False)
    threshold: float = SLIP_THRESHOLD

    @property
    def onsets(self) -> np.ndarray:
        """(n_events,) onset times."""
        return np.array([e.onset for e in self.events], dtype=float)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Per-event table: equal-length arrays keyed by name."""
        keys = ("onset", "end", "onset_index", "end_index", "peak_rate", "sign")
        return {k: np.array([getattr(e, k) for e in self.events],
                            dtype=int if k in ("onset_index", "end_index", "sign") else float)
                for k in keys}


class SlipDetector:
    r"""Online slip detection: the shear-force derivative against a band.

    Parameters
    ----------
    threshold : float
        Half-width of the band (N/s), default the published 0.06.
    window : float
        Length (s) of the causal window of the derivative, default 0.5.
    hold : float
        An event ends once the derivative has stayed inside the band this
        long (s), default 0.3; a shorter return to the band continues the
        event (the recovery of a slip belongs to it).
    min_samples : int
        Fewest samples in the window for a derivative, default 3.
    min_fill : float
        The samples in the window must also span this fraction of it,
        default 0.75: a slope over a short stretch is too noisy to compare
        with the band (the noise grows as the span's power -3/2).
    direction : {"both", "drop", "rise"}
        Which excursions start an event: both signs (default), a falling
        shear only, or a rising one only. Once started, an event lasts while
        the derivative is out of the band on either side.

    Notes
    -----
    **Smoothing.** The derivative at time ``t_k`` is the least-squares
    slope of the shear over the samples of the last ``window`` seconds,

    .. math:: \dot F(t_k) = \frac{\sum_i (t_i - \bar t)(F_i - \bar F)}{\sum_i (t_i - \bar t)^2},
              \qquad t_k - t_i < \text{window},

    i.e. a causal Savitzky-Golay derivative filter of order 1 (exact for any
    sampling, uniform or not). For ``n`` equally spaced samples ``dt`` apart
    and white shear noise ``sigma`` its noise is
    ``sigma sqrt(12 / (n (n^2 - 1))) / dt``: with 10 samples at 20 Hz and
    ``sigma`` = 5 mN, 0.011 N/s, a fifth of the band. The price is delay:
    a ramp is tracked with a lag of about ``window / 2``, a step is seen
    within one or two samples. A vector shear is reduced to its magnitude
    ``|F_t|`` (a slip lowers it whatever the direction of the load).

    Samples with ``active=False`` (e.g. while the robot accelerates or turns,
    when the shear changes by command) clear the window and end any event;
    the derivative is ready again once the window has filled (``min_fill``).

    Examples
    --------
    >>> import numpy as np
    >>> det = SlipDetector()
    >>> t = np.arange(0, 4, 0.05)
    >>> shear = np.where(t < 2, 0.15, 0.08)           # the grip gives way at t = 2 s
    >>> for ti, fi in zip(t, shear):
    ...     _ = det.update(ti, fi)
    >>> [(round(e.onset, 2), e.sign) for e in det.events]
    [(2.0, -1)]
    """

    def __init__(self, *, threshold: float = SLIP_THRESHOLD, window: float = 0.5, hold: float = 0.3,
                 min_samples: int = 3, min_fill: float = 0.75, direction: str = "both") -> None:
        self.threshold = positive(threshold, "threshold")
        self.window = positive(window, "window")
        self.hold = positive(hold, "hold", allow_zero=True)
        self.min_samples = integer(min_samples, "min_samples", minimum=2)
        self.min_fill = _fraction(min_fill, "min_fill")
        if direction not in ("both", "drop", "rise"):
            raise InputError(f"direction must be one of ('both', 'drop', 'rise'), got {direction!r}")
        self.direction = direction
        self.reset()

    def reset(self) -> None:
        """Forget the stream: clear the window, the current event and the event list."""
        self._buf: deque = deque()
        self._t_last: float | None = None
        self._k = -1
        self._event: dict | None = None
        self.events: list[SlipEvent] = []
        #: Last derivative (N/s), 0 until ready.
        self.derivative = 0.0
        #: Whether the last derivative had enough samples.
        self.ready = False

    @property
    def slipping(self) -> bool:
        """Whether an event is under way."""
        return self._event is not None

    def _close(self) -> SlipEvent:
        ev = self._event
        out = SlipEvent(onset=ev["onset"], end=ev["end"], onset_index=ev["onset_index"],
                        end_index=ev["end_index"], peak_rate=ev["peak"], sign=ev["sign"])
        self.events.append(out)
        self._event = None
        return out

    def _slope(self) -> float:
        t = np.fromiter((p[0] for p in self._buf), float, len(self._buf))
        f = np.fromiter((p[1] for p in self._buf), float, len(self._buf))
        tc = t - t.mean()
        den = float(tc @ tc)
        return float(tc @ (f - f.mean()) / den) if den > 0 else 0.0

    def update(self, t, shear, *, active: bool = True) -> bool:
        """Feed one sample; return whether an event is under way after it.

        Parameters
        ----------
        t : float
            Sample time (s), later than the previous one.
        shear : float or (k,) array_like
            Shear force (N): a value, or a vector whose magnitude is used.
        active : bool
            False while detection must not run (see the class *Notes*).

        Raises
        ------
        TypeError, InputError
            Non-numeric or non-finite values, or ``t`` not after the previous
            sample.
        """
        t = real_number(t, "t")
        if self._t_last is not None and not t > self._t_last:
            raise InputError(f"t must increase from sample to sample, got {t!r} after {self._t_last!r}")
        f = finite(real_array(shear, "shear"), "shear")
        if f.ndim > 1:
            raise ShapeError(f"shear must be a value or a vector (k,), got shape {f.shape}")
        value = float(np.sqrt(np.sum(f * f))) if f.ndim == 1 else float(f)
        self._t_last = t
        self._k += 1
        if not active:
            self._buf.clear()
            self.derivative, self.ready = 0.0, False
            if self._event is not None:
                self._close()
            return False
        self._buf.append((t, value))
        while t - self._buf[0][0] >= self.window and len(self._buf) > 1:
            self._buf.popleft()
        self.ready = (len(self._buf) >= self.min_samples
                      and t - self._buf[0][0] >= self.min_fill * self.window * (1.0 - 1e-9))
        self.derivative = self._slope() if self.ready else 0.0
        d = self.derivative
        out = self.ready and abs(d) > self.threshold
        if self._event is None:
            starts = out and (self.direction == "both" or (d < 0) == (self.direction == "drop"))
            if starts:
                self._event = {"onset": t, "end": t, "onset_index": self._k, "end_index": self._k,
                               "peak": d, "sign": -1 if d < 0 else 1}
        elif out:
            ev = self._event
            ev["end"], ev["end_index"] = t, self._k
            if abs(d) > abs(ev["peak"]):
                ev["peak"] = d
        elif t - self._event["end"] >= self.hold:
            self._close()
        return self._event is not None

    def finish(self) -> list[SlipEvent]:
        """Close an event still under way at the end of the stream; return all events."""
        if self._event is not None:
            self._close()
        return list(self.events)


def detect_slip(t, shear, *, active=None, threshold: float = SLIP_THRESHOLD, window: float = 0.5,
                hold: float = 0.3, min_samples: int = 3, min_fill: float = 0.75,
                direction: str = "both") -> SlipResult:
    """Slip events of a recorded stream (the online :class:`SlipDetector`, sample by sample).

    Parameters
    ----------
    t : (T,) array_like
        Sample times (s), strictly increasing.
    shear : (T,) or (T, k) array_like
        Shear force (N), values or vectors (their magnitude is used).
    active : (T,) array_like of bool, optional
        Samples where detection runs (default all).
    threshold, window, hold, min_samples, min_fill, direction
        As for :class:`SlipDetector`.

    Returns
    -------
    SlipResult
        Identical to feeding the samples one by one to a
        :class:`SlipDetector` (an event still under way at the end is
        closed).

    Raises
    ------
    TypeError, ShapeError, InputError
        Wrong kinds, lengths, non-finite values, or times not increasing.
    """
    f = _series(shear, "shear")
    tt = _times(t, len(f))
    if active is None:
        act = np.ones(len(f), bool)
    else:
        act = np.asarray(active)
        if act.dtype != np.bool_:
            raise TypeError(f"active must be a bool array, got dtype {act.dtype}")
        if act.shape != (len(f),):
            raise ShapeError(f"active must have shape ({len(f)},) like the shear, got {act.shape}")
    det = SlipDetector(threshold=threshold, window=window, hold=hold, min_samples=min_samples,
                       min_fill=min_fill, direction=direction)
    deriv = np.zeros(len(f))
    ready = np.zeros(len(f), bool)
    slipping = np.zeros(len(f), bool)
    for k in range(len(f)):
        slipping[k] = det.update(float(tt[k]), float(f[k]), active=bool(act[k]))
        deriv[k], ready[k] = det.derivative, det.ready
    return SlipResult(events=det.finish(), derivative=deriv, ready=ready, slipping=slipping,
                      threshold=det.threshold)


# ============================================================================ contact
class ContactDetector:
    """Per-element contact from normal forces, with hysteresis (online).

    Parameters
    ----------
    on : float
        Normal force (N) at or above which an element comes into contact,
        default the published table threshold 0.2 N (use
        ``CONTOUR_THRESHOLD``, 0.3 N, for contour tracing).
    off : float, optional
        Force below which it leaves contact again, default ``0.75 * on``;
        must be ``<= on``. The gap is the hysteresis: a force hovering at the
        threshold with noise smaller than ``on - off`` does not chatter.
    confirm : int
        Consecutive samples beyond a threshold needed to switch (default 1).

    Attributes
    ----------
    state : (E,) ndarray of bool or None
        Current contact per element (None before the first update).
    events : list of tuple
        ``(sample_index, element, "on" | "off")`` transitions, in order.

    Examples
    --------
    >>> det = ContactDetector(0.3)
    >>> [bool(det.update(f)[0]) for f in (0.1, 0.31, 0.28, 0.31, 0.2)]
    [False, True, True, True, False]
    """

    def __init__(self, on: float = TABLE_THRESHOLD, *, off: float | None = None, confirm: int = 1) -> None:
        self.on = positive(on, "on")
        self.off = 0.75 * self.on if off is None else positive(off, "off", allow_zero=True)
        if self.off > self.on:
            raise InputError(f"off must be <= on ({self.on:g} N), got {self.off!r}")
        self.confirm = integer(confirm, "confirm", minimum=1)
        self.reset()

    def reset(self) -> None:
        """Forget the stream."""
        self.state: np.ndarray | None = None
        self._count: np.ndarray | None = None
        self._k = -1
        self.events: list[tuple[int, int, str]] = []

    def update(self, fn) -> np.ndarray:
        """Feed one sample of normal forces (a value or ``(E,)``); return the contact state.

        Raises
        ------
        TypeError, ShapeError, InputError
            Non-numeric, non-finite, or a number of elements that changed.
        """
        f = finite(real_array(fn, "fn"), "fn")
        if f.ndim > 1:
            raise ShapeError(f"fn must be a value or one per element (E,), got shape {f.shape}")
        f = np.atleast_1d(f)
        if self.state is None:
            self.state = np.zeros(f.shape, bool)
            self._count = np.zeros(f.shape, int)
        elif f.shape != self.state.shape:
            raise ShapeError(f"fn must keep its shape {self.state.shape} from sample to sample, "
                             f"got {f.shape}")
        self._k += 1
        want = np.where(self.state, f >= self.off, f >= self.on)
        change = want != self.state
        self._count = np.where(change, self._count + 1, 0)
        flip = self._count >= self.confirm
        for e in np.flatnonzero(flip):
            self.events.append((self._k, int(e), "on" if want[e] else "off"))
        self.state = np.where(flip, want, self.state)
        self._count[flip] = 0
        return self.state.copy()


def detect_contact(fn, *, on: float = TABLE_THRESHOLD, off: float | None = None,
                   confirm: int = 1) -> np.ndarray:
    """Contact states of a recorded stream of normal forces (see :class:`ContactDetector`).

    Parameters
    ----------
    fn : (T,) or (T, E) array_like
        Normal forces (N) per sample (and element).
    on, off, confirm
        As for :class:`ContactDetector`.

    Returns
    -------
    (T,) or (T, E) ndarray of bool
    """
    f = finite(real_array(fn, "fn"), "fn")
    if f.ndim not in (1, 2):
        raise ShapeError(f"fn must have shape (T,) or (T, E), got {f.shape}")
    det = ContactDetector(on, off=off, confirm=confirm)
    out = np.zeros(f.shape, bool)
    for k in range(len(f)):
        st = det.update(f[k])
        out[k] = st if f.ndim == 2 else st[0]
    return out
