"""Contact model: element forces -> conical-feeler contact patches on the dome.

Convention
----------
Forces are element-local ``(Fx, Fy, Fz)`` in N: ``Fz`` is the normal force
pressing the element onto the dome (positive = compression), ``Fx, Fy`` the
shear in the element's tangent plane. Patch centres are global ``(x, y, z)``
points on the outer dome surface in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from optitact._validate import check_type, finite, real_array
from optitact.errors import InputError, ShapeError
from optitact.optics.sensor import DomeSensor

__all__ = ["Contacts", "contact_patches", "cone_loads"]

#: Fraction of the support polygon the centre of pressure may reach before the
#: columnar feeler counts as tipped (the load distribution stops following shear).
TIP_MARGIN = 0.95
#: Largest force component (N) accepted: far beyond any tactile load (a unit mix-up, mN for N,
#: stays well inside), and small enough that the contact arithmetic cannot overflow.
MAX_FORCE_N = 1e6


@dataclass(frozen=True)
class Contacts:
    """Contact patches of every conical feeler, for one frame.

    Attributes
    ----------
    centers : (N, K, 3) ndarray
        Patch centres on the outer dome surface, global mm.
    radii : (N, K) ndarray
        Patch radii (mm); 0 where the cone does not touch.
    loads : (N, K) ndarray
        Normal load carried by each cone (N).
    saturated : (N, K) ndarray of bool
        Cone fully flattened: the radius is capped at the cone's base radius.
    tipped : (N,) ndarray of bool
        The shear moment exceeded what the cones can balance; the load
        distribution was capped at the support polygon's edge.
    slide : (N, 2) ndarray
        Rigid slide of the element's patches along the shear, local x/y mm.
    """

    centers: np.ndarray
    radii: np.ndarray
    loads: np.ndarray
    saturated: np.ndarray
    tipped: np.ndarray
    slide: np.ndarray

    @property
    def in_contact(self) -> np.ndarray:
        """(N, K) bool: the cone touches the dome."""
        return self.radii > 0

    @property
    def area_mm2(self) -> np.ndarray:
        """(N, K) contact areas in mm^2."""
        return np.pi * self.radii**2

    def as_dict(self) -> dict:
        """Per-cone table: equal-length flat arrays keyed by name."""
        n, k = self.radii.shape
        return {
            "element": np.repeat(np.arange(n), k),
            "cone": np.tile(np.arange(k), n),
            "x": self.centers[..., 0].ravel(),
            "y": self.centers[..., 1].ravel(),
            "z": self.centers[..., 2].ravel(),
            "radius_mm": self.radii.ravel(),
            "load_n": self.loads.ravel(),
            "saturated": self.saturated.ravel(),
        }


def check_forces(forces, sensor: DomeSensor, name: str = "forces") -> np.ndarray:
    """Validate element-local forces: a finite real array of shape (N, 3), within ``MAX_FORCE_N``.

    Raises
    ------
    TypeError
        For a bool, complex, object or string array, or nested sequences
        that do not form an array.
    ShapeError
        If the shape is not ``(n_elements, 3)``.
    InputError
        For NaN, infinity, or a component beyond ``MAX_FORCE_N`` (1e6 N) in
        magnitude.
    """
    check_type(sensor, DomeSensor, "sensor")
    arr = real_array(forces, name)
    if arr.shape != (sensor.n_elements, 3):
        raise ShapeError(
            f"{name} must have shape ({sensor.n_elements}, 3) (Fx, Fy, Fz per element, N), "
            f"got {arr.shape}"
        )
    finite(arr, name)
    if arr.size and np.abs(arr).max() > MAX_FORCE_N:
        bad = tuple(int(i) for i in np.argwhere(np.abs(arr) > MAX_FORCE_N)[0])
        raise InputError(f"{name} must be at most {MAX_FORCE_N:g} N in magnitude (check the units), "
                         f"got {float(arr[bad])!r} at index {bad}")
    return arr


def _support_radius(sensor: DomeSensor, direction: np.ndarray) -> np.ndarray:
    """Distance from the element centre to the cone polygon's edge along ``direction`` (rad)."""
    k = sensor.n_cones
    half = np.pi / k
    # Edge normals lie half-way between cone directions (angles pi/k + 2 pi j / k).
    delta = np.mod(direction, 2.0 * half) - half
    return sensor.cone_circle_radius * np.cos(half) / np.cos(delta)


