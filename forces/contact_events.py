"""Contact events: per-element normal-force thresholds with hysteresis.

Published thresholds: 0.2 N to find a table, 0.3 N for contour contact.
"""

from __future__ import annotations


import numpy as np

from optitact._validate import finite, integer, positive, real_array
from optitact.errors import InputError, ShapeError

from optitact.forces.series import TABLE_THRESHOLD

__all__ = ["ContactDetector", "detect_contact"]


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
