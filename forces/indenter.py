r"""Objects pressed into the dome: rigid indenter shapes, their pose, and the element forces they make.

:func:`press` puts a rigid object (an *indenter*) on the dome, pushes it in by a
depth or until it carries a force, optionally slides it, and returns the
element-local forces of the 41 elements as an :class:`Indentation`;
:func:`press_points` does the same on any set of feeler tips (a flat array,
another sensor). The shapes are :class:`Sphere`, :class:`Flat` (a flat
cylindrical punch), :class:`Edge` (a rounded knife edge), :class:`Cylinder`
(lying) and :class:`SDF` (any signed distance function); :class:`Pose` places
one, :class:`ContactModel` holds the rubber's contact law, and
:func:`parse_spec` reads the text form of the command line
(``optitact render --indenter sphere:radius=5 ...``).

Convention
----------
Lengths in mm, forces in N, moduli in MPa (N/mm^2), angles in degrees.

- **Indenter frame.** Every shape is given in its own frame with its contact
  face or tip at the origin; the solid lies on the ``+z`` side and the
  indenter presses along its own ``-z`` axis. ``signed_distance`` is negative
  inside the solid, its gradient (:meth:`Shape.normal`) the outward normal.
- **Pose.** A point ``q`` of the indenter frame is at ``position + rotation @ q``
  in the sensor frame of :mod:`optitact.optics.sensor` (origin at the dome
  centre, ``z`` up through the apex). The pressing direction is
  ``-rotation[:, 2]``; ``depth`` moves the indenter that far along it.
- **Forces.** Element-local ``(Fx, Fy, Fz)`` as everywhere in optitact
  (:mod:`optitact.optics.force_frames`): ``z`` the element's outward normal,
  ``Fz > 0`` when the element is pressed onto the dome. Global forces are the
  forces the object exerts on the elements, in the sensor frame.

Notes
-----
**Contact points.** Each element's columnar feeler is a point probe whose tip
stands at ``x_i = (R + h) e_i`` (``R`` the dome's outer radius, ``h`` the
feeler height, ``e_i`` the element's outward normal), as in
:func:`optitact.finger.scene.feeler_forces`. An object pushed further than
the feelers stand out also meets the rubber *skin* between them (the sheet the
feelers stand on, on the outer dome surface, radius ``R``): with ``skin`` on,
the skin over the elements' tributary region is sampled by points ``y_s``
(a Fibonacci lattice, ``skin_spacing`` apart, area ``a_s`` each), and a load
on skin point ``s`` is carried by the elements around it with the weights
``omega_si`` of a smooth partition of unity (Wendland's compactly supported
kernel of the distance to each element centre, support ``1.5`` times the
largest distance from a skin point to its nearest element; the weights sum to
one). A feeler tip belongs to its own element alone (``omega = 1``).

**Normal problem.** With the indenter at depth ``d``, ``g_a`` is the signed
distance of contact point ``a`` to the solid (the *gap*, negative inside) and
``n_a`` the solid's outward normal there. Contact is frictionless in the
normal problem: point ``a`` carries the force ``p_a n_a`` with ``p_a >= 0``.
Element ``i`` is an elastic support: its feeler moves by ``F_i / k`` under
the force ``F_i = sum_a omega_ai p_a n_a`` (a spring of stiffness ``k`` in
every direction, so that one tip alone gets ``p = k max(-g, 0)``, the penalty
law of :func:`optitact.finger.scene.feeler_forces`), and a skin point gives way
locally as a Winkler layer of modulus ``E* / t`` (``t`` = ``skin_thickness``,
``E* = E / (1 - nu^2)``). The points move, ``g`` becomes ``g + A p``, and the
contact forces solve the linear complementarity problem

.. math::

    p \ge 0, \qquad g + A p \ge 0, \qquad p^T (g + A p) = 0 ,

with the symmetric positive definite compliance matrix

.. math::

    A_{ab} = \frac{n_a \cdot n_b}{k} \sum_i \omega_{ai} \omega_{bi}
           + \frac{\delta_{ab} \, [a \text{ on the skin}]}{a_s E^* / t}
           + \sum_{ij} C_{ai} \, w_{ij} \, C_{bj}, \qquad
    C_{ai} = \omega_{ai} \max(-n_a \cdot e_i, 0) .

The last term is the optional elastic ``coupling`` of the elements through
the rubber: the compressive load ``sum_a C_ai p_a`` on element ``i`` sinks
element ``j`` by Boussinesq's point load on an elastic half-space,

.. math::

    w_{ij} = \frac{1 - \nu^2}{\pi E \, |x_i - x_j|} \quad (i \ne j), \qquad
    w_{ii} = \frac{2 (1 - \nu^2)}{\pi E \, a_i}, \quad a_i = \sqrt{A_i / \pi} ,

the self term being the centre displacement of a uniform pressure on a disc
of the element's tributary area ``A_i``. With tips alone and no coupling
``A`` is diagonal, ``p_a = k max(-g_a, 0)``: independent springs (a Winkler
foundation), computed in closed form. Otherwise the problem, the
minimisation of ``p^T A p / 2 + g^T p`` over ``p >= 0``, is solved exactly by
an active set method (Cholesky solves on the contact set, dropping points
that pull, adding points that still penetrate; warm-started from the last
depth's contact set), falling back to non-negative least squares
(``scipy.optimize.nnls`` on the Cholesky factor) should it cycle. The problem
starts with the feeler tips inside the object; then every other tip and skin
point that the elements' displacements carry into the object joins it, until
none is left: the result is the complementarity solution over all points.

**Pressing force.** ``F(d) = sum_a p_a n_a . u`` with ``u`` the pressing
direction: the load the indenter is pressed with. Asked for a force, the
depth is found on the rising branch of ``F``: steps from depth 0 (0.01 mm,
growing to 0.25 mm) until ``F`` reaches it, then Brent's method
(``scipy.optimize.brentq``) within the last step; the force is met to 1e-9
relative. An object that sinks past the feelers before carrying the force,
or a force that jumps past the target (contact points crossing the object's
middle, where the nearest surface and its normal change), is an
:class:`~optitact.errors.InputError` rather than a wrong depth. The model
holds while the penetrations stay below the object's own size (its radius,
its tip radius).

**Friction.** After pressing, the indenter may slide by a small vector ``s``.
Each contact point is dragged along the part of ``s`` in its contact's
tangent plane, ``s_a = s - (s . n_a) n_a``. Element ``i`` resists with a
tangential spring ``k_t`` up to Coulomb's limit on its normal load
``N_i = sum_a omega_ai p_a``; each point loading it contributes in proportion
to its share ``beta_ai = omega_ai p_a / N_i`` of that load:

.. math::

    \tau_{ai} = k_t s_a \ \text{if} \ k_t |s_a| \le \mu N_i
    \ \text{(stick)}, \qquad
    \tau_{ai} = \mu N_i \, s_a / |s_a| \ \text{otherwise (slip)}, \qquad
    T_i = \sum_a \beta_{ai} \tau_{ai} .

A feeler tip alone thus gets ``k_t s_a`` while it sticks and ``mu p_a`` along
``s_a`` when it slips, and the result does not depend on how finely the skin
is sampled. The normal forces are those of the pressed pose (the slide is
small against the object's curvature). Element ``i`` gets
``F_i = sum_a omega_ai p_a n_a + T_i``; it *slips* when it slips on every
contact point that loads it.
"""

from __future__ import annotations

import abc
import functools
import math
import numbers
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize
from scipy.spatial import distance

from optitact._validate import finite, positive, real_array, real_number
from optitact.errors import InputError, KindError, ShapeError
from optitact.optics.force_frames import local_from_global
from optitact.optics.sensor import DomeSensor

__all__ = ["Shape", "Sphere", "Flat", "Edge", "Cylinder", "SDF", "Pose", "ContactModel", "Indentation",
           "press", "press_points", "parse_spec", "SPEC_GRAMMAR"]

#: The text form of an indenter (:func:`parse_spec`, ``optitact render --indenter``); lengths mm, angles deg.
SPEC_GRAMMAR = ("sphere:radius=R | flat:radius=R | edge:length=L,tip_radius=r[,angle=DEG] | "
                "cylinder:radius=R,length=L, each optionally with ,spin=DEG")


