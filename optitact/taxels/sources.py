"""Tactile image sources: one interface for the dome camera and every taxel array.

Every tactile sensor optitact knows is a *source* of small images: its frames
are ``(H, W)`` or ``(T, H, W)`` arrays whose cells are laid out on a grid
described by a :class:`Layout` (pitch, which cells exist, units, sampling
rate). A source turns a :class:`Scenario` (an :class:`Indenter`, its pose and
its depth or force over time) into frames, with a seed.

Sensor types are data: each is a frozen, validated config dataclass (units in
its field comments) plus a factory registered by name with
:func:`register_source`; :func:`make_source` builds one by name and refuses an
unknown name with a ValueError listing the valid ones.

Convention: cell indices are ``(row, col)`` with ``(0, 0)`` the top-left
cell; the layout frame has x along columns and y along rows (mm), origin at
the grid centre, so cell ``(r, c)`` sits at
``x = (c - (W - 1) / 2) * pitch_x``, ``y = (r - (H - 1) / 2) * pitch_y``.

Examples
--------
>>> from optitact.taxels.sources import source_names
>>> "dome41" in source_names()
True
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from optitact._validate import finite, real_array
from optitact.errors import InputError, ShapeError

__all__ = [
    "Layout", "Indenter", "Scenario", "TactileSource", "register_source", "make_source",
    "source_names", "source_config", "moments", "INDENTER_SHAPES",
]

#: Indenter shapes a scenario may name; a source says which of them it simulates.
INDENTER_SHAPES = ("point", "sphere", "cylinder", "wire", "flat", "box")


def _as_mask(mask, shape: tuple[int, int]) -> np.ndarray:
    if mask is None:
        m = np.ones(shape, dtype=bool)
    else:
        m = np.asarray(mask)
        if m.dtype != bool:
            raise TypeError(f"layout mask must be a bool array, got dtype {m.dtype}")
        if m.shape != shape:
            raise ShapeError(f"layout mask must have shape {shape}, got {m.shape}")
        m = m.copy()
    if not m.any():
        raise InputError("layout mask must contain at least one cell, got none")
    m.setflags(write=False)
    return m


@dataclass(frozen=True, eq=False)
class Layout:
    """Where a source's cells are and what their values mean.

    Parameters
    ----------
    shape : (int, int)
        Grid rows and columns (H, W).
    pitch_mm : (float, float)
        Centre-to-centre distance along rows (y) and columns (x), mm.
    units : str
        Units of the frame values (``"V"``, ``"DN"``, ``"kOhm"``, ...).
    rate_hz : float
        Frames per second the sensor delivers.
    mask : (H, W) bool array, optional
        Which cells exist (non-rectangular pads); all by default.
    positions_mm : (H, W, 3) float array, optional
        Cell centres in 3-D for non-planar sensors; by default the flat grid
        (z = 0) of the module convention.
    normals : (H, W, 3) float array, optional
        Unit outward normals of the cells for non-planar sensors; +z by default.

    Convention: see the module docstring (row, col) and the layout frame.
    """

    shape: tuple[int, int]
    pitch_mm: tuple[float, float]
    units: str
    rate_hz: float
    mask: np.ndarray | None = None
    positions_mm: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        if len(self.shape) != 2 or any(int(n) != n or n < 1 for n in self.shape):
            raise InputError(f"layout shape must be two positive integers (H, W), got {self.shape!r}")
        shape = (int(self.shape[0]), int(self.shape[1]))
        object.__setattr__(self, "shape", shape)
        pitch = np.broadcast_to(real_array(self.pitch_mm, "pitch_mm"), (2,)).astype(float)
        if not np.all(np.isfinite(pitch)) or np.any(pitch <= 0):
            raise InputError(f"pitch_mm must be finite and > 0, got {self.pitch_mm!r}")
        object.__setattr__(self, "pitch_mm", (float(pitch[0]), float(pitch[1])))
        if not isinstance(self.units, str) or not self.units:
            raise TypeError(f"units must be a non-empty string, got {self.units!r}")
        if not (isinstance(self.rate_hz, (int, float)) and math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"rate_hz must be finite and > 0, got {self.rate_hz!r}")
        object.__setattr__(self, "mask", _as_mask(self.mask, shape))
        for name in ("positions_mm", "normals"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = finite(real_array(value, name), name).copy()
            if arr.shape != (*shape, 3):
                raise ShapeError(f"{name} must have shape {(*shape, 3)}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n_cells(self) -> int:
        """Number of cells that exist (``mask.sum()``)."""
        return int(self.mask.sum())

    def cell_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell centres ``(x, y)`` in mm on the flat grid, each of shape (H, W)."""
        h, w = self.shape
        py, px = self.pitch_mm
        y, x = np.meshgrid((np.arange(h) - (h - 1) / 2) * py, (np.arange(w) - (w - 1) / 2) * px,
                           indexing="ij")
        return x, y

    def check_frames(self, frames, name: str = "frames") -> np.ndarray:
        """Return ``frames`` as a float64 (T, H, W) array after checking it fits this layout.

        Raises
        ------
        TypeError
            For non-numeric dtypes.
        ShapeError
            When the trailing dimensions are not ``shape``.
        InputError
            For NaN or infinite values.
        """
        arr = real_array(frames, name)
        if arr.ndim not in (2, 3) or arr.shape[-2:] != self.shape:
            raise ShapeError(f"{name} must have shape {self.shape} or (T, *{self.shape}), got {arr.shape}")
        finite(arr, name)
        return arr.reshape((-1, *self.shape))


