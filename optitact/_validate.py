"""Validation helpers shared by the public entry points."""

from __future__ import annotations

import numbers

import numpy as np

from optitact.errors import InputError, ShapeError


def real_array(value, name: str) -> np.ndarray:
    """Return ``value`` as a float64 array, refusing non-numeric kinds.

    Raises
    ------
    TypeError
        If ``value`` is not a real numeric array (bool, complex, object and
        string arrays are refused), or nested sequences of unequal lengths.
    """
    try:
        arr = np.asarray(value)
    except ValueError as exc:  # nested sequences of unequal lengths
        raise TypeError(f"{name} must be a real numeric array; could not make one from the "
                        f"nested sequences given ({exc})") from None
    if arr.dtype.kind not in "iuf":
        raise TypeError(
            f"{name} must be a real numeric array, got dtype {arr.dtype}"
        )
    return arr.astype(np.float64, copy=False)


def finite(arr: np.ndarray, name: str) -> np.ndarray:
    """Raise InputError if ``arr`` holds NaN or infinity."""
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InputError(
            f"{name} must be finite, got {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}"
        )
    return arr


def shape_tail(arr: np.ndarray, tail: tuple[int, ...], name: str, what: str) -> np.ndarray:
    """Check that the trailing dimensions of ``arr`` equal ``tail``."""
    if arr.ndim < len(tail) or tuple(arr.shape[arr.ndim - len(tail):]) != tail:
        raise ShapeError(f"{name} must have shape {what}, got {arr.shape}")
    return arr


def positive(value, name: str, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a float after checking it is a finite positive number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    bound = ">= 0" if allow_zero else "> 0"
    v = _float(value, f"{name} must be finite and {bound}")
    ok = v >= 0 if allow_zero else v > 0
    if not np.isfinite(v) or not ok:
        raise InputError(f"{name} must be finite and {bound}, got {value!r}")
    return v


def _float(value: numbers.Real, must: str) -> float:
    """``float(value)``; InputError ``must`` for a number beyond float64 (a huge int or Fraction)."""
    try:
        return float(value)
    except OverflowError:  # its repr may not even be printable (ints beyond 4300 digits)
        raise InputError(f"{must}, got a number beyond float64 (about 1.8e308)") from None


def integer(value, name: str, *, minimum: int | None = None) -> int:
    """Return ``value`` as an int after checking its kind and lower bound."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise InputError(f"{name} must be >= {minimum}, got {v}")
    return v


def real_number(value, name: str) -> float:
    """Return ``value`` as a float after checking it is a finite real number (any sign)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = _float(value, f"{name} must be finite")
    if not np.isfinite(v):
        raise InputError(f"{name} must be finite, got {value!r}")
    return v


def seed_value(seed, name: str = "seed") -> int | None:
    """Check a seed: None or a non-negative integer."""
    if seed is None:
        return None
    return integer(seed, name, minimum=0)


def check_type(value, cls: type, name: str):
    """Return ``value`` if it is a ``cls``; a TypeError naming ``name`` otherwise."""
    if not isinstance(value, cls):
        raise TypeError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
    return value


def check_keys(d, allowed, what: str, *, required=(), noun: str = "key") -> dict:
    """Check a dict read from a file: a mapping whose keys are among ``allowed``.

    Unknown keys are an :class:`InputError` listing them and the valid ones
    (``"<what>: unknown <noun>(s) [...]; valid: [...]"``); so are missing
    ``required`` keys; a non-mapping is a TypeError. Returns a plain dict copy.
    """
    from collections.abc import Mapping

    if not isinstance(d, Mapping):
        raise TypeError(f"{what} must be a dict, got {type(d).__name__}")
    allowed = set(allowed)
    unknown = sorted(set(map(str, d)) - allowed)
    if unknown:
        raise InputError(f"{what}: unknown {noun}(s) {unknown}; valid: {sorted(allowed)}")
    missing = [k for k in required if k not in d]
    if missing:
        raise InputError(f"{what}: missing {noun}(s) {missing}")
    return dict(d)


def json_numbers(value, what: str) -> np.ndarray:
    """A nested list of JSON numbers as a float64 array; InputError naming ``what`` otherwise.

    Strings ("0.99"), booleans, nulls and objects are refused (NumPy would
    convert the first two), and so are values that are not finite in float64
    (1e309 parses as infinity; integers beyond float64 overflow).
    """
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise InputError(f"{what} must hold numbers, got {item!r} ({type(item).__name__})")
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, ArithmeticError):  # ragged lists; ints beyond float64 overflow
        raise InputError(f"{what} must be a regular array of numbers within float64") from None
    if not np.isfinite(a).all():
        raise InputError(f"{what} must be finite, got {a[~np.isfinite(a)].flat[0]} (JSON numbers beyond "
                         f"float64, such as 1e309, read as infinity)")
    return a


def float_like(arr: np.ndarray, like) -> np.ndarray:
    """``arr`` as float32 if ``like`` is float32 (float32 in, float32 out), else unchanged."""
    return arr.astype(np.float32) if np.asarray(like).dtype == np.float32 else arr