def _freeze(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


def _points(points, name: str = "points") -> np.ndarray:
    """``points`` as a finite float64 (n, 3) array."""
    arr = finite(real_array(points, name), name)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ShapeError(f"{name} must have shape (n, 3) (one x, y, z row per point, mm), got {arr.shape}")
    return arr


def _unit(v: np.ndarray, fallback) -> np.ndarray:
    """Rows of ``v`` normalised; ``fallback`` where a row is zero."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = norm > 0
    return np.where(ok, v / np.where(ok, norm, 1.0), np.broadcast_to(np.asarray(fallback, float), v.shape))


def _fmt(value: float) -> str:
    return format(value, ".12g")


# ----------------------------------------------------------------------------------------------- shapes
class Shape(abc.ABC):
    """A rigid indenter solid in its own frame: contact face or tip at the origin, pressing along ``-z``.

    Subclasses give :meth:`signed_distance` (mm, negative inside) and
    :meth:`normal` (the unit outward normal, the distance's gradient) for
    points in the indenter frame; :func:`press` evaluates them at the feeler
    tips. The solid lies on the ``+z`` side of its frame: its lowest point (or
    face) is at ``z = 0``, over the origin.
    """

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance (mm) of points to the surface: negative inside, positive outside.

        Parameters
        ----------
        points : (n, 3) array_like
            Points in the indenter frame (mm), finite.

        Returns
        -------
        (n,) ndarray
            The signed distances (mm).

        Raises
        ------
        TypeError
            ``points`` is not a real numeric array.
        ShapeError
            ``points`` is not (n, 3).
        InputError
            ``points`` holds NaN or infinity.
        """
        return self._evaluate(_points(points))[0]

    def normal(self, points) -> np.ndarray:
        """Unit outward normals (the gradient of the signed distance) at points, shape (n, 3).

        Parameters
        ----------
        points : (n, 3) array_like
            Points in the indenter frame (mm), finite.

        Returns
        -------
        (n, 3) ndarray
            Unit vectors in the indenter frame; inside the solid they point
            to the nearest part of the surface and out.

        Raises
        ------
        TypeError, ShapeError, InputError
            As :meth:`signed_distance`.
        """
        return self._evaluate(_points(points))[1]

    @abc.abstractmethod
    def _evaluate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (n,) and unit outward normals (n, 3) of checked points (n, 3)."""


def _extrude(a: np.ndarray, ga: np.ndarray, b: np.ndarray, gb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance and normal of the intersection of two solids ``a <= 0`` and ``b <= 0``.

    ``a`` and ``b`` are exact signed distances with unit gradients ``ga``,
    ``gb`` perpendicular to each other (a profile and its extrusion), so the
    result is exact: ``min(max(a, b), 0) + |(max(a, 0), max(b, 0))|``.
    """
    ap, bp = np.maximum(a, 0.0), np.maximum(b, 0.0)
    out = np.hypot(ap, bp)
    d = np.minimum(np.maximum(a, b), 0.0) + out
    n_out = ap[:, None] * ga + bp[:, None] * gb
    n_in = np.where((a >= b)[:, None], ga, gb)
    outside = out > 0
    n = np.where(outside[:, None], n_out / np.where(outside, out, 1.0)[:, None], n_in)
    return d, n


@dataclass(frozen=True)
class Sphere(Shape):
    """A rigid sphere (a ball indenter) touching the origin from above.

    Parameters
    ----------
    radius : float
        Radius (mm), finite and > 0.

    Notes
    -----
    Centre at ``(0, 0, radius)`` in the indenter frame;
    ``signed_distance(q) = |q - c| - radius``, normal ``(q - c) / |q - c|``.

    Examples
    --------
    >>> Sphere(5.0).signed_distance([[0.0, 0.0, -1.0], [0.0, 0.0, 5.0]])
    array([ 1., -5.])
    """

    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", positive(self.radius, "Sphere radius (mm)"))

    @property
    def spec(self) -> str:
        """The text form (:func:`parse_spec`), e.g. ``"sphere:radius=5"``."""
        return f"sphere:radius={_fmt(self.radius)}"

    def _evaluate(self, q):
        v = q - np.array([0.0, 0.0, self.radius])
        return np.linalg.norm(v, axis=1) - self.radius, _unit(v, (0.0, 0.0, -1.0))


@dataclass(frozen=True)
class Flat(Shape):
    r"""A flat cylindrical punch: a circular face of ``radius`` at ``z = 0``, the body above it.

    Parameters
    ----------
    radius : float
        Radius of the face (mm), finite and > 0; its rim is a sharp edge.

    Notes
    -----
    The solid ``sqrt(x^2 + y^2) <= radius, z >= 0`` (semi-infinite upwards);
    the face's outward normal is ``-z``, the pressing direction. Outside, the
    signed distance is exact (:math:`|(a^+, b^+)|` with
    ``a = sqrt(x^2 + y^2) - radius`` and ``b = -z``); inside, it is the depth
    below the face, ``-z``, with the normal ``-z``: pressed along its axis,
    the punch takes every feeler in through its face, and the face stays that
    feeler's contact however deep (the exact distance would hand a feeler
    near the rim over to the side wall). A large radius is a flat plate (a
    table top).

    Examples
    --------
    >>> Flat(3.0).signed_distance([[0.0, 0.0, -0.5], [0.0, 0.0, 0.25], [4.0, 0.0, 1.0]])
    array([ 0.5 , -0.25,  1.  ])
    """

    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", positive(self.radius, "Flat radius (mm)"))

    @property
    def spec(self) -> str:
        """The text form (:func:`parse_spec`), e.g. ``"flat:radius=3"``."""
        return f"flat:radius={_fmt(self.radius)}"

    def _evaluate(self, q):
        rho_v = np.concatenate([q[:, :2], np.zeros((len(q), 1))], axis=1)
        a = np.hypot(q[:, 0], q[:, 1]) - self.radius
        ga = _unit(rho_v, (1.0, 0.0, 0.0))
        gb = np.broadcast_to(np.array([0.0, 0.0, -1.0]), q.shape)
        d, n = _extrude(a, ga, -q[:, 2], gb)
        inside = d < 0
        return np.where(inside, -q[:, 2], d), np.where(inside[:, None], gb, n)


def _length_along_x(q: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """The end caps at ``|x| = length / 2``: their signed distance and normal (+-x)."""
    sx = np.where(q[:, 0] >= 0, 1.0, -1.0)
    g = np.zeros_like(q)
    g[:, 0] = sx
    return np.abs(q[:, 0]) - length / 2.0, g


@dataclass(frozen=True)
class Cylinder(Shape):
    """A cylinder lying along the indenter's ``x`` axis, touching the origin with its lowest line.

    Parameters
    ----------
    radius : float
        Radius (mm), finite and > 0.
    length : float
        Length along ``x`` (mm), finite and > 0; flat ends at ``x = +-length / 2``.

    Notes
    -----
    Axis on the line ``y = 0, z = radius``; exact signed distance of the
    capped cylinder (the circular profile in ``y, z`` extruded along ``x``).

    Examples
    --------
    >>> Cylinder(2.0, 10.0).signed_distance([[0.0, 0.0, -1.0], [9.0, 0.0, 2.0]])
    array([1., 4.])
    """

    radius: float
    length: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", positive(self.radius, "Cylinder radius (mm)"))
        object.__setattr__(self, "length", positive(self.length, "Cylinder length (mm)"))

    @property
    def spec(self) -> str:
        """The text form (:func:`parse_spec`), e.g. ``"cylinder:radius=2,length=10"``."""
        return f"cylinder:radius={_fmt(self.radius)},length={_fmt(self.length)}"

    def _evaluate(self, q):
        v = np.stack([np.zeros(len(q)), q[:, 1], q[:, 2] - self.radius], axis=1)
        a = np.linalg.norm(v, axis=1) - self.radius
        b, gb = _length_along_x(q, self.length)
        return _extrude(a, _unit(v, (0.0, 0.0, -1.0)), b, gb)


@dataclass(frozen=True)
class Edge(Shape):
    """A straight knife edge along the indenter's ``x`` axis: a wedge with a rounded tip.

    Parameters
    ----------
    length : float
        Length of the edge along ``x`` (mm), finite and > 0; flat ends at
        ``x = +-length / 2``.
    tip_radius : float
        Radius of the rounded tip (mm), finite and > 0.
    angle : float
        Included angle of the wedge (deg), in (0, 180), default 60; its flanks
        are tangent to the tip's circle.

    Notes
    -----
    In the ``y, z`` profile the tip's circle has its centre at
    ``(0, tip_radius)`` and touches the origin; the flanks rise from it at
    ``angle / 2`` on each side of ``+z``. The profile is the Minkowski sum of a
    sharp wedge (apex at the circle's centre) and the disc, so its signed
    distance is the wedge's minus ``tip_radius``, exact; the profile is
    extruded along ``x`` over ``length``.

    Examples
    --------
    >>> e = Edge(10.0, 0.5, angle=90.0)
    >>> e.signed_distance([[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]])
    array([ 0.5, -0.5])
    """

    length: float
    tip_radius: float
    angle: float = 60.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "length", positive(self.length, "Edge length (mm)"))
        object.__setattr__(self, "tip_radius", positive(self.tip_radius, "Edge tip_radius (mm)"))
        angle = positive(self.angle, "Edge angle (deg)")
        if not angle < 180.0:
            raise InputError(f"Edge angle (deg) must be in (0, 180) (the wedge's included angle), "
                             f"got {angle!r}")
        object.__setattr__(self, "angle", angle)

    @property
    def spec(self) -> str:
        """The text form (:func:`parse_spec`), e.g. ``"edge:length=10,tip_radius=0.5,angle=60"``."""
        return f"edge:length={_fmt(self.length)},tip_radius={_fmt(self.tip_radius)},angle={_fmt(self.angle)}"

    def _evaluate(self, q):
        beta = math.radians(self.angle) / 2.0
        sy = np.where(q[:, 1] >= 0, 1.0, -1.0)
        u, w = np.abs(q[:, 1]), q[:, 2] - self.tip_radius       # folded profile, apex at the origin
        t = u * math.sin(beta) + w * math.cos(beta)               # along the flank
        below = t < 0                                             # nearest to the apex
        r = np.hypot(u, w)
        flank = u * math.cos(beta) - w * math.sin(beta)
        a = np.where(below, r, flank) - self.tip_radius
        apex_n = np.stack([sy * u, w], axis=1) / np.where(r > 0, r, 1.0)[:, None]
        apex_n[r == 0] = (0.0, -1.0)
        flank_n = np.stack([sy * math.cos(beta), np.full(len(q), -math.sin(beta))], axis=1)
        n2 = np.where(below[:, None], apex_n, flank_n)
        ga = np.concatenate([np.zeros((len(q), 1)), n2], axis=1)
        b, gb = _length_along_x(q, self.length)
        return _extrude(a, ga, b, gb)


@dataclass(frozen=True, eq=False)
class SDF(Shape):
    """Any indenter shape given as a signed distance function.

    Parameters
    ----------
    function : callable
        ``function(points) -> distances``: points (n, 3) in the indenter frame
        (mm), returns (n,) signed distances (mm; negative inside). Follow the
        indenter frame's convention: the solid's lowest point over the origin,
        the body on the ``+z`` side.
    step : float
        Step of the central differences that give the normals (mm), default 1e-4.

    Raises
    ------
    TypeError
        ``function`` is not callable.
    InputError
        ``step`` is not finite and > 0.

    Notes
    -----
    The normal is the normalised gradient by central differences,
    ``(f(q + h e_k) - f(q - h e_k)) / (2 h)`` for ``k = x, y, z``, all seven
    evaluations in one call of ``function`` (7 n points). A result of the wrong
    shape or kind, or a non-finite one, is an error naming the function.

    Examples
    --------
    >>> ball = SDF(lambda q: np.linalg.norm(q - (0.0, 0.0, 5.0), axis=1) - 5.0)
    >>> ball.signed_distance([[0.0, 0.0, -1.0]])
    array([1.])
    """

    function: Callable
    step: float = 1e-4

    def __post_init__(self) -> None:
        if not callable(self.function):
            raise TypeError(f"SDF function must be callable, points (n, 3) -> signed distances (n,); got "
                            f"{type(self.function).__name__}")
        object.__setattr__(self, "step", positive(self.step, "SDF step (mm)"))

    def _call(self, q: np.ndarray) -> np.ndarray:
        name = getattr(self.function, "__name__", type(self.function).__name__)
        out = self.function(q.copy())
        try:
            arr = np.asarray(out)
        except ValueError as exc:
            raise KindError(f"SDF function {name} must return a real array of shape ({len(q)},), "
                            f"got {type(out).__name__} ({exc})") from None
        if arr.dtype.kind not in "iuf":
            raise KindError(f"SDF function {name} must return real numbers, got dtype {arr.dtype}")
        if arr.shape != (len(q),):
            raise ShapeError(f"SDF function {name} must return one signed distance per point, shape "
                             f"({len(q)},), for points of shape {q.shape}; got {arr.shape}")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise InputError(f"SDF function {name} returned {arr[bad]} for the point {q[bad].tolist()}; "
                             f"signed distances must be finite")
        return arr

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance (mm) of points to the surface: ``function(points)``, checked.

        Parameters
        ----------
        points : (n, 3) array_like
            Points in the indenter frame (mm), finite.

        Returns
        -------
        (n,) ndarray
            The signed distances (mm).

        Raises
        ------
        TypeError, ShapeError, InputError
            As :meth:`Shape.signed_distance`; also for a result of the wrong
            kind or shape, or one that is not finite.
        """
        return self._call(_points(points))

    def _evaluate(self, q):
        n, h = len(q), self.step
        steps = np.concatenate([np.zeros((1, 3)), h * np.eye(3), -h * np.eye(3)])   # (7, 3)
        d = self._call((q[None, :, :] + steps[:, None, :]).reshape(-1, 3)).reshape(7, n)
        grad = (d[1:4] - d[4:7]).T / (2.0 * h)
        norm = np.linalg.norm(grad, axis=1)
        if np.any(norm == 0):
            bad = int(np.flatnonzero(norm == 0)[0])
            raise InputError(f"the SDF's gradient is zero at {q[bad].tolist()} (step {h:g} mm): "
                             f"no normal there")
        return d[0], grad / norm[:, None]


# ------------------------------------------------------------------------------------------------- pose
def _rotation_from_vector(v: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: the rotation by ``|v|`` rad about ``v``."""
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


@dataclass(frozen=True, eq=False)
class Pose:
    """Where an indenter is: its frame's origin and axes in the sensor frame.

    Parameters
    ----------
    position : (3,) array_like
        The indenter frame's origin (its tip) in the sensor frame (mm).
    rotation : (3, 3) or (3,) array_like, optional
        The indenter frame's axes as the columns of a rotation matrix
        (orthonormal, determinant +1, to 1e-6), or a rotation vector (axis
        times angle in rad); default the identity (pressing along ``-z``, down
        onto the apex). Stored as a read-only (3, 3) matrix, re-orthonormalised.

    Raises
    ------
    TypeError
        Not real numeric arrays.
    ShapeError
        ``position`` is not (3,), ``rotation`` neither (3, 3) nor (3,).
    InputError
        NaN or infinity, or a matrix that is not a rotation.

    Notes
    -----
    A point ``q`` of the indenter frame is at ``position + rotation @ q``; the
    pressing direction is ``-rotation[:, 2]``. :meth:`touching` places an
    indenter on the dome.

    Examples
    --------
    >>> p = Pose.touching(DomeSensor.default(), 0.0, 0.0)
    >>> p.position, p.press_direction
    (array([ 0.,  0., 21.]), array([-0., -0., -1.]))
    """

    position: np.ndarray
    rotation: np.ndarray | None = None

    def __post_init__(self) -> None:
        pos = finite(real_array(self.position, "Pose position"), "Pose position")
        if pos.shape != (3,):
            raise ShapeError(f"Pose position must have shape (3,) (x, y, z in mm, sensor frame), "
                             f"got {pos.shape}")
        if self.rotation is None:
            rot = np.eye(3)
        else:
            rot = finite(real_array(self.rotation, "Pose rotation"), "Pose rotation")
            if rot.shape == (3,):
                rot = _rotation_from_vector(rot)
            elif rot.shape == (3, 3):
                err = float(np.abs(rot.T @ rot - np.eye(3)).max())
                if err > 1e-6 or np.linalg.det(rot) <= 0:
                    raise InputError(f"Pose rotation must be a rotation matrix (orthonormal to 1e-6, "
                                     f"determinant +1), got one with |R^T R - I| = {err:.3g} and determinant "
                                     f"{np.linalg.det(rot):.6g}")
                u, _, vt = np.linalg.svd(rot)
                rot = u @ vt
            else:
                raise ShapeError(f"Pose rotation must be a (3, 3) rotation matrix or a (3,) rotation vector, "
                                 f"got shape {rot.shape}")
        object.__setattr__(self, "position", _freeze(np.array(pos, dtype=np.float64)))
        object.__setattr__(self, "rotation", _freeze(np.array(rot, dtype=np.float64)))

    def __repr__(self) -> str:
        p = ", ".join(f"{v:.4g}" for v in self.position)
        u = ", ".join(f"{v:.4g}" for v in self.press_direction)
        return f"Pose(position=({p}) mm, press_direction=({u}))"

    @classmethod
    def touching(cls, sensor: DomeSensor, polar_deg: float, azimuth_deg: float, *, spin_deg: float = 0.0,
                 feeler_height: float = 1.0) -> Pose:
        """The pose of an indenter whose tip touches the feeler tips' sphere, pressing towards the centre.

        Parameters
        ----------
        sensor : DomeSensor
        polar_deg : float
            Polar angle of the touching point from the dome axis (deg), in [0, 90).
        azimuth_deg : float
            Its azimuth, counter-clockwise from ``+x`` (deg).
        spin_deg : float
            Rotation of the indenter about its pressing axis (deg), default 0:
            counter-clockwise seen from outside the dome.
        feeler_height : float
            Height of the feelers above the dome (mm), default 1 (as
            :class:`ContactModel`'s default); the tip is at ``R + feeler_height``.

        Returns
        -------
        Pose
            Origin at ``(R + h) u`` with ``u`` the outward unit vector at
            ``(polar_deg, azimuth_deg)``; the indenter's ``z`` axis is ``u``
            (it presses along ``-u``, onto the dome centre) and, at zero spin,
            its ``x`` axis is the global ``x`` projected onto the tangent plane
            (as the element frames of :class:`~optitact.optics.sensor.DomeSensor`;
            the global ``y`` where that vanishes).

        Raises
        ------
        TypeError
            ``sensor`` is not a DomeSensor or an angle not a real number.
        InputError
            ``polar_deg`` outside [0, 90) or an angle that is not finite.
        """
        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        polar = real_number(polar_deg, "polar_deg")
        if not 0.0 <= polar < 90.0:
            raise InputError(f"polar_deg must be in [0, 90) (on the dome), got {polar_deg!r}")
        az = math.radians(real_number(azimuth_deg, "azimuth_deg"))
        spin = math.radians(real_number(spin_deg, "spin_deg"))
        h = positive(feeler_height, "feeler_height", allow_zero=True)
        th = math.radians(polar)
        u = np.array([math.sin(th) * math.cos(az), math.sin(th) * math.sin(az), math.cos(th)])
        x = np.array([1.0, 0.0, 0.0]) - u[0] * u
        if np.linalg.norm(x) < 1e-9:
            x = np.array([0.0, 1.0, 0.0]) - u[1] * u
        x /= np.linalg.norm(x)
        y = np.cross(u, x)
        xs = math.cos(spin) * x + math.sin(spin) * y
        ys = np.cross(u, xs)
        return cls((sensor.outer_radius + h) * u, np.stack([xs, ys, u], axis=1))

    @property
    def press_direction(self) -> np.ndarray:
        """The unit pressing direction in the sensor frame, ``-rotation[:, 2]``, shape (3,)."""
        return -self.rotation[:, 2]

    def moved(self, depth: float) -> Pose:
        """The same pose pushed ``depth`` mm along :attr:`press_direction` (negative: backed off)."""
        d = real_number(depth, "depth")
        return Pose(self.position + d * self.press_direction, self.rotation)

    def to_local(self, points) -> np.ndarray:
        """Sensor-frame points (n, 3) in the indenter frame: ``rotation^T (p - position)``."""
        return (_points(points) - self.position) @ self.rotation


# ---------------------------------------------------------------------------------------- contact model
def _stiffness(value, name: str, *, allow_inf: bool) -> float:
    """A stiffness: finite and > 0, or ``inf`` where allowed."""
    if allow_inf and isinstance(value, numbers.Real) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    return positive(value, name)


@dataclass(frozen=True)
class ContactModel:
    """The contact law of the rubber feelers and skin.

    Parameters
    ----------
    stiffness : float
        Contact stiffness of one element's feeler (N/mm), default 2, finite
        and > 0; ``math.inf`` (rigid feelers) only with ``coupling``, where
        the rubber alone gives way. (:func:`optitact.finger.scene.feeler_forces`
        uses 0.5 by default.)
    tangential_stiffness : float, optional
        Tangential (sticking) stiffness of one feeler (N/mm), > 0 (``math.inf``
        allowed: every slide slips); default ``mindlin_ratio * stiffness``.
    coupling : bool
        Couple the elements through the rubber (Boussinesq half-space
        influence between feeler tips), default False: independent springs.
    skin : bool
        Let the object meet the rubber skin between the feelers, default True
        (:func:`press` only; :func:`press_points` has tips alone). False: the
        feeler tips alone, as :func:`optitact.finger.scene.feeler_forces`.
    youngs_modulus : float
        Young's modulus ``E`` of the rubber (MPa), default 1.
    poisson_ratio : float
        Poisson ratio ``nu`` of the rubber, in [0, 0.5), default 0.49.
    feeler_height : float
        How far the columnar feelers stand out of the skin (mm), default 1, >= 0.
    skin_thickness : float
        Thickness ``t`` of the skin's rubber layer (mm), default 1: its local
        Winkler modulus is ``E* / t``.
    skin_spacing : float
        Spacing of the points that sample the skin (mm), default 0.4, from
        0.05 to 5.

    Raises
    ------
    TypeError
        A parameter of the wrong kind (``coupling`` and ``skin`` must be bools).
    InputError
        A value out of range.

    Notes
    -----
    The rubber's defaults are those of :class:`~optitact.optics.sensor.DomeSensor`
    (``E = 1 MPa``, ``nu = 0.49``), the feeler height that of
    :func:`optitact.finger.scene.feeler_forces` (``h = 1 mm``).
    ``E`` of the order of 1 MPa and ``nu`` close to 0.5 are those of silicone
    rubbers (nearly incompressible elastomers): for example Johnston et al.,
    "Mechanical characterization of bulk Sylgard 184 for microfluidics and
    microengineering", J. Micromech. Microeng. 24, 035017 (2014), measured
    1.3 to 3 MPa for Sylgard 184, depending on its curing.

    The feeler stiffness has its basis in the element's own contact law
    (:func:`optitact.optics.contact.cone_loads`): the feeler stands on ``K = 8``
    conical feelers, each obeying Sneddon's cone,
    ``P = (2/pi) E* tan(alpha) d^2`` with ``E* = E / (1 - nu^2)`` and semi-apex
    angle ``alpha = 45 deg``: the element carries ``F = C d^2`` with
    ``C = 8 (2/pi) E* tan(alpha) = 6.70 N/mm^2`` at a flattening ``d``, up to
    3.35 N at ``d = 0.71 mm`` (:attr:`DomeSensor.max_cone_load
    <optitact.optics.sensor.DomeSensor.max_cone_load>` per cone). The default
    linear spring is the secant of that law at 0.6 N, the middle of the
    loads the calibration sets use: ``k = sqrt(C F) = 2.0 N/mm``
    (``d = 0.30 mm``); it is stiffer than the law below that load and softer
    above. The
    tangential stiffness follows Mindlin's ratio for an elastic contact,
    ``k_t / k_n = 2 (1 - nu) / (2 - nu)`` (0.675 at ``nu = 0.49``). The skin's
    Winkler modulus ``E* / t`` is that of a thin elastic layer of thickness
    ``t`` on a rigid base; the skin's thickness is not a sensor parameter, and
    1 mm is of the order of the feeler height. It only matters once an object
    reaches the skin; the elements' springs then carry the load.

    Examples
    --------
    >>> m = ContactModel()
    >>> round(m.mindlin_ratio, 4), round(m.tangential, 4)
    (0.6755, 1.351)
    """

    stiffness: float = 2.0
    tangential_stiffness: float | None = None
    coupling: bool = False
    skin: bool = True
    youngs_modulus: float = 1.0
    poisson_ratio: float = 0.49
    feeler_height: float = 1.0
    skin_thickness: float = 1.0
    skin_spacing: float = 0.4

    def __post_init__(self) -> None:
        for name in ("coupling", "skin"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"ContactModel {name} must be a bool, got {type(value).__name__}")
            object.__setattr__(self, name, bool(value))
        k = _stiffness(self.stiffness, "ContactModel stiffness (N/mm)", allow_inf=True)
        if math.isinf(k) and not self.coupling:
            raise InputError("ContactModel stiffness = inf (rigid feelers) needs coupling=True: without the "
                             "rubber's compliance nothing gives way")
        object.__setattr__(self, "stiffness", k)
        if self.tangential_stiffness is not None:
            object.__setattr__(self, "tangential_stiffness",
                               _stiffness(self.tangential_stiffness, "ContactModel tangential_stiffness (N/mm)",
                                          allow_inf=True))
        object.__setattr__(self, "youngs_modulus",
                           positive(self.youngs_modulus, "ContactModel youngs_modulus (MPa)"))
        nu = positive(self.poisson_ratio, "ContactModel poisson_ratio", allow_zero=True)
        if not nu < 0.5:
            raise InputError(f"ContactModel poisson_ratio must be in [0, 0.5), got {self.poisson_ratio!r}")
        object.__setattr__(self, "poisson_ratio", nu)
        object.__setattr__(self, "feeler_height",
                           positive(self.feeler_height, "ContactModel feeler_height (mm)", allow_zero=True))
        object.__setattr__(self, "skin_thickness",
                           positive(self.skin_thickness, "ContactModel skin_thickness (mm)"))
        spacing = positive(self.skin_spacing, "ContactModel skin_spacing (mm)")
        if not 0.05 <= spacing <= 5.0:
            raise InputError(f"ContactModel skin_spacing must be from 0.05 to 5 mm, got {self.skin_spacing!r}")
        object.__setattr__(self, "skin_spacing", spacing)

    @classmethod
    def of(cls, sensor: DomeSensor, **changes) -> ContactModel:
        """The model with the sensor's rubber (``youngs_modulus``, ``poisson_ratio``) and ``changes``.

        Parameters
        ----------
        sensor : DomeSensor
        **changes
            Any other :class:`ContactModel` parameter.

        Returns
        -------
        ContactModel
        """
        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        kw = {"youngs_modulus": sensor.youngs_modulus, "poisson_ratio": sensor.poisson_ratio}
        kw.update(changes)
        return cls(**kw)

    @property
    def mindlin_ratio(self) -> float:
        """Mindlin's ratio of tangential to normal contact stiffness, ``2 (1 - nu) / (2 - nu)``."""
        nu = self.poisson_ratio
        return 2.0 * (1.0 - nu) / (2.0 - nu)

    @property
    def tangential(self) -> float:
        """The tangential stiffness in use (N/mm): ``tangential_stiffness`` or Mindlin's share of ``stiffness``.

        ``math.inf`` with rigid feelers and no ``tangential_stiffness``: every slide slips.
        """
        if self.tangential_stiffness is not None:
            return self.tangential_stiffness
        return self.mindlin_ratio * self.stiffness

    @property
    def effective_modulus(self) -> float:
        """Plane-strain modulus ``E* = E / (1 - nu^2)`` of the rubber (MPa)."""
        return self.youngs_modulus / (1.0 - self.poisson_ratio**2)


# --------------------------------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class Indentation:
    """The element forces of an indenter pressed (and slid) on the dome; all arrays read-only.

    Attributes
    ----------
    forces : (N, 3) ndarray
        Element-local forces ``(Fx, Fy, Fz)`` (N); ``Fz > 0`` presses the
        element onto the dome. ``ForceField(sensor, ind.forces,
        contact=ind.contact)`` makes a :class:`~optitact.forces.ForceField`.
    global_forces : (N, 3) ndarray
        The forces the object exerts on the elements, sensor frame (N).
    normal : (N,) ndarray
        The contact normal force each element carries, ``sum_a omega_ai p_a``
        (N, >= 0).
    contact : (N,) ndarray of bool
        Elements that carry a load (``normal > 0``).
    slipping : (N,) ndarray of bool
        Elements whose every loading contact point slides on the object (its
        friction force at Coulomb's limit).
    tips : (N, 3) ndarray
        Feeler tip positions (mm, sensor frame), unloaded.
    points : (m, 3) ndarray
        The contact points that carry a load (feeler tips and skin points),
        sensor frame (mm), unloaded.
    point_forces : (m, 3) ndarray
        The force the object exerts at each contact point (N, sensor frame).
    point_normals : (m, 3) ndarray
        The object's outward unit normal at each contact point.
    on_skin : (m,) ndarray of bool
        Contact points on the skin (the others are feeler tips).
    depth : float
        How far the indenter was pushed from ``pose`` along its pressing
        direction (mm).
    normal_force : float
        The pressing force ``sum_a p_a n_a . u`` (N), ``u`` the pressing
        direction: the load the indenter is pressed with (friction excluded).
    pose : Pose
        The pose at depth 0 (:attr:`pressed_pose` is the pose at ``depth``).
    """

    forces: np.ndarray
    global_forces: np.ndarray
    normal: np.ndarray
    contact: np.ndarray
    slipping: np.ndarray
    tips: np.ndarray
    points: np.ndarray
    point_forces: np.ndarray
    point_normals: np.ndarray
    on_skin: np.ndarray
    depth: float
    normal_force: float
    pose: Pose

    def __post_init__(self) -> None:
        for name in ("forces", "global_forces", "normal", "contact", "slipping", "tips", "points",
                     "point_forces", "point_normals", "on_skin"):
            object.__setattr__(self, name, _freeze(np.array(getattr(self, name))))

    def __repr__(self) -> str:
        f = ", ".join(f"{v:.4g}" for v in self.resultant)
        return (f"Indentation(depth={self.depth:.4g} mm, normal_force={self.normal_force:.4g} N, "
                f"n_contact={self.n_contact}, n_slipping={int(self.slipping.sum())}, resultant=({f}) N)")

    @property
    def n_contact(self) -> int:
        """Number of elements in contact."""
        return int(np.count_nonzero(self.contact))

    @property
    def pressed_pose(self) -> Pose:
        """The indenter's pose at :attr:`depth` (before any slide)."""
        return self.pose.moved(self.depth)

    @property
    def resultant(self) -> np.ndarray:
        """Sum of :attr:`global_forces` (N), shape (3,): the force of the object on the sensor."""
        return self.global_forces.sum(axis=0)

    @property
    def moment(self) -> np.ndarray:
        """Moment of the contact forces about the dome centre (N mm), shape (3,): ``sum_a y_a x f_a``.

        ``y_a`` the contact points, ``f_a`` :attr:`point_forces`.
        """
        return np.cross(self.points, self.point_forces).sum(axis=0)

    @property
    def wrench(self) -> np.ndarray:
        """``(resultant, moment)`` about the dome centre, shape (6,) (N, N mm)."""
        return np.concatenate([self.resultant, self.moment])


# ------------------------------------------------------------------------------------------ mechanics
def _lcp(a: np.ndarray, g: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """``p >= 0`` with ``g + a p >= 0`` and ``p (g + a p) = 0`` for a symmetric positive definite ``a``.

    Active set from ``start`` (default: every point): solve on the set, drop
    points that pull (negative force), add points still penetrating, until
    neither changes; then non-negative least squares on the Cholesky factor if
    it ever cycles.
    """
    m = len(g)
    tol = 1e-12 * max(float(np.abs(g).max()), 1e-300)
    active = np.ones(m, dtype=bool) if start is None or not start.any() else start.copy()
    seen = set()
    for _ in range(4 * m + 20):
        idx = np.flatnonzero(active)
        p = np.zeros(m)
        if idx.size:
            sub = a[np.ix_(idx, idx)]
            try:
                p[idx] = linalg.cho_solve(linalg.cho_factor(sub), -g[idx])
            except linalg.LinAlgError:
                p[idx] = np.linalg.lstsq(sub, -g[idx], rcond=None)[0]
        pulled = active & (p < 0)
        if pulled.any():
            active &= ~pulled
        else:
            missing = ~active & (g + a @ p < -tol)
            if not missing.any():
                return np.maximum(p, 0.0)
            active |= missing
        key = active.tobytes()
        if key in seen:
            break
        seen.add(key)
    # a cycle: the same quadratic programme, min p'Ap/2 + g'p over p >= 0, as least squares
    chol = linalg.cholesky(a + 1e-14 * np.trace(a) / m * np.eye(m), lower=True)
    rhs = -linalg.solve_triangular(chol, g, lower=True)
    return optimize.nnls(chol.T, rhs, maxiter=50 * m)[0]


def _influence(points: np.ndarray, areas: np.ndarray, model: ContactModel) -> np.ndarray:
    """Boussinesq normal compliance between elements (mm/N), self terms from uniform pressure on a disc."""
    c = (1.0 - model.poisson_ratio**2) / (math.pi * model.youngs_modulus)
    r = distance.cdist(points, points)
    np.fill_diagonal(r, 1.0)
    w = c / np.maximum(r, 1e-9)
    np.fill_diagonal(w, 2.0 * c / np.sqrt(areas / math.pi))
    return w


@dataclass(frozen=True)
class _Skin:
    """The skin's sample points on the outer dome surface and the elements that carry them."""

    points: np.ndarray   # (S, 3) mm
    weights: np.ndarray  # (S, N) partition of unity over the elements
    area: float          # mm^2 per point


def _wendland(r: np.ndarray) -> np.ndarray:
    """Wendland's C2 kernel ``(1 - r)^4 (4 r + 1)`` on ``r < 1``."""
    q = np.clip(1.0 - r, 0.0, None)
    return q**4 * (4.0 * r + 1.0)


@functools.lru_cache(maxsize=8)
def _dome_skin(sensor: DomeSensor, spacing: float) -> _Skin:
    """A Fibonacci lattice over the elements' tributary cap, and its partition of unity (cached)."""
    r_out = sensor.outer_radius
    top = float(_ring_bands(sensor)[1].max())
    cap = 2.0 * math.pi * r_out**2 * (1.0 - math.cos(top))
    n = max(int(round(cap / spacing**2)), 1)
    k = np.arange(n) + 0.5
    z = 1.0 - (1.0 - math.cos(top)) * k / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    points = r_out * np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    d = distance.cdist(points, sensor.element_positions)
    support = 1.5 * float(d.min(axis=1).max())
    w = _wendland(d / support)
    w /= w.sum(axis=1, keepdims=True)
    return _Skin(_freeze(points), _freeze(w), cap / n)


@dataclass(frozen=True)
class _Contacts:
    """Contact points that carry a load at one depth, and the elements they load."""

    points: np.ndarray    # (m, 3)
    normals: np.ndarray   # (m, 3) the object's outward normals
    p: np.ndarray         # (m,) normal forces
    elements: np.ndarray  # (E',) the elements loaded
    omega: np.ndarray     # (m, E') each point's shares of them
    on_skin: np.ndarray   # (m,)


class _Problem:
    """The elements, the skin and what presses them: one normal problem per depth."""

    def __init__(self, tips, normals, areas, shape: Shape, pose: Pose, model: ContactModel, skin: _Skin | None):
        self.tips, self.normals, self.areas = tips, normals, areas
        self.shape, self.pose, self.model, self.skin = shape, pose, model, skin
        self.coupling = _influence(tips, areas, model) if model.coupling else None
        self.warm = np.zeros(0, dtype=int)  # the points in contact at the last depth: the next solve's start
        self.skin_compliance = model.skin_thickness / (model.effective_modulus * skin.area) if skin else 0.0
        #: The deepest push worth trying (mm): the indenter's tip past the farthest feeler tip.
        self.reach = float(np.linalg.norm(tips - pose.position, axis=1).max()) + 1.0

    def _query(self, points: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rot = self.pose.rotation
        gap, local_n = self.shape._evaluate((points - position) @ rot)
        return gap, local_n @ rot.T

    def state(self, depth: float) -> _Contacts:
        """The contact points' forces at ``depth``."""
        model = self.model
        position = self.pose.position + depth * self.pose.press_direction
        gap_t, n_t = self._query(self.tips, position)
        if self.skin is not None:
            gap_s, n_s = self._query(self.skin.points, position)
        else:
            gap_s, n_s = np.zeros(0), np.zeros((0, 3))
        n_el = len(self.tips)
        it = np.flatnonzero(gap_t < 0)
        warm = self.warm[self.warm >= n_el] - n_el             # skin points in contact at the last depth
        js = warm[gap_s[warm] < 0]
        e = self.normals
        for _ in range(100):
            if js.size == 0 and self.coupling is None:  # tips alone on independent springs: closed form
                c = _Contacts(self.tips[it], n_t[it], -model.stiffness * gap_t[it], it, np.eye(it.size),
                              np.zeros(it.size, dtype=bool))
            else:
                c = self._solve(it, js, gap_t, n_t, gap_s, n_s)
            # every element's displacement, and the points not yet in the problem that end up in the object
            u = np.zeros((n_el, 3))
            if not math.isinf(model.stiffness):
                u[c.elements] = c.omega.T @ (c.p[:, None] * c.normals) / model.stiffness
            sink = np.zeros(n_el)
            if self.coupling is not None:
                sigma = (c.omega * np.maximum(-(c.normals @ e[c.elements].T), 0.0)).T @ c.p
                sink = self.coupling[:, c.elements] @ sigma
            bound = max(float(np.linalg.norm(u, axis=1).max(initial=0.0)), float(sink.max(initial=0.0)))
            tol = 1e-12  # mm
            tt = np.setdiff1d(np.flatnonzero(gap_t < bound), it, assume_unique=True)
            after_t = (gap_t[tt] + np.einsum("ij,ij->i", n_t[tt], u[tt])
                       + np.maximum(-np.einsum("ij,ij->i", n_t[tt], e[tt]), 0.0) * sink[tt])
            ss = np.setdiff1d(np.flatnonzero(gap_s < bound), js, assume_unique=True)
            w = self.skin.weights[ss] if ss.size else np.zeros((0, n_el))
            after_s = (gap_s[ss] + np.einsum("ij,ij->i", n_s[ss], w @ u)
                       + (w * np.maximum(-(n_s[ss] @ e.T), 0.0)) @ sink)
            new_t, new_s = tt[after_t < -tol], ss[after_s < -tol]
            if not new_t.size and not new_s.size:
                if js.size == 0 and self.coupling is None:
                    self.warm = it[c.p > 0]
                return c
            it, js = np.union1d(it, new_t), np.union1d(js, new_s)
        return c  # pragma: no cover - the problem grows at most to every point

    def _solve(self, it, js, gap_t, n_t, gap_s, n_s) -> _Contacts:
        """The linear complementarity problem of the tips ``it`` and skin points ``js``."""
        model = self.model
        mt, ms = it.size, js.size
        skin_w = self.skin.weights[js] if ms else np.zeros((0, len(self.tips)))
        elements = np.union1d(it, np.flatnonzero(skin_w.any(axis=0)))
        omega = np.zeros((mt + ms, elements.size))
        omega[np.arange(mt), np.searchsorted(elements, it)] = 1.0
        omega[mt:] = skin_w[:, elements]
        normals = np.concatenate([n_t[it], n_s[js]])
        gap = np.concatenate([gap_t[it], gap_s[js]])
        points = np.concatenate([self.tips[it], self.skin.points[js]]) if ms else self.tips[it]
        on_skin = np.arange(mt + ms) >= mt
        a = np.zeros((mt + ms, mt + ms))
        if not math.isinf(model.stiffness):
            a += (omega @ omega.T) * (normals @ normals.T) / model.stiffness
        a[np.diag_indices_from(a)] += np.where(on_skin, self.skin_compliance, 0.0)
        if self.coupling is not None:
            c = omega * np.maximum(-(normals @ self.normals[elements].T), 0.0)
            a += c @ self.coupling[np.ix_(elements, elements)] @ c.T
        small = a.diagonal() <= 0  # a rigid feeler pushed along the skin: nothing gives way
        if small.any():
            a[np.diag_indices_from(a)] += np.where(small, 1e-9 * float(a.diagonal().max(initial=1.0)), 0.0)
        ids = np.concatenate([it, js + len(self.tips)])
        p = _lcp(a, gap, np.isin(ids, self.warm)) if gap.size else np.zeros(0)
        self.warm = ids[p > 0]
        return _Contacts(points, normals, p, elements, omega, on_skin)

    def force(self, depth: float) -> float:
        """The pressing force (N) at ``depth``."""
        c = self.state(depth)
        return float(c.p @ (c.normals @ self.pose.press_direction))

    def depth_for(self, target: float) -> float:
        """The depth (mm) at which the pressing force is ``target`` (N), on the rising branch of ``F(d)``.

        Steps outward from depth 0 (backwards first if ``F(0)`` is already
        above ``target``), in steps growing from 0.01 to 0.25 mm, until ``F``
        reaches ``target``; Brent's method then solves within the last step.
        """
        def f(d):
            return self.force(d) - target

        f0 = f(0.0)
        if f0 == 0.0:
            return 0.0
        sign = 1.0 if f0 < 0 else -1.0                      # push in, or back off
        lo, hi, step, top = 0.0, 0.0, 0.01, (f0 + target, 0.0)
        while True:
            lo, hi = hi, hi + sign * step
            f_hi = f(hi)
            if sign * f_hi >= 0:
                break
            if sign < 0 and abs(hi) > self.reach:  # pragma: no cover - an object around the whole sensor
                raise InputError(f"force {target:g} N: the indenter presses more at every depth tried")
            if sign > 0:
                top = max(top, (f_hi + target, hi))
                if top[0] == 0 and abs(hi) > self.reach:
                    raise InputError(f"force {target:g} N cannot be reached: the indenter touches nothing "
                                     f"(does its pressing direction point at the tips?)")
                if f_hi + target < 0.5 * top[0] or abs(hi) > self.reach:
                    raise InputError(f"force {target:g} N cannot be reached: the indenter presses at most "
                                     f"{top[0]:.4g} N (at depth {top[1]:.4g} mm) before it sinks past the "
                                     f"feelers (try a smaller force, a larger object or a stiffer model)")
            step = min(1.3 * step, 0.25)
        depth = optimize.brentq(f, min(lo, hi), max(lo, hi), xtol=1e-14, rtol=4.0 * np.finfo(float).eps,
                                maxiter=500)
        got = self.force(depth)
        if abs(got - target) > max(1e-9 * target, 1e-12):
            raise InputError(f"force {target:g} N cannot be reached: the pressing force jumps past it at depth "
                             f"{depth:.6g} mm (to {got:.9g} N; contact points cross the object's middle, "
                             f"where its surface normal flips)")
        return depth


def _local_frames(normals: np.ndarray) -> np.ndarray:
    """Element-local axes (n, 3, 3) for outward normals, by the convention of the dome's element frames."""
    x = np.array([1.0, 0.0, 0.0]) - normals[:, :1] * normals
    flat = np.linalg.norm(x, axis=1) < 1e-9
    x[flat] = np.array([0.0, 1.0, 0.0]) - normals[flat, 1:2] * normals[flat]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(normals, x), normals], axis=1)


def _slide_vector(slide, pose: Pose) -> np.ndarray:
    s = finite(real_array(slide, "slide"), "slide")
    if s.shape == (2,):
        return s[0] * pose.rotation[:, 0] + s[1] * pose.rotation[:, 1]
    if s.shape == (3,):
        return s
    raise ShapeError(f"slide must be (dx, dy) along the indenter's own x, y axes or (dx, dy, dz) in the sensor "
                     f"frame (mm), got shape {s.shape}")


def _press(tips, normals, areas, shape, pose, *, depth, force, slide, friction, model, skin,
           to_local) -> Indentation:
    if not isinstance(shape, Shape):
        raise TypeError(f"indenter must be a Shape (Sphere, Flat, Edge, Cylinder or SDF), got "
                        f"{type(shape).__name__}")
    if not isinstance(pose, Pose):
        raise TypeError(f"pose must be a Pose (e.g. Pose.touching(sensor, polar_deg, azimuth_deg)), got "
                        f"{type(pose).__name__}")
    if (depth is None) == (force is None):
        raise InputError("give exactly one of depth (mm beyond the pose) and force (N, the pressing force); "
                         "got " + ("both" if depth is not None else "neither"))
    mu = positive(friction, "friction", allow_zero=True)
    s = None if slide is None else _slide_vector(slide, pose)
    target = None if force is None else positive(force, "force (N)")
    depth = None if depth is None else real_number(depth, "depth (mm)")
    problem = _Problem(tips, normals, areas, shape, pose, model, skin)
    if target is not None:
        depth = problem.depth_for(target)
    c = problem.state(depth)
    m, e = len(c.p), len(c.elements)
    load = c.omega.T @ c.p                                   # N_i, each loaded element's normal load
    beta = c.omega * c.p[:, None] / np.where(load > 0, load, 1.0)[None, :]
    tau = np.zeros((m, e))                                   # |tau_ai|
    slips = np.zeros((m, e), dtype=bool)
    unit = np.zeros((m, 3))
    if s is not None and m:
        st = s - (c.normals @ s)[:, None] * c.normals
        mag = np.linalg.norm(st, axis=1)
        unit = st / np.where(mag > 0, mag, 1.0)[:, None]
        kt = model.tangential
        pairs = (beta > 0) & (mag > 0)[:, None]
        limit = np.broadcast_to(mu * load[None, :], (m, e))
        if math.isinf(kt):  # rigid tangentially: any slide slips
            stick = np.zeros((m, e))
            slips = pairs
        else:
            stick = np.broadcast_to(kt * mag[:, None], (m, e))
            slips = pairs & (stick > limit)
        tau = np.where(pairs, np.where(slips, limit, stick), 0.0)
    element_t = (beta * tau).T @ unit                        # T_i
    point_forces = c.p[:, None] * c.normals + (beta * tau).sum(axis=1)[:, None] * unit
    n = len(tips)
    g = np.zeros((n, 3))
    g[c.elements] = c.omega.T @ (c.p[:, None] * c.normals) + element_t
    normal = np.zeros(n)
    normal[c.elements] = load
    contact = normal > 0
    loads = beta > 0
    slipping = np.zeros(n, dtype=bool)
    slipping[c.elements] = (loads & slips).any(axis=0) & ~(loads & ~slips).any(axis=0)
    keep = c.p > 0
    return Indentation(forces=to_local(g) + 0.0, global_forces=g, normal=normal, contact=contact,
                       slipping=slipping,
                       tips=tips, points=c.points[keep], point_forces=point_forces[keep],
                       point_normals=c.normals[keep], on_skin=c.on_skin[keep], depth=float(depth),
                       normal_force=float(c.p @ (c.normals @ pose.press_direction)), pose=pose)


def _ring_bands(sensor: DomeSensor) -> tuple[np.ndarray, np.ndarray]:
    """Polar angles (rad) where each ring's band starts and ends: half-way to the neighbouring rings.

    From the apex for a ring at 0 deg; the last ring's band reaches as far
    beyond it as the previous half-pitch (at most 90 deg). A single ring
    reaches the cone circle's angular radius beyond it on each side.
    """
    th = np.radians(np.asarray(sensor.ring_polar_deg, float))
    if len(th) == 1:
        half = np.array([(sensor.cone_circle_radius + sensor.cone_base_radius) / sensor.outer_radius])
        lo, hi = th - half, th + half
    else:
        mid = (th[1:] + th[:-1]) / 2.0
        lo = np.concatenate([[th[0] - (mid[0] - th[0])], mid])
        hi = np.concatenate([mid, [th[-1] + (th[-1] - mid[-1])]])
    if th[0] == 0.0:
        lo[0] = 0.0
    return np.maximum(lo, 0.0), np.minimum(hi, math.pi / 2)


def _dome_areas(sensor: DomeSensor) -> np.ndarray:
    """Each element's tributary area on the outer surface (mm^2): its ring's band, shared equally."""
    lo, hi = _ring_bands(sensor)
    counts = np.asarray(sensor.ring_counts)
    band = 2.0 * math.pi * sensor.outer_radius**2 * (np.cos(lo) - np.cos(hi)) / counts
    return np.repeat(band, counts)


def press(sensor: DomeSensor, indenter: Shape, pose: Pose, *, depth: float | None = None,
          force: float | None = None, slide=None, friction: float = 0.5,
          model: ContactModel | None = None) -> Indentation:
    """Press an indenter into the dome: the element-local forces of every element.

    Parameters
    ----------
    sensor : DomeSensor
        The dome; feeler tips stand at ``(R + h) e_i`` (``e_i`` the element
        normals of ``sensor.element_frames``, as built).
    indenter : Shape
        :class:`Sphere`, :class:`Flat`, :class:`Edge`, :class:`Cylinder` or
        :class:`SDF`.
    pose : Pose
        The indenter's pose at depth 0, e.g. ``Pose.touching(sensor, 30, 40)``.
    depth : float, optional
        How far to push the indenter from ``pose`` along its pressing
        direction (mm); negative backs it off.
    force : float, optional
        The pressing force to reach instead (N, > 0); the depth is solved for
        (the force is met to 1e-9 relative or better; see the module's notes).
    slide : (2,) or (3,) array_like, optional
        A slide of the indenter after pressing (mm): ``(dx, dy)`` along its
        own ``x``, ``y`` axes (tangent to the dome at the touching point for a
        :meth:`Pose.touching` pose), or ``(dx, dy, dz)`` in the sensor frame.
        Each contact point's share is projected onto its contact's tangent
        plane.
    friction : float
        Coulomb friction coefficient ``mu`` between object and rubber,
        default 0.5, >= 0 (only used with ``slide``).
    model : ContactModel, optional
        The contact law; default ``ContactModel.of(sensor)`` (independent
        2 N/mm feeler springs, the skin, the sensor's rubber).

    Returns
    -------
    Indentation
        The element-local forces, contact and slip flags, depth and wrench.

    Raises
    ------
    TypeError
        An argument of the wrong kind.
    ShapeError
        ``slide`` of the wrong shape.
    InputError
        Both or neither of ``depth`` and ``force``; a value out of range or
        not finite; a force the indenter cannot reach.

    Notes
    -----
    The model is the module's (see :mod:`optitact.forces.indenter`);
    element-local forces come from
    :func:`optitact.optics.force_frames.local_from_global`. Each element's
    tributary area (the coupling's self term) is its ring's band of the outer
    surface, between the polar angles half-way to the neighbouring rings,
    shared equally among the ring's elements; the skin is sampled over the
    union of the bands. While the object touches the feeler tips alone and
    ``coupling`` is off, the forces are exactly those of
    :func:`optitact.finger.scene.feeler_forces` (with the same stiffness) for
    an object of the same geometry. A call takes about a millisecond (the skin's sample points are
    tested against the shape each time; tens of milliseconds when solving for
    a force with the skin in contact).

    Examples
    --------
    >>> s = DomeSensor.default()
    >>> ind = press(s, Sphere(5.0), Pose.touching(s, 0.0, 0.0), force=0.8)
    >>> ind.n_contact, round(ind.depth, 4), round(float(ind.forces[:, 2].sum()), 4)
    (1, 0.4, 0.8)
    """
    if not isinstance(sensor, DomeSensor):
        raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
    model = ContactModel.of(sensor) if model is None else model
    if not isinstance(model, ContactModel):
        raise TypeError(f"model must be a ContactModel, got {type(model).__name__}")
    normals = sensor.element_frames[:, 2, :]
    tips = (sensor.outer_radius + model.feeler_height) * normals
    skin = _dome_skin(sensor, model.skin_spacing) if model.skin else None
    return _press(tips, normals, _dome_areas(sensor), indenter, pose, depth=depth, force=force, slide=slide,
                  friction=friction, model=model, skin=skin, to_local=lambda g: local_from_global(sensor, g))


def press_points(tips, normals, areas, indenter: Shape, pose: Pose, *, depth: float | None = None,
                 force: float | None = None, slide=None, friction: float = 0.5,
                 model: ContactModel | None = None) -> Indentation:
    """Press an indenter onto any set of feeler tips: :func:`press` without the dome.

    Parameters
    ----------
    tips : (n, 3) array_like
        Feeler tip positions (mm), in the frame of ``pose``; each tip is an
        element.
    normals : (n, 3) array_like
        Outward normals of the surface each tip stands on (normalised here);
        the element-local frames follow the dome's convention (``z`` the
        normal, ``x`` the global ``x`` projected onto the tangent plane, the
        global ``y`` where that vanishes).
    areas : float or (n,) array_like
        Tributary area of each tip (mm^2, > 0): the self term of the
        coupling.
    indenter, pose, depth, force, slide, friction
        As :func:`press`.
    model : ContactModel, optional
        Default ``ContactModel()``; its ``skin`` is not used (the tips alone
        touch the object).

    Returns
    -------
    Indentation
        As :func:`press`, for the ``n`` tips.

    Raises
    ------
    TypeError, ShapeError, InputError
        As :func:`press`; also tips, normals or areas of the wrong shape, a
        zero normal or an area that is not > 0.

    Examples
    --------
    A sphere on a flat 0.5 mm grid of independent springs:

    >>> x = np.arange(-5, 5.01, 0.5)
    >>> tips = np.stack(np.meshgrid(x, x, [0.0]), -1).reshape(-1, 3)
    >>> up = np.tile([0.0, 0.0, 1.0], (len(tips), 1))
    >>> ind = press_points(tips, up, 0.25, Sphere(10.0), Pose([0.0, 0.0, 0.0]), depth=0.1)
    >>> ind.n_contact, round(ind.normal_force, 4)
    (21, 2.4792)
    """
    model = ContactModel() if model is None else model
    if not isinstance(model, ContactModel):
        raise TypeError(f"model must be a ContactModel, got {type(model).__name__}")
    tips = _points(tips, "tips")
    normals = _points(normals, "normals")
    if normals.shape != tips.shape:
        raise ShapeError(f"normals must have the shape of tips {tips.shape}, got {normals.shape}")
    norm = np.linalg.norm(normals, axis=1)
    if np.any(norm == 0):
        raise InputError(f"normals must be non-zero vectors, got a zero one at row {int(np.argmin(norm))}")
    normals = normals / norm[:, None]
    a = finite(real_array(areas, "areas"), "areas")
    if a.ndim == 0:
        a = np.full(len(tips), float(a))
    if a.shape != (len(tips),):
        raise ShapeError(f"areas must be a number or have shape ({len(tips)},) (one per tip), got {a.shape}")
    if np.any(a <= 0):
        raise InputError(f"areas must be > 0 (mm^2), got {a.min()}")
    frames = _local_frames(normals)
    sign = np.array([1.0, 1.0, -1.0])
    return _press(tips, normals, a, indenter, pose, depth=depth, force=force, slide=slide, friction=friction,
                  model=model, skin=None, to_local=lambda g: np.einsum("nij,nj->ni", frames, g) * sign)


# ------------------------------------------------------------------------------------------- text form
_SHAPES = {"sphere": (Sphere, ("radius",), ()), "flat": (Flat, ("radius",), ()),
           "edge": (Edge, ("length", "tip_radius"), ("angle",)),
           "cylinder": (Cylinder, ("radius", "length"), ())}
_SPEC = re.compile(r"^\s*(?P<name>[A-Za-z_]+)\s*(?::(?P<args>.*))?$")


def parse_spec(text: str) -> tuple[Shape, float]:
    """Read an indenter's text form: the shape and its spin about the pressing axis.

    Parameters
    ----------
    text : str
        ``NAME:key=value,key=value``, one of :data:`SPEC_GRAMMAR`:
        ``sphere:radius=R``, ``flat:radius=R``,
        ``edge:length=L,tip_radius=r[,angle=DEG]``,
        ``cylinder:radius=R,length=L``; each may add ``spin=DEG``. Lengths in
        mm, angles in degrees; names in any case.

    Returns
    -------
    shape : Shape
    spin_deg : float
        The ``spin`` (deg), 0 when not given (for :meth:`Pose.touching`).

    Raises
    ------
    TypeError
        ``text`` is not a str.
    InputError
        Any other text; the message says what is wrong and gives the grammar.

    Examples
    --------
    >>> parse_spec("edge:length=10,tip_radius=0.5,spin=30")
    (Edge(length=10.0, tip_radius=0.5, angle=60.0), 30.0)
    """
    if not isinstance(text, str):
        raise TypeError(f"an indenter spec must be a str, got {type(text).__name__}")

    def bad(why: str) -> InputError:
        return InputError(f"indenter {text!r}: {why}; expected {SPEC_GRAMMAR}")

    m = _SPEC.match(text)
    if m is None:
        raise bad("not NAME:key=value,...")
    name = m["name"].lower()
    if name not in _SHAPES:
        raise bad(f"unknown shape {m['name']!r}")
    cls, required, optional = _SHAPES[name]
    values: dict[str, float] = {}
    for item in (m["args"] or "").split(","):
        if not item.strip():
            continue
        key, sep, value = item.partition("=")
        key = key.strip().lower()
        if not sep:
            raise bad(f"{item.strip()!r} is not key=value")
        if key not in (*required, *optional, "spin"):
            raise bad(f"{name} takes {', '.join((*required, *optional, 'spin'))}, not {key!r}")
        if key in values:
            raise bad(f"{key} given twice")
        try:
            values[key] = float(value)
        except ValueError:
            raise bad(f"{key}={value.strip()!r} is not a number") from None
        if not math.isfinite(values[key]):
            raise bad(f"{key} must be finite, got {value.strip()}")
    missing = [k for k in required if k not in values]
    if missing:
        raise bad(f"{name} needs {', '.join(missing)}")
    spin = values.pop("spin", 0.0)
    try:
        shape = cls(**values)
    except InputError as exc:
        raise bad(str(exc)) from None
    return shape, spin
