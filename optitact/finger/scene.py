"""The finger's scene: a table and objects on it, the dome's feelers pressed against them, frames.

* :class:`Table`, :class:`Cylinder`, :class:`Box` -- objects with a
  penetration depth and outward normal for world points.
* :func:`feeler_tips` and :func:`feeler_forces` -- a penalty contact model of
  the dome's columnar feelers against the objects.
* :func:`world_from_local` / :func:`local_from_world` -- element-local forces
  and world force vectors, through the sensor's pose
  (:func:`optitact.optics.force_frames.global_from_local` and the pose's rotation).
* :func:`sliding_friction` -- a specimen's kinetic friction coefficient with a
  mild speed dependence.

Convention
----------
World frame: ``(x, y, z)`` in mm, ``z`` up, the table top at ``z = 0`` in the
experiments. A sensor pose is ``(rotation, origin)``: a sensor-frame point
``q`` is at ``origin + rotation @ q`` in the world
(:meth:`optitact.finger.kinematics.Finger.sensor_pose`). Element-local forces as
everywhere in optitact (``Fz`` > 0 presses the element onto the dome).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from optitact._validate import finite, positive, real_array, real_number
from optitact.errors import ShapeError
from optitact.optics.sensor import DomeSensor
from optitact.finger.kinematics import as_point

__all__ = ["Table", "Cylinder", "Box", "feeler_tips", "feeler_forces", "world_from_local", "local_from_world",
           "sliding_friction"]


@dataclass(frozen=True)
class Table:
    """A horizontal table top at height ``z`` (mm); its outward normal is +z."""

    z: float = 0.0

    def penetration(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth (mm, >= 0) of world points below the top, and the outward normals (n, 3)."""
        depth = np.maximum(self.z - points[:, 2], 0.0)
        return depth, np.broadcast_to(np.array([0.0, 0.0, 1.0]), points.shape).copy()


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder standing on the table (mm): centre ``(x, y)``, radius, height."""

    center: tuple = (200.0, 0.0)
    radius: float = 20.0
    height: float = 60.0

    def signed_distance(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """2-D signed distance of points (n, 2) to the outline (negative inside) and outward normals."""
        q = np.atleast_2d(np.asarray(xy, float)) - np.asarray(self.center)
        r = np.hypot(q[:, 0], q[:, 1])
        n = q / np.where(r > 0, r, 1.0)[:, None]
        n[r == 0] = (1.0, 0.0)
        return r - self.radius, n

    def penetration(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth (mm, >= 0) of world points inside the solid, and the outward normals (n, 3)."""
        return _prism_penetration(self, points)

    def outline(self, n: int = 256) -> np.ndarray:
        """Closed outline, (n + 1, 2) mm."""
        a = np.linspace(0.0, 2.0 * np.pi, n + 1)
        return np.asarray(self.center) + self.radius * np.stack([np.cos(a), np.sin(a)], axis=1)

    @property
    def corners(self) -> np.ndarray:
        """No corners: shape (0, 2)."""
        return np.zeros((0, 2))


