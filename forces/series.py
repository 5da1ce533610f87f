"""Checks shared by the force-series tools (friction, slip, contact events).

Convention
----------
Forces in N, times in s. A shear given as vectors ``(T, 2)`` or ``(T, 3)``
is reduced to its magnitude ``|F_t|``; a scalar series is used as is.
"""

from __future__ import annotations

import numpy as np

from optitact._validate import finite, positive, real_array
from optitact.errors import InputError, ShapeError

#: Published slip band on the shear-force derivative (N/s).
SLIP_THRESHOLD = 0.06
#: Published normal-force threshold that detects the table (N).
TABLE_THRESHOLD = 0.2
#: Published normal-force threshold of contour contact (N).
CONTOUR_THRESHOLD = 0.3


def series(values, name: str) -> np.ndarray:
    """A finite 1-D float series; (T, k) vectors become their magnitudes."""
    arr = finite(real_array(values, name), name)
    if arr.ndim == 2:
        arr = np.sqrt(np.sum(arr * arr, axis=1))
    elif arr.ndim != 1:
        raise ShapeError(f"{name} must have shape (T,) or (T, k) (one value or vector per sample), "
                         f"got {arr.shape}")
    return arr


def times(t, n: int, name: str = "t") -> np.ndarray:
    """``t`` as ``n`` finite, strictly increasing times; InputError or ShapeError naming ``name``."""
    arr = finite(real_array(t, name), name)
    if arr.shape != (n,):
        raise ShapeError(f"{name} must have shape ({n},) like the forces, got {arr.shape}")
    if n > 1 and not np.all(np.diff(arr) > 0):
        bad = int(np.argmin(np.diff(arr)))
        raise InputError(f"{name} must be strictly increasing, got {arr[bad]!r} then {arr[bad + 1]!r} "
                         f"at index {bad}")
    return arr


def fraction(value, name: str, *, upper: float = 1.0, allow_zero: bool = True) -> float:
    """``value`` as a number in [0, ``upper``] (0 excluded without ``allow_zero``); InputError otherwise."""
    v = positive(value, name, allow_zero=allow_zero)
    if v > upper:
        raise InputError(f"{name} must be in [0, {upper:g}], got {value!r}")
    return v
