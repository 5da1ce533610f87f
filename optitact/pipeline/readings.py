"""Per-element readings of a frame or a stack: integrated grey value, centroid shift, flags."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from optitact.errors import InputError, ShapeError

__all__ = ["Readings"]


@dataclass(frozen=True)
class Readings:
    """What the pipeline reads from one frame ``(E,)`` or a stack ``(T, E)``.

    Attributes
    ----------
    G : (E,) or (T, E) float64
        Integrated grey value of each element's region, grey level x mm^2
        measured on the dome surface; 0 where there is no contact.
    u : (E, 2) or (T, E, 2) float64
        Shift of the grey-value centroid from the element centre (mm), in the
        element-local tangent coordinates x, y (geodesic normal coordinates,
        the inverse of :meth:`DomeSensor.dome_point`); ``(0, 0)`` where there
        is no contact.
    contact : (E,) or (T, E) bool
        The region's G is above its noise floor.
    saturated : (E,) or (T, E) bool
        A pixel feeding the region is at the saturation level, so G
        underestimates the light.

    Examples
    --------
    >>> r = Readings.empty(41)
    >>> r.G.shape, r.u.shape, len(r.as_dict()["element"])
    ((41,), (41, 2), 41)
    """

    G: np.ndarray
    u: np.ndarray
    contact: np.ndarray
    saturated: np.ndarray

    def __post_init__(self) -> None:
        g = np.asarray(self.G)
        if g.ndim not in (1, 2):
            raise ShapeError(f"G must have shape (E,) or (T, E), got {g.shape}")
        for name, tail in (("u", (2,)), ("contact", ()), ("saturated", ())):
            arr = np.asarray(getattr(self, name))
            if arr.shape != g.shape + tail:
                raise ShapeError(f"{name} must have shape {g.shape + tail}, got {arr.shape}")

    @classmethod
    def empty(cls, n_elements: int, n_frames: int | None = None) -> Readings:
        """Readings of no contact anywhere, for one frame or ``n_frames``."""
        lead = (n_elements,) if n_frames is None else (n_frames, n_elements)
        return cls(np.zeros(lead), np.zeros(lead + (2,)), np.zeros(lead, bool),
                   np.zeros(lead, bool))

    @property
    def is_stack(self) -> bool:
        """True for readings of a stack ``(T, E)``."""
        return self.G.ndim == 2

    @property
    def n_elements(self) -> int:
        """Number of elements E."""
        return self.G.shape[-1]

    @property
    def element(self) -> np.ndarray:
        """Element indices ``0..E-1``."""
        return np.arange(self.n_elements)

    def __len__(self) -> int:
        """Number of frames of a stack (a single frame's readings have no length)."""
        if not self.is_stack:
            raise TypeError("readings of a single frame have no length; use .G.shape")
        return self.G.shape[0]

    def __getitem__(self, t) -> Readings:
        """Frame ``t`` (or a slice of frames) of stack readings."""
        if not self.is_stack:
            raise TypeError("readings of a single frame cannot be indexed by frame")
        return Readings(self.G[t], self.u[t], self.contact[t], self.saturated[t])

    @classmethod
    def stack(cls, items) -> Readings:
        """Stack single-frame (or stack) readings along a new (or the frame) axis."""
        items = list(items)
        if not items:
            raise InputError("cannot stack an empty list of readings")
        stacks = [r.as_stack() for r in items]
        return cls(*(np.concatenate([getattr(r, f) for r in stacks])
                     for f in ("G", "u", "contact", "saturated")))

    def as_stack(self) -> Readings:
        """These readings as a stack ``(T, E)``: a single frame's as a stack of one (views), a stack itself.

        Examples
        --------
        >>> r = Readings.empty(41)
        >>> r.as_stack().G.shape, len(r.as_stack()), r.as_stack().as_stack().G.shape
        ((1, 41), 1, (1, 41))
        """
        if self.is_stack:
            return self
        return Readings(self.G[None], self.u[None], self.contact[None], self.saturated[None])

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped columns, one row per element (and frame).

        Keys: ``frame`` (stacks only), ``element``, ``G``, ``ux``, ``uy``,
        ``contact``, ``saturated``; so ``pandas.DataFrame(r.as_dict())``
        is the readings table.
        """
        out: dict[str, np.ndarray] = {}
        if self.is_stack:
            t, e = self.G.shape
            out["frame"] = np.repeat(np.arange(t), e)
            out["element"] = np.tile(np.arange(e), t)
        else:
            out["element"] = self.element
        out["G"] = self.G.reshape(-1)
        out["ux"] = self.u[..., 0].reshape(-1)
        out["uy"] = self.u[..., 1].reshape(-1)
        out["contact"] = self.contact.reshape(-1)
        out["saturated"] = self.saturated.reshape(-1)
        return out