@dataclass(frozen=True)
class Box:
    """A box standing on the table (mm): centre ``(x, y)``, size ``(lx, ly)``, yaw angle (deg), height."""

    center: tuple = (200.0, 0.0)
    size: tuple = (40.0, 30.0)
    angle_deg: float = 45.0
    height: float = 60.0

    def _rot(self) -> np.ndarray:
        a = math.radians(self.angle_deg)
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    def signed_distance(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """2-D signed distance of points (n, 2) to the outline (negative inside) and outward normals."""
        rot = self._rot()
        q = (np.atleast_2d(np.asarray(xy, float)) - np.asarray(self.center)) @ rot
        half = np.asarray(self.size) / 2.0
        dd = np.abs(q) - half
        outside = np.maximum(dd, 0.0)
        dist_out = np.hypot(outside[:, 0], outside[:, 1])
        inside = np.minimum(np.max(dd, axis=1), 0.0)
        dist = np.where(dist_out > 0, dist_out, inside)
        sgn = np.where(q >= 0, 1.0, -1.0)
        n_out = outside * sgn
        axis = np.argmax(dd, axis=1)
        n_in = np.zeros_like(q)
        n_in[np.arange(len(q)), axis] = sgn[np.arange(len(q)), axis]
        n = np.where((dist_out > 0)[:, None], n_out / np.where(dist_out > 0, dist_out, 1.0)[:, None], n_in)
        return dist, n @ rot.T

    def penetration(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth (mm, >= 0) of world points inside the solid, and the outward normals (n, 3)."""
        return _prism_penetration(self, points)

    @property
    def corners(self) -> np.ndarray:
        """The four vertical edges' positions, (4, 2) mm, counter-clockwise."""
        hx, hy = np.asarray(self.size) / 2.0
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return np.asarray(self.center) + local @ self._rot().T

    def outline(self, n: int = 256) -> np.ndarray:
        """Closed outline, (5, 2) mm (``n`` is ignored)."""
        c = self.corners
        return np.vstack([c, c[:1]])


def _prism_penetration(obj, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Penetration of points into a vertical prism on the table (side walls only; the top is not probed)."""
    dist, n2 = obj.signed_distance(points[:, :2])
    inside = (dist < 0) & (points[:, 2] >= 0.0) & (points[:, 2] <= obj.height)
    depth = np.where(inside, -dist, 0.0)
    return depth, np.concatenate([n2, np.zeros((len(points), 1))], axis=1)


def _rotation(value, name: str = "rotation") -> np.ndarray:
    rot = finite(real_array(value, name), name)
    if rot.shape != (3, 3):
        raise ShapeError(f"{name} must have shape (3, 3), got {rot.shape}")
    return rot


def feeler_tips(sensor: DomeSensor, rotation, origin, *, feeler_height: float = 1.0) -> np.ndarray:
    """World positions (N, 3) of the columnar feelers' tips (mm) for a sensor pose.

    The tip of element ``i`` is at ``(R + h) e_i`` in the sensor frame (``e_i``
    its outward normal, ``R`` the dome's outer radius, ``h`` =
    ``feeler_height``), moved into the world by ``rotation`` and ``origin``.
    """
    rot, org = _rotation(rotation), as_point(origin, "origin")
    h = positive(feeler_height, "feeler_height", allow_zero=True)
    return org + ((sensor.outer_radius + h) * sensor.element_frames[:, 2, :]) @ rot.T


def feeler_forces(sensor: DomeSensor, rotation, origin, objects, *, stiffness: float = 0.5,
                  feeler_height: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Element-local forces of the dome pressed against objects: one penalty spring per feeler.

    Parameters
    ----------
    sensor : DomeSensor
    rotation, origin : (3, 3), (3,) array_like
        Sensor pose in the world (:meth:`Finger.sensor_pose`).
    objects : sequence
        :class:`Table`, :class:`Cylinder`, :class:`Box` (anything with
        ``penetration(points) -> (depth, normal)``).
    stiffness : float
        Contact stiffness per feeler (N/mm), default 0.5: feeler rubber and
        object compliance in series.
    feeler_height : float
        How far the columnar feelers stand out of the dome (mm), default 1.

    Returns
    -------
    forces : (N, 3) ndarray
        Element-local forces (N).
    tips : (N, 3) ndarray
        World positions of the feeler tips (mm).

    Notes
    -----
    Each element's columnar feeler is a point probe at ``(R + h) e_i`` in
    the sensor frame (``e_i`` its outward normal, ``R`` the dome's outer
    radius, ``h`` = ``feeler_height``). A tip ``delta`` mm inside an object is
    pushed out along the object's outward normal ``n`` with
    ``F = k delta n`` (frictionless: the contact force is normal to the
    object's surface); the force is rotated into the sensor frame and split
    into the element's normal (compression ``Fz``) and shear with
    :func:`optitact.optics.force_frames.local_from_global`. Between feelers the dome
    itself is not tested for contact (the tips stand out by more than the
    sag between neighbours, 0.3 mm on the default dome).
    """
    from optitact.optics.force_frames import local_from_global

    k = positive(stiffness, "stiffness")
    tips = feeler_tips(sensor, rotation, origin, feeler_height=feeler_height)
    total = np.zeros((sensor.n_elements, 3))
    for obj in objects:
        depth, n = obj.penetration(tips)
        total += (k * depth)[:, None] * n
    return local_from_global(sensor, total @ _rotation(rotation)), tips


def world_from_local(sensor: DomeSensor, forces, rotations) -> np.ndarray:
    """World force vectors on the elements (T, N, 3) from element-local forces and sensor rotations.

    Parameters
    ----------
    sensor : DomeSensor
    forces : (T, N, 3) array_like
        Element-local forces (N) of ``T`` frames.
    rotations : (T, 3, 3) array_like
        The sensor's rotation in the world in each frame.

    Notes
    -----
    :func:`optitact.optics.force_frames.global_from_local` per frame (sensor frame), then
    the frame's rotation: ``F_world = R F_sensor``.
    """
    from optitact.optics.force_frames import global_from_local

    f = real_array(forces, "forces")
    if f.ndim != 3:
        raise ShapeError(f"forces must have shape (T, N, 3), got {f.shape}")
    rot = _rotations(rotations, len(f))
    f_s = np.stack([global_from_local(sensor, ft) for ft in f]) if len(f) else f
    return np.einsum("tij,tnj->tni", rot, f_s)


def local_from_world(sensor: DomeSensor, forces_world, rotations) -> np.ndarray:
    """Inverse of :func:`world_from_local`: element-local forces (T, N, 3) from world force vectors."""
    from optitact.optics.force_frames import local_from_global

    w = real_array(forces_world, "forces_world")
    if w.ndim != 3:
        raise ShapeError(f"forces_world must have shape (T, N, 3), got {w.shape}")
    rot = _rotations(rotations, len(w))
    f_s = np.einsum("tij,tni->tnj", rot, w)
    return np.stack([local_from_global(sensor, ft) for ft in f_s]) if len(f_s) else f_s


def _rotations(value, n: int) -> np.ndarray:
    rot = finite(real_array(value, "rotations"), "rotations")
    if rot.shape != (n, 3, 3):
        raise ShapeError(f"rotations must have shape ({n}, 3, 3) (one per frame), got {rot.shape}")
    return rot


def sliding_friction(mu, speed, *, reference_speed: float = 6.2, coefficient: float = 0.01) -> float:
    r"""Kinetic friction coefficient with a mild (logarithmic) speed dependence.

    ``mu_k(v) = mu (1 + c ln(v / v_ref))``: ``mu`` at ``v_ref`` (mm/s),
    changing by ``c mu`` per e-fold of speed (default ``c`` = 0.01, i.e.
    -1.5 % at 1.4 mm/s and +1.4 % at 25 mm/s around 6.2 mm/s), the weak
    velocity strengthening of rubber on smooth surfaces.

    Examples
    --------
    >>> round(sliding_friction(0.4, 6.2), 6)
    0.4
    """
    mu = positive(mu, "mu")
    v = positive(speed, "speed")
    v_ref = positive(reference_speed, "reference_speed")
    c = real_number(coefficient, "coefficient")
    return mu * (1.0 + c * math.log(v / v_ref))

