"""Indenter geometry: the height of an indenter's surface above its crest, for every shape.

Every taxel source turns a :class:`~optitact.taxels.sources.Indenter` pressed
``depth`` into the sensor into a local overlap ``u = max(0, depth - h)``,
where ``h(x, y)`` is how far the indenter's surface lies above its lowest
point (its crest). This module writes ``h`` once for every shape.

Convention: points and poses are in the layout frame (x along columns, y
along rows, mm, origin at the grid centre; :mod:`optitact.taxels.sources`); an
axis angle runs from +x towards +y.
"""

from __future__ import annotations

import math

import numpy as np

from optitact.errors import InputError
from optitact.taxels.sources import Indenter

__all__ = ["surface_height", "overlap"]

#: Shapes with a surface (a ``point`` indenter has none: it loads one spot).
SURFACE_SHAPES = ("sphere", "cylinder", "wire", "box", "flat")


def surface_height(indenter: Indenter, px, py, x_mm, y_mm, angle_rad=0.0, *,
                   curvature_per_mm=None) -> np.ndarray:
    r"""Height of ``indenter``'s surface above its crest at points ``(px, py)``, mm (inf: cannot touch).

    Parameters
    ----------
    indenter : Indenter
        Its ``shape`` (``sphere``, ``cylinder``, ``wire``, ``box`` or
        ``flat``), ``size_mm`` (radius; half width of a box's face) and
        ``length_mm`` (of a cylinder, wire or box along its axis).
    px, py : array
        Point coordinates, mm; broadcast together to the points' shape ``P``.
    x_mm, y_mm : float or (n,) array
        Crest position(s): the centre of a sphere, a point on the axis of a
        cylinder/wire/box (the middle of a finite one).
    angle_rad : float or (n,) array
        Axis direction of a cylinder/wire/box, from +x towards +y.
    curvature_per_mm : float or (n,) array, optional
        Curvature :math:`\kappa` of a bent cylinder/wire axis: in the axis
        frame (s along the axis, n to its left) the axis is
        :math:`n = \kappa s^2 / 2` through the crest. None: straight.

    Returns
    -------
    ndarray
        ``h`` of shape ``P`` for scalar poses, ``(n, *P)`` for pose arrays
        (float64): 0 at the crest, ``inf`` where the surface cannot touch
        (beyond the radius, off a box's face or beyond a finite length).

    Raises
    ------
    TypeError
        If ``indenter`` is not an Indenter.
    InputError
        For a ``point`` indenter (no surface).

    Notes
    -----
    With :math:`r` the distance from the centre (sphere) or from the axis
    (cylinder, wire) and :math:`R` the radius:
    :math:`h = R - \sqrt{R^2 - r^2}` for :math:`r < R`, :math:`\infty`
    beyond. A box is flat on its face of width :math:`2a`
    (:math:`h = 0` for :math:`r \le a`, :math:`\infty` beyond); ``flat`` is
    0 everywhere. Along the axis, points farther than half of a finite
    ``length_mm`` from the crest get :math:`\infty`.

    Examples
    --------
    >>> from optitact.taxels.sources import Indenter
    >>> surface_height(Indenter("sphere", 5.0), [0.0, 3.0, 6.0], 0.0, 0.0, 0.0).tolist()
    [0.0, 1.0, inf]
    """
    if not isinstance(indenter, Indenter):
        raise TypeError(f"indenter must be an Indenter, got {type(indenter).__name__}")
    shape = indenter.shape
    if shape not in SURFACE_SHAPES:
        raise InputError(f"indenter shape must be one of {SURFACE_SHAPES} to have a surface, got {shape!r}")
    px, py = np.broadcast_arrays(np.asarray(px, dtype=float), np.asarray(py, dtype=float))
    x0, y0, ang = (np.asarray(v, dtype=float) for v in (x_mm, y_mm, angle_rad))
    n_pose = np.broadcast_shapes(x0.shape, y0.shape, ang.shape)
    if len(n_pose) > 1:
        raise InputError(f"poses must be scalars or 1-D arrays, got shape {n_pose}")
    if shape == "flat":
        return np.zeros((*n_pose, *px.shape))
    tail = (slice(None),) + (None,) * px.ndim if n_pose else ()

    def pose(v):
        return np.broadcast_to(v, n_pose)[tail] if n_pose else v

    dx = px - pose(x0)
    dy = py - pose(y0)
    if shape == "sphere":
        r2 = dx * dx + dy * dy
        along = None
    else:
        c, s = np.cos(pose(ang)), np.sin(pose(ang))
        along = dx * c + dy * s
        normal = dy * c - dx * s
        if curvature_per_mm is not None:
            normal = normal - 0.5 * pose(np.asarray(curvature_per_mm, dtype=float)) * along * along
        r2 = normal ** 2
    rad = indenter.size_mm
    if shape == "box":
        h = np.where(r2 <= rad * rad, 0.0, np.inf)
    else:
        h = np.where(r2 < rad * rad, rad - np.sqrt(np.clip(rad * rad - r2, 0.0, None)), np.inf)
    if along is not None and math.isfinite(indenter.length_mm):
        h = np.where(np.abs(along) <= indenter.length_mm / 2, h, np.inf)
    return h


def overlap(depth_mm, height_mm) -> np.ndarray:
    """Local overlap ``max(0, depth - h)``, mm: how far the surface at ``h`` has entered (broadcast).

    Examples
    --------
    >>> overlap(0.5, [0.0, 0.2, float("inf")]).tolist()
    [0.5, 0.3, 0.0]
    """
    return np.clip(np.asarray(depth_mm, dtype=float) - np.asarray(height_mm, dtype=float), 0.0, None)