def _pressure_weights(target: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """Solve ``sum_j w_j = 1``, ``sum_j w_j u_j = target`` for ``w_j = max(beta + b.u_j, 0)^2``.

    These are the stationarity conditions of the convex function
    ``phi(beta, b) = sum_j max(beta + b.u_j, 0)^3 / 3 - beta - b.target``,
    minimised by Newton's method with backtracking, vectorised over rows.
    """
    n = target.shape[0]
    k = unit.shape[0]
    aug = np.concatenate([np.ones((k, 1)), unit], axis=1)  # (K, 3): [1, u_j]
    rhs = np.concatenate([np.ones((n, 1)), target], axis=1)
    beta0 = np.sqrt(1.0 / k)
    x = np.concatenate([np.full((n, 1), beta0), target / (beta0 * k)], axis=1)

    def phi(x):
        m = np.maximum(x @ aug.T, 0.0)
        return (m**3).sum(axis=1) / 3.0 - (x * rhs).sum(axis=1)

    for _ in range(60):
        m = np.maximum(x @ aug.T, 0.0)
        grad = (m * m) @ aug - rhs
        if np.max(np.abs(grad)) < 1e-11:
            break
        hess = 2.0 * np.einsum("nk,ki,kj->nij", m, aug, aug) + 1e-12 * np.eye(3)
        step = -np.linalg.solve(hess, grad[..., None])[..., 0]
        t = np.ones(n)
        f0 = phi(x)
        slope = (grad * step).sum(axis=1)
        for _ in range(40):
            bad = phi(x + t[:, None] * step) > f0 + 1e-4 * t * slope
            if not bad.any():
                break
            t[bad] *= 0.5
        x = x + t[:, None] * step
    w = np.maximum(x @ aug.T, 0.0) ** 2
    return w / w.sum(axis=1, keepdims=True)


def cone_loads(sensor: DomeSensor, forces) -> tuple[np.ndarray, np.ndarray]:
    r"""Share each element's load among its conical feelers.

    Parameters
    ----------
    sensor : DomeSensor
    forces : (N, 3) array_like
        Element-local forces (N).

    Returns
    -------
    loads : (N, K) ndarray
        Normal load on each cone (N), >= 0.
    tipped : (N,) ndarray of bool
        Whether the centre of pressure was capped at the support polygon.

    Notes
    -----
    The columnar feeler is rigid; cone ``j`` at ``r_j`` (local tangent plane)
    is compressed by ``d_j = d0 + theta . r_j`` and, by Sneddon's cone
    solution, carries ``P_j = (2/pi) E* tan(alpha) max(d_j, 0)^2``. Force and
    moment balance of the feeler (load point a lever arm ``h`` above the cone
    tips) give

    .. math:: \sum_j P_j = F_z, \qquad \sum_j P_j r_j = h F_t .

    Dividing by ``F_z`` leaves the centre of pressure ``c = h F_t / F_z``;
    writing ``P_j = F_z w_j``, ``w_j = max(beta + b . r_j / rho, 0)^2`` (the
    scaled compressions), the three unknowns solve ``sum w_j = 1``,
    ``sum_j w_j r_j = c``: the stationarity conditions of a convex
    function, minimised by a vectorised Newton method.
    Cones with ``d_j <= 0`` lift off. ``c`` must lie inside the polygon of
    cone centres; beyond ``TIP_MARGIN`` of it the feeler tips, ``c`` is capped
    there and ``tipped`` is set. ``F_z`` includes the sensor's preload;
    ``F_z <= 0`` (pull) gives no load at all.
    """
    f = check_forces(forces, sensor)
    fz = f[:, 2] + sensor.preload
    loaded = fz > 0
    n = sensor.n_elements
    rho = sensor.cone_circle_radius
    unit = sensor.cone_offsets / rho  # (K, 2)

    # c = h F_t / F_z, capped at the tip limit; compared as h |F_t| > limit F_z so that a
    # vanishing F_z (down to subnormal) cannot overflow the ratio.
    ft = np.hypot(f[:, 0], f[:, 1])
    limit = TIP_MARGIN * _support_radius(sensor, np.arctan2(f[:, 1], f[:, 0]))
    tipped = loaded & (sensor.lever_arm * ft > limit * np.where(loaded, fz, 0.0))
    c = np.zeros((n, 2))
    free = loaded & ~tipped
    c[free] = sensor.lever_arm * f[free, :2] / fz[free, None]
    c[tipped] = f[tipped, :2] / ft[tipped, None] * limit[tipped, None]  # |f / ft| <= 1

    loads = fz[:, None] * _pressure_weights(c / rho, unit)
    loads[~loaded] = 0.0
    return loads, tipped


def contact_patches(sensor: DomeSensor, forces) -> Contacts:
    r"""Compute every conical feeler's contact patch on the dome.

    Parameters
    ----------
    sensor : DomeSensor
    forces : (N, 3) array_like
        Element-local forces ``(Fx, Fy, Fz)`` in N.

    Returns
    -------
    Contacts

    Notes
    -----
    Loads per cone come from :func:`cone_loads`. Sneddon's solution for a cone
    of semi-apex angle ``alpha`` on a flat gives a contact area linear in load,

    .. math:: A_j = \pi a_j^2 = 2 P_j \tan\alpha / E^*, \qquad E^* = E / (1 - \nu^2),

    capped at the cone's base area ``pi r_base^2`` (fully flattened:
    ``saturated``). The patches slide rigidly along the shear by
    ``s = F_t / \sum_j k_j`` with Mindlin's tangential stiffness of a circular
    contact ``k_j = 8 G^* a_j``, ``G^* = G / (2 - \nu)``, capped at half a great
    circle (``pi R``; only a tipped feeler under a vanishing normal load gets
    there). Patch centres are the cone offsets plus the slide, mapped onto
    the outer surface with :meth:`DomeSensor.dome_point`.

    Examples
    --------
    >>> import numpy as np
    >>> s = DomeSensor.default()
    >>> f = np.zeros((41, 3)); f[0, 2] = 1.0
    >>> c = contact_patches(s, f)
    >>> bool(np.allclose(c.area_mm2[0].sum(), 2 * 1.0 * np.tan(s.cone_half_angle) / s.effective_modulus))
    True
    """
    loads, tipped = cone_loads(sensor, forces)
    f = np.asarray(forces, dtype=np.float64)
    area = 2.0 * loads * np.tan(sensor.cone_half_angle) / sensor.effective_modulus
    max_area = np.pi * sensor.cone_base_radius**2
    saturated = area > max_area
    radii = np.sqrt(np.minimum(area, max_area) / np.pi)

    g_star = sensor.shear_modulus / (2.0 - sensor.poisson_ratio)
    stiffness = 8.0 * g_star * radii.sum(axis=1)  # N/mm
    slide = np.zeros((sensor.n_elements, 2))
    touching = stiffness > 0
    slide[touching] = f[touching, :2] / stiffness[touching, None]
    # Half a great circle is as far as geodesic coordinates reach: only a feeler far outside the
    # model (a shear on a vanishing normal load, which tips it) slides that far; capped there.
    mag = np.hypot(slide[:, 0], slide[:, 1])
    far = mag > np.pi * sensor.outer_radius
    slide[far] *= (np.pi * sensor.outer_radius / mag[far])[:, None]

    offsets = sensor.cone_offsets[None, :, :] + slide[:, None, :]
    element = np.broadcast_to(np.arange(sensor.n_elements)[:, None], radii.shape)
    centers = sensor.dome_point(element, offsets)
    return Contacts(centers=centers, radii=radii, loads=loads, saturated=saturated,
                    tipped=tipped, slide=slide)
