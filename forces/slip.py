"""Slip detection: the shear force's time derivative against a band, online or on recorded arrays.

:class:`SlipDetector` (frame by frame) and :func:`detect_slip` (arrays) give
identical events; the published band is ``+-0.06 N/s``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from optitact._validate import finite, integer, positive, real_array, real_number
from optitact.errors import InputError, ShapeError

from optitact.forces.series import SLIP_THRESHOLD, fraction, series, times

__all__ = ["SlipEvent", "SlipResult", "SlipDetector", "detect_slip"]


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
        self.min_fill = fraction(min_fill, "min_fill")
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
    f = series(shear, "shear")
    tt = times(t, len(f))
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