@dataclass(frozen=True)
class Indenter:
    """The object pressed on a sensor.

    Parameters
    ----------
    shape : str
        One of :data:`INDENTER_SHAPES`.
    size_mm : float
        Radius for ``sphere``/``cylinder``/``wire``/``point``; half side for ``box``;
        ignored (any positive value) for ``flat``.
    length_mm : float
        Length of a ``cylinder``/``wire``/``box`` along its axis (``inf``: longer than the pad).
    stiffness_n_per_mm : float
        Contact stiffness of the object itself (``inf``: rigid).
    plasticity : float
        0 (fully elastic, springs back) ... 1 (fully plastic, keeps its deformation).
    """

    shape: str
    size_mm: float = 1.0
    length_mm: float = math.inf
    stiffness_n_per_mm: float = math.inf
    plasticity: float = 0.0

    def __post_init__(self) -> None:
        if self.shape not in INDENTER_SHAPES:
            raise InputError(f"indenter shape must be one of {INDENTER_SHAPES}, got {self.shape!r}")
        for name in ("size_mm", "length_mm", "stiffness_n_per_mm"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or math.isnan(v) or v <= 0:
                raise InputError(f"indenter {name} must be a number > 0, got {v!r}")
        if math.isinf(self.size_mm):
            raise InputError(f"indenter size_mm must be finite, got {self.size_mm!r}")
        if not isinstance(self.plasticity, (int, float)) or not 0 <= self.plasticity <= 1:
            raise InputError(f"indenter plasticity must be in [0, 1], got {self.plasticity!r}")


def _series(value, n: int, name: str) -> np.ndarray:
    arr = finite(real_array(value, name), name)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ShapeError(f"{name} must be a scalar or have shape ({n},) like t_s, got {arr.shape}")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Scenario:
    """An indenter's pose and load over time.

    Parameters
    ----------
    indenter : Indenter
    t_s : (T,) float
        Sample times, s, strictly increasing.
    x_mm, y_mm : float or (T,) float
        Indenter centre in the layout frame, mm.
    angle_rad : float or (T,) float
        Axis direction of a cylinder/wire/box, from +x towards +y.
    depth_mm : float or (T,) float, optional
        Indentation depth (>= 0), mm. Exactly one of ``depth_mm`` and ``force_n``.
    force_n : float or (T,) float, optional
        Normal force (>= 0), N.
    """

    indenter: Indenter
    t_s: np.ndarray
    x_mm: Any = 0.0
    y_mm: Any = 0.0
    angle_rad: Any = 0.0
    depth_mm: Any = None
    force_n: Any = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.indenter, Indenter):
            raise TypeError(f"indenter must be an Indenter, got {type(self.indenter).__name__}")
        t = finite(real_array(self.t_s, "t_s"), "t_s")
        if t.ndim != 1 or t.size < 1:
            raise ShapeError(f"t_s must be a non-empty 1-D array, got shape {t.shape}")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            raise InputError("t_s must be strictly increasing")
        t = t.copy()
        t.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        n = t.size
        for name in ("x_mm", "y_mm", "angle_rad"):
            object.__setattr__(self, name, _series(getattr(self, name), n, name))
        if (self.depth_mm is None) == (self.force_n is None):
            raise InputError("a scenario needs exactly one of depth_mm and force_n")
        for name in ("depth_mm", "force_n"):
            value = getattr(self, name)
            if value is not None:
                arr = _series(value, n, name)
                if np.any(arr < 0):
                    raise InputError(f"{name} must be >= 0, got minimum {arr.min()}")
                object.__setattr__(self, name, arr)

    @property
    def n_frames(self) -> int:
        """Number of samples T."""
        return int(self.t_s.size)


@runtime_checkable
class TactileSource(Protocol):
    """What every tactile sensor offers: a layout and frames from a contact scenario."""

    name: str

    @property
    def layout(self) -> Layout:
        """Cell grid, pitch, mask, units and sampling rate."""
        ...

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """Simulated frames (T, H, W) for ``scenario``; the same seed gives the same frames."""
        ...


@dataclass(frozen=True)
class _Entry:
    config_type: type
    factory: Callable[[Any], TactileSource]
    module: str


_REGISTRY: dict[str, _Entry] = {}
#: Modules that register the built-in sources when imported.
_BUILTIN_MODULES = ("optitact.taxels.dome41", "optitact.taxels")


def register_source(name: str, config_type: type, factory: Callable[[Any], TactileSource]) -> None:
    """Register a sensor type: a config dataclass and a factory ``factory(config) -> source``.

    Raises
    ------
    ValueError
        If ``name`` is already registered by another module.
    """
    if not isinstance(name, str) or not name:
        raise TypeError(f"source name must be a non-empty string, got {name!r}")
    if not dataclasses.is_dataclass(config_type):
        raise TypeError(f"config_type must be a dataclass, got {config_type!r}")
    module = getattr(factory, "__module__", "?")
    old = _REGISTRY.get(name)
    if old is not None and old.module != module:
        raise InputError(f"source {name!r} is already registered by {old.module}")
    _REGISTRY[name] = _Entry(config_type, factory, module)


def _load_builtins() -> None:
    for module in _BUILTIN_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:  # a built-in module not written yet
            if exc.name != module:
                raise


def source_names() -> list[str]:
    """Names of every registered sensor type, sorted."""
    _load_builtins()
    return sorted(_REGISTRY)


def _entry(name: str) -> _Entry:
    _load_builtins()
    if name not in _REGISTRY:
        raise InputError(f"unknown tactile source {name!r}; valid names: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def source_config(name: str, **overrides):
    """The validated config of sensor type ``name`` (defaults, with ``overrides`` applied).

    Raises
    ------
    ValueError
        For an unknown name or an unknown field (the message lists the valid ones).
    """
    entry = _entry(name)
    fields = {f.name for f in dataclasses.fields(entry.config_type)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise InputError(f"unknown config field(s) {unknown} for source {name!r}; valid: {sorted(fields)}")
    return entry.config_type(**overrides)


def make_source(name: str, config=None, **overrides) -> TactileSource:
    """Build the registered source ``name`` from ``config`` (or its defaults plus ``overrides``).

    Examples
    --------
    >>> from optitact.taxels.sources import make_source
    >>> make_source("nosuch")
    Traceback (most recent call last):
    ...
    optitact.errors.InputError: unknown tactile source 'nosuch'; valid names: ...
    """
    entry = _entry(name)
    if config is None:
        config = source_config(name, **overrides)
    elif overrides:
        config = dataclasses.replace(config, **overrides)
    if not isinstance(config, entry.config_type):
        raise TypeError(f"config for source {name!r} must be {entry.config_type.__name__}, "
                        f"got {type(config).__name__}")
    return entry.factory(config)


def moments(frames, layout: Layout) -> dict[str, np.ndarray]:
    r"""Integrated value, centroid and second moments of frames on a layout.

    The same quantities the dome pipeline reads per element (G and the
    centroid), for a whole taxel image: only cells in ``layout.mask`` count;
    sums accumulate in float64.

    Parameters
    ----------
    frames : (H, W) or (T, H, W) array
    layout : Layout

    Returns
    -------
    dict
        Table-shaped, one row per frame: ``frame``, ``total`` (sum of values),
        ``n_active`` (cells > 0), ``x_mm``, ``y_mm`` (value-weighted centroid,
        0 where the total is 0), ``sxx``, ``syy``, ``sxy`` (central second
        moments, mm²).

    Notes
    -----
    With weights :math:`w_i \ge 0` (negative values are clipped to 0):
    :math:`\bar x = \sum w_i x_i / \sum w_i` and
    :math:`s_{xx} = \sum w_i (x_i - \bar x)^2 / \sum w_i`.
    """
    arr = layout.check_frames(frames)
    w = np.where(layout.mask, np.clip(arr, 0, None), 0.0).reshape(arr.shape[0], -1)
    x, y = (c.ravel() for c in layout.cell_xy())
    total = w.sum(axis=1)
    safe = np.where(total > 0, total, 1.0)
    cx = np.where(total > 0, w @ x / safe, 0.0)
    cy = np.where(total > 0, w @ y / safe, 0.0)
    dx = x[None, :] - cx[:, None]
    dy = y[None, :] - cy[:, None]
    return {
        "frame": np.arange(arr.shape[0]),
        "total": total,
        "n_active": (w > 0).sum(axis=1),
        "x_mm": cx,
        "y_mm": cy,
        "sxx": np.where(total > 0, (w * dx * dx).sum(axis=1) / safe, 0.0),
        "syy": np.where(total > 0, (w * dy * dy).sum(axis=1) / safe, 0.0),
        "sxy": np.where(total > 0, (w * dx * dy).sum(axis=1) / safe, 0.0),
    }
