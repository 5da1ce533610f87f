"""The dome sensor on a 3-degree-of-freedom robotic finger: kinematics, the simulated chain, experiments.

The finger of the sensor's inventors: three revolute joints (a yaw joint and
two pitch joints) on a vertical z-stage, with the dome sensor at the
fingertip. Here it is simulated end to end -- every force the experiments
use is *estimated* from rendered camera frames through the real chain
(contact model -> render -> CCD -> pipeline -> calibration), never read
from the simulated truth:

* :class:`Finger` -- forward kinematics from Denavit-Hartenberg parameters
  (base tilts ``phi1``, ``phi2``), the Jacobian, and resolved motion rate
  control with a condition-number check or damped least squares.
* :class:`ChainSimulator` -- element forces -> estimated forces, frame by
  frame (cached no-load baseline, only the loaded elements' pixels
  rendered).
* :class:`Table`, :class:`Cylinder`, :class:`Box` and :func:`feeler_forces`
  -- a penalty contact model of the dome's feelers against objects.
* Experiments, each a function returning a JSON-ready dict, with a plot:
  :func:`surface_scanning` (friction coefficient of specimens),
  :func:`slip_experiment` (slip while pushing a block along a rectangle) and
  :func:`contour_tracing` (a cylinder and a box on a table); all three
  together with :func:`experiment` / :func:`plot_experiment` (``optitact
  experiment finger``).

Convention
----------
World frame: ``(x, y, z)`` in mm, ``z`` up, the table top at ``z = 0`` in the
experiments. The sensor frame is :mod:`optitact.sensor`'s (origin at the
dome's base-circle centre, ``z`` towards the apex); the finger carries it
with ``z_s`` along the last link and ``x_s`` along the last joint axis.
Element-local forces as everywhere in optitact (``Fz`` > 0 presses the
element onto the dome). Joint angles in radians, forces in N, times in s.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ._validate import finite, integer, positive, real_array, seed_value
from .camera import FisheyeCamera
from .ccd import CCD
from .errors import InputError, ShapeError
from .sensor import DomeSensor

__all__ = ["UnreachableError", "SingularityError", "Finger", "RMRCResult", "ChainSimulator",
           "ChainEstimate", "Table", "Cylinder", "Box", "feeler_forces", "sliding_friction",
           "surface_scanning", "slip_experiment", "contour_tracing", "experiment",
           "plot_surface_scanning", "plot_slip", "plot_contour", "plot_experiment", "joint_error_study",
           "plot_joint_error_study", "PUBLISHED_DEVIATION_MM",
           "extended_calibration"]


class UnreachableError(InputError):
    """A target position lies outside the finger's workspace (or RMRC did not reach it)."""


class SingularityError(InputError):
    """The Jacobian is (nearly) singular on the way to a target: its condition number is too large."""


# ============================================================================ kinematics
def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _triple(value, name: str, *, allow_negative: bool = True) -> tuple[float, float, float]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise TypeError(f"{name} must be a sequence of 3 numbers (one per joint), got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise TypeError(f"{name}[{i}] must be a real number, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v) or (not allow_negative and v < 0):
            raise InputError(f"{name}[{i}] must be finite{'' if allow_negative else ' and >= 0'}, got {v!r}")
        out.append(v)
    return tuple(out)


def _real(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite, got {v!r}")
    return v


def _joints(theta, name: str = "theta") -> np.ndarray:
    th = finite(real_array(theta, name), name)
    if th.shape != (3,):
        raise ShapeError(f"{name} must have shape (3,) (one angle per joint, rad), got {th.shape}")
    return th


def _rmrc_options(tol, max_iter, max_step, cond_max) -> tuple[float, int, float | None, float]:
    """Validated ``tol``, ``max_iter``, ``max_step`` (None allowed) and ``cond_max`` of an RMRC call."""
    return (positive(tol, "tol"), integer(max_iter, "max_iter", minimum=1),
            None if max_step is None else positive(max_step, "max_step"), positive(cond_max, "cond_max"))


def _direction(value, name: str = "direction") -> np.ndarray:
    d = finite(real_array(value, name), name)
    if d.shape != (3,):
        raise ShapeError(f"{name} must have shape (3,) (a world direction), got {d.shape}")
    n = float(np.linalg.norm(d))
    if not n > 0:
        raise InputError(f"{name} must be a non-zero vector, got {d.tolist()}")
    return d / n


def _point(value, name: str) -> np.ndarray:
    p = finite(real_array(value, name), name)
    if p.shape != (3,):
        raise ShapeError(f"{name} must have shape (3,) (x, y, z in mm), got {p.shape}")
    return p


@dataclass(frozen=True)
class RMRCResult:
    """Outcome of :meth:`Finger.rmrc`.

    Attributes
    ----------
    theta : (3,) ndarray
        Joint angles reached (rad).
    position : (3,) ndarray
        Tool point there (mm).
    error : float
        ``|r_d - r|`` at the end (mm).
    iterations : int
        Updates made.
    condition : float
        Condition number of the Jacobian at the end.
    path : (k + 1, 3) ndarray
        Tool positions visited, start first.
    """

    theta: np.ndarray
    position: np.ndarray
    error: float
    iterations: int
    condition: float
    path: np.ndarray = field(repr=False)
    z: float = 0.0


@dataclass(frozen=True, kw_only=True)
class Finger:
    r"""A 3-joint finger on a vertical z-stage, from Denavit-Hartenberg parameters.

    Parameters
    ----------
    a : 3 floats
        Link lengths ``a_i`` (mm), default ``(0, 100, 80)``.
    d : 3 floats
        Link offsets ``d_i`` (mm), default ``(0, 0, 0)``.
    alpha_deg : 3 floats
        Link twists ``alpha_i`` (deg), default ``(90, 0, 0)``: joint 1 is a
        yaw joint about the stage's vertical, joints 2 and 3 pitch joints.
    theta_offset_deg : 3 floats
        Joint zero offsets (deg) added to the joint angles, default 0.
    phi1_deg, phi2_deg : float
        Base tilts (deg): the finger's base is rotated by ``phi1`` about the
        world x axis, then by ``phi2`` about the (tilted) y axis; default 0.
    base : 3 floats
        Base position (mm) when the z-stage reads 0, default the origin.
    tool : float
        Tool point along the last link beyond joint frame 3 (mm), default
        20: the dome's apex (``DomeSensor.default().outer_radius``), with
        the dome's base-circle centre at frame 3's origin.

    Notes
    -----
    Standard DH: ``T_i = Rz(theta_i + offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
    and ``T = Tz(z_stage) T(base) Rx(phi1) Ry(phi2) T_1 T_2 T_3``. The tool
    point is ``T (tool, 0, 0, 1)``; the sensor frame has ``z_s = x_3``
    (along the last link), ``x_s = z_3`` (the last joint axis) and ``y_s =
    z_s x x_s``. The Jacobian of the tool point is geometric,
    ``J_i = z_{i-1} x (p - o_{i-1})`` (revolute joints), equal to the
    derivative of :meth:`forward` (tested against finite differences).

    Resolved motion rate control (:meth:`rmrc`) iterates
    ``theta_{k+1} = theta_k + J^{-1} (r_d - r_k)`` until
    ``|r_d - r_k| < tol``; each Cartesian correction is limited to
    ``max_step`` mm so the linearisation holds on long moves.

    Examples
    --------
    >>> import numpy as np
    >>> f = Finger()
    >>> np.round(f.forward([0.0, 0.0, 0.0]), 6)          # stretched out along x
    array([200.,   0.,   0.])
    >>> r = f.rmrc([150.0, 20.0, -40.0], [0.0, 0.3, -1.0])
    >>> bool(r.error < 1e-3)
    True
    """

    a: tuple = (0.0, 100.0, 80.0)
    d: tuple = (0.0, 0.0, 0.0)
    alpha_deg: tuple = (90.0, 0.0, 0.0)
    theta_offset_deg: tuple = (0.0, 0.0, 0.0)
    phi1_deg: float = 0.0
    phi2_deg: float = 0.0
    base: tuple = (0.0, 0.0, 0.0)
    tool: float = 20.0

    def __post_init__(self) -> None:
        for name in ("a", "d", "alpha_deg", "theta_offset_deg", "base"):
            object.__setattr__(self, name, _triple(getattr(self, name), name))
        object.__setattr__(self, "phi1_deg", _real(self.phi1_deg, "phi1_deg"))
        object.__setattr__(self, "phi2_deg", _real(self.phi2_deg, "phi2_deg"))
        object.__setattr__(self, "tool", _real(self.tool, "tool"))

    def to_dict(self) -> dict:
        """JSON-friendly parameters."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    # ------------------------------------------------------------------ frames
    def _base(self, z: float) -> np.ndarray:
        t = np.eye(4)
        t[:3, :3] = _rot_x(math.radians(self.phi1_deg)) @ _rot_y(math.radians(self.phi2_deg))
        t[:3, 3] = np.asarray(self.base) + (0.0, 0.0, z)
        return t

    def frames(self, theta, *, z: float = 0.0) -> np.ndarray:
        """World transforms of the base and joint frames 1-3, shape (4, 4, 4).

        Parameters
        ----------
        theta : (3,) array_like
            Joint angles (rad).
        z : float
            z-stage position (mm).
        """
        th = _joints(theta)
        z = _real(z, "z")
        out = np.empty((4, 4, 4))
        t = self._base(z)
        out[0] = t
        for i in range(3):
            q = th[i] + math.radians(self.theta_offset_deg[i])
            ca, sa = math.cos(math.radians(self.alpha_deg[i])), math.sin(math.radians(self.alpha_deg[i]))
            cq, sq = math.cos(q), math.sin(q)
            a = np.array([[cq, -sq * ca, sq * sa, self.a[i] * cq],
                          [sq, cq * ca, -cq * sa, self.a[i] * sq],
                          [0.0, sa, ca, self.d[i]],
                          [0.0, 0.0, 0.0, 1.0]])
            t = t @ a
            out[i + 1] = t
        return out

    def forward(self, theta, *, z: float = 0.0) -> np.ndarray:
        """Tool point (mm), shape (3,), for joint angles ``theta`` (rad) and z-stage ``z`` (mm)."""
        t = self.frames(theta, z=z)[3]
        return t[:3, 3] + self.tool * t[:3, 0]

    def sensor_pose(self, theta, *, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (3, 3) and origin (3,) of the sensor frame in the world.

        The columns of the rotation are the sensor's ``x_s, y_s, z_s`` axes
        (see the class *Notes*); a sensor-frame point ``q`` is at
        ``origin + R @ q`` in the world.
        """
        t = self.frames(theta, z=z)[3]
        zs, xs = t[:3, 0], t[:3, 2]
        return np.stack([xs, np.cross(zs, xs), zs], axis=1), t[:3, 3].copy()

    def jacobian(self, theta, *, z: float = 0.0) -> np.ndarray:
        """Jacobian ``d forward / d theta`` (mm/rad), shape (3, 3); column ``i`` for joint ``i``."""
        fr = self.frames(theta, z=z)
        p = fr[3][:3, 3] + self.tool * fr[3][:3, 0]
        return np.stack([np.cross(fr[i][:3, 2], p - fr[i][:3, 3]) for i in range(3)], axis=1)

    # ------------------------------------------------------------------ inverse
    def _reach(self) -> tuple[float, float] | None:
        """Shoulder-to-tool distance range of the standard yaw-pitch-pitch structure, else None."""
        if (self.a[0] == 0.0 and self.d[1] == 0.0 and self.d[2] == 0.0 and self.alpha_deg[1] == 0.0
                and self.alpha_deg[2] == 0.0 and abs(abs(self.alpha_deg[0]) - 90.0) < 1e-12):
            l2, l3 = abs(self.a[1]), abs(self.a[2] + self.tool)
            return abs(l2 - l3), l2 + l3
        return None

    def rmrc(self, target, theta0, *, z: float = 0.0, tol: float = 1e-3, max_iter: int = 200,
             max_step: float | None = 10.0, cond_max: float = 1e4, damping: float = 0.0) -> RMRCResult:
        r"""Resolved motion rate control to a target position of the tool point.

        Parameters
        ----------
        target : (3,) array_like
            Desired tool position ``r_d`` (mm, world).
        theta0 : (3,) array_like
            Starting joint angles (rad).
        z : float
            z-stage position (mm), held fixed.
        tol : float
            Stop when ``|r_d - r_k| < tol`` (mm), default 1e-3.
        max_iter : int
            Most updates, default 200.
        max_step : float or None
            Largest Cartesian correction per update (mm), default 10; None
            applies the full ``r_d - r_k`` every time (the plain formula).
        cond_max : float
            Largest condition number of ``J`` accepted with ``damping = 0``
            (default 1e4).
        damping : float
            0 (default): ``delta = J^{-1} e``, refusing a near-singular ``J``.
            ``lambda > 0`` (mm): damped least squares,
            ``delta = J^T (J J^T + lambda^2 I)^{-1} e``, which stays bounded
            through singularities (at the price of slower convergence near
            them); no condition check.

        Returns
        -------
        RMRCResult

        Raises
        ------
        UnreachableError
            The target is farther from the shoulder than the stretched
            finger reaches, or nearer than the folded finger allows (checked
            first, for the standard yaw-pitch-pitch structure), or the
            iteration did not reach ``tol`` in ``max_iter`` updates.
        SingularityError
            With ``damping = 0``: ``cond(J) > cond_max`` at some iterate
            (e.g. a stretched arm, or a target on the yaw axis).
        TypeError, ShapeError, InputError
            Bad arguments.

        Notes
        -----
        With ``e_k = r_d - r_k`` (scaled to ``max_step`` when longer), the
        update is ``theta_{k+1} = theta_k + J(theta_k)^{-1} e_k``: Newton's
        method on the forward map, quadratically convergent near a regular
        solution. Which of the (up to four) solutions is reached depends on
        ``theta0``.
        """
        rd = _point(target, "target")
        th = _joints(theta0, "theta0").copy()
        z = _real(z, "z")
        tol, max_iter, max_step, cond_max = _rmrc_options(tol, max_iter, max_step, cond_max)
        damping = positive(damping, "damping", allow_zero=True)
        reach = self._reach()
        if reach is not None:
            shoulder = self.frames(th, z=z)[1][:3, 3]
            dist = float(np.linalg.norm(rd - shoulder))
            lo, hi = reach
            if dist > hi + tol or dist < lo - tol:
                raise UnreachableError(
                    f"target {np.round(rd, 3).tolist()} mm is {dist:.3f} mm from the shoulder; the finger "
                    f"reaches {lo:.3f} to {hi:.3f} mm (z-stage at {z:g} mm)")
        path = [self.forward(th, z=z)]
        cond = float("nan")
        for k in range(max_iter + 1):
            e = rd - path[-1]
            err = float(np.linalg.norm(e))
            jac = self.jacobian(th, z=z)
            cond = float(np.linalg.cond(jac))
            if err < tol:
                if damping == 0.0 and not cond <= cond_max:
                    raise SingularityError(
                        f"the target {np.round(rd, 3).tolist()} mm is reached only in a near-singular pose "
                        f"(condition number {cond:.3g} > cond_max {cond_max:g}, e.g. on the yaw axis or with "
                        f"the finger stretched): the joints there are undetermined")
                return RMRCResult(theta=th, position=path[-1], error=err, iterations=k, condition=cond,
                                  path=np.array(path), z=z)
            if k == max_iter:
                break
            if max_step is not None and err > max_step:
                e = e * (max_step / err)
            if damping == 0.0:
                if not cond <= cond_max:
                    raise SingularityError(
                        f"the Jacobian is near-singular at theta = {np.round(th, 4).tolist()} rad "
                        f"(condition number {cond:.3g} > cond_max {cond_max:g}) on the way to "
                        f"{np.round(rd, 3).tolist()} mm; use damping > 0 (damped least squares) or "
                        f"another start")
                step = np.linalg.solve(jac, e)
            else:
                step = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(3), e)
            th = th + step
            path.append(self.forward(th, z=z))
        raise UnreachableError(f"RMRC did not reach {np.round(rd, 3).tolist()} mm within {max_iter} updates "
                               f"(residual {err:.3g} mm > tol {tol:g} mm; condition number {cond:.3g})")

    # ------------------------------------------------------------------ with the z-stage: hold the lean
    def lean(self, theta, *, z: float = 0.0, direction=(1.0, 0.0, 0.0)) -> float:
        """Lean of the sensor axis from straight down towards ``direction`` (rad): ``asin(z_s . d)``."""
        d = _direction(direction)
        return float(math.asin(np.clip(self.sensor_pose(theta, z=z)[0][:, 2] @ d, -1.0, 1.0)))

    def jacobian_stage(self, theta, *, z: float = 0.0, direction=(1.0, 0.0, 0.0)) -> np.ndarray:
        """Jacobian (4, 4) of ``(tool point, z_s . d)`` with respect to ``(theta_1..3, z-stage)``.

        Rows 0-2: the tool point (mm per rad, and 1 per mm of stage); row 3: the
        sensor axis's component along the horizontal unit ``direction`` (per rad;
        the stage does not turn it). Tested against finite differences.
        """
        d = _direction(direction)
        fr = self.frames(theta, z=z)
        zs = fr[3][:3, 0]
        jac = np.zeros((4, 4))
        jac[:3, :3] = self.jacobian(theta, z=z)
        jac[2, 3] = 1.0
        jac[3, :3] = [np.cross(fr[i][:3, 2], zs) @ d for i in range(3)]
        return jac

    def rmrc_lean(self, target, lean_deg: float, theta0, *, z0: float = 0.0, direction=(1.0, 0.0, 0.0),
                  tol: float = 1e-3, max_iter: int = 200, max_step: float | None = 10.0,
                  cond_max: float = 1e4, length_scale: float = 100.0) -> RMRCResult:
        r"""Resolved motion rate control with the z-stage as a fourth axis, holding the sensor's lean.

        Three joints place the tool point but leave the sensor's orientation to
        follow; with the z-stage as a fourth (prismatic) axis the finger can
        also hold the sensor axis leaning ``lean_deg`` from straight down
        towards ``direction`` -- e.g. constant along a friction-scanning stroke.

        Parameters
        ----------
        target : (3,) array_like
            Desired tool position (mm, world).
        lean_deg : float
            Desired lean (deg), ``z_s . d = sin(lean)``; in (-90, 90).
        theta0 : (3,) array_like
            Starting joint angles (rad).
        z0 : float
            Starting z-stage position (mm).
        direction : (3,) array_like
            Horizontal direction of the lean (normalised), default +x.
        tol : float
            Stop when ``|r_d - r| < tol`` (mm) and the lean is within
            ``tol / length_scale`` rad.
        max_iter, max_step, cond_max
            As in :meth:`rmrc` (``max_step`` bounds the Cartesian part).
        length_scale : float
            Millimetres per radian of lean in the error norm and the
            condition number (default 100, the finger's link scale).

        Returns
        -------
        RMRCResult
            With the stage position reached in ``z``.

        Raises
        ------
        SingularityError
            ``cond`` of the scaled 4x4 Jacobian exceeds ``cond_max`` (e.g.
            the second link vertical over the stroke, where holding the lean
            leaves no way to move horizontally).
        UnreachableError
            Not converged within ``max_iter`` updates.
        TypeError, ShapeError, InputError
            Bad arguments.

        Notes
        -----
        Newton's method on ``(r, z_s . d)`` as functions of ``(theta, z)``:
        ``(theta, z)_{k+1} = (theta, z)_k + J_4^{-1} e_k`` with
        ``J_4`` = :meth:`jacobian_stage` and ``e_k`` the position and
        lean errors (the lean row scaled by ``length_scale``).
        """
        rd = _point(target, "target")
        lean = _real(lean_deg, "lean_deg")
        if not -90.0 < lean < 90.0:
            raise InputError(f"lean_deg must be in (-90, 90) degrees, got {lean!r}")
        sd = math.sin(math.radians(lean))
        d = _direction(direction)
        th = _joints(theta0, "theta0").copy()
        z = _real(z0, "z0")
        tol, max_iter, max_step, cond_max = _rmrc_options(tol, max_iter, max_step, cond_max)
        ls = positive(length_scale, "length_scale")
        w = np.array([1.0, 1.0, 1.0, ls])
        path = [self.forward(th, z=z)]
        cond, err = float("nan"), float("inf")
        for k in range(max_iter + 1):
            s = self.sensor_pose(th, z=z)[0][:, 2] @ d
            e = np.append(rd - path[-1], sd - s) * w
            err = float(np.linalg.norm(e[:3]))
            jac = self.jacobian_stage(th, z=z, direction=d) * w[:, None]
            cond = float(np.linalg.cond(jac))
            if not cond <= cond_max:
                raise SingularityError(
                    f"the z-stage Jacobian is near-singular at theta = {np.round(th, 4).tolist()} rad, "
                    f"z = {z:.3f} mm (condition number {cond:.3g} > cond_max {cond_max:g}) on the way to "
                    f"{np.round(rd, 3).tolist()} mm with a {lean:g} deg lean")
            if err < tol and abs(e[3]) < tol:
                return RMRCResult(theta=th, position=path[-1], error=err, iterations=k, condition=cond,
                                  path=np.array(path), z=z)
            if k == max_iter:
                break
            if max_step is not None and np.linalg.norm(e) > max_step:
                e = e * (max_step / np.linalg.norm(e))
            step = np.linalg.solve(jac, e)
            th, z = th + step[:3], z + float(step[3])
            path.append(self.forward(th, z=z))
        raise UnreachableError(f"RMRC with the z-stage did not reach {np.round(rd, 3).tolist()} mm at a "
                               f"{lean:g} deg lean within {max_iter} updates (position residual {err:.3g} mm; "
                               f"condition number {cond:.3g})")


# ============================================================================ objects and contact
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
    :func:`optitact.forces.local_from_global`. Between feelers the dome
    itself is not tested for contact (the tips stand out by more than the
    sag between neighbours, 0.3 mm on the default dome).
    """
    from optitact.forces import local_from_global

    rot = finite(real_array(rotation, "rotation"), "rotation")
    org = _point(origin, "origin")
    if rot.shape != (3, 3):
        raise ShapeError(f"rotation must have shape (3, 3), got {rot.shape}")
    k = positive(stiffness, "stiffness")
    h = positive(feeler_height, "feeler_height", allow_zero=True)
    normals = sensor.element_frames[:, 2, :]
    tips = org + ((sensor.outer_radius + h) * normals) @ rot.T
    total = np.zeros((sensor.n_elements, 3))
    for obj in objects:
        depth, n = obj.penetration(tips)
        total += (k * depth)[:, None] * n
    return local_from_global(sensor, total @ rot), tips


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
    c = _real(coefficient, "coefficient")
    return mu * (1.0 + c * math.log(v / v_ref))


# ============================================================================ the chain
@dataclass(frozen=True)
class ChainEstimate:
    """Estimated element forces of a sequence of frames (see :meth:`ChainSimulator.estimate`).

    Attributes
    ----------
    forces : (T, N, 3) ndarray
        Estimated element-local forces (N); 0 where there is no contact.
    clamped : (T, N) ndarray of bool
        The reading was outside the calibration's fitted range (clamped).
    contact : (T, N) ndarray of bool
        The pipeline found the element in contact.
    truth : (T, N, 3) ndarray
        The forces the frames were rendered from.
    tipped : (T, N) ndarray of bool
        The contact model tipped the feeler (shear beyond what the cones
        balance; see :func:`optitact.contact.cone_loads`).
    readings : optitact.Readings
        Stack readings, e.g. for another calibration.
    seconds : float
        Wall time of the chain.
    """

    forces: np.ndarray
    clamped: np.ndarray
    contact: np.ndarray
    truth: np.ndarray
    tipped: np.ndarray
    readings: object = field(repr=False)
    seconds: float = 0.0

    def __len__(self) -> int:
        return len(self.forces)


class ChainSimulator:
    """Element forces -> estimated forces through the real chain, frame by frame.

    Parameters
    ----------
    calibration : optitact.calib.Calibration, optional
        Default the shipped one (:func:`optitact.calib.default_calibration`);
        it fixes the sensor, camera and pipeline options.
    sensor, camera : optional
        Checked against the calibration's (a mismatch is a
        ``CalibrationMismatchError``).
    ccd : CCD, optional
        Camera noise model, default ``CCD()``.
    spp : int
        Samples per pixel of each frame's render, default 32.
    seed : int
        Seeds the no-load baseline and, with the frame index, every frame.
    baseline_frames : int
        No-load frames of the baseline (default 4), rendered once at
        ``baseline_spp`` (default 64) and cached on disk
        (:func:`optitact._cache.cached_render`; with seed 0 the same frames
        as ``optitact demo``).
    variant : str, optional
        Mitsuba variant.
    render_options : dict, optional
        Extra keywords for :func:`optitact.render.render` (e.g.
        ``{"transport": "two_stage"}``); with the default path tracing only
        the loaded elements' region pixels (:func:`optitact.render.spot_pixels`)
        are rendered, over the mean no-load radiance.

    Notes
    -----
    Frame ``i`` (an index the caller gives, so that closed-loop experiments
    stay reproducible) is rendered and exposed with the seed
    ``SeedSequence([seed, 7, i])``; a frame without loaded elements is the
    no-load radiance, exposed with fresh camera noise. The pipeline is
    ``calibration.pipeline(baseline=...)`` over the exposed no-load frames
    (their mean, and their per-pixel noise for the threshold); forces come
    from ``calibration.forces``.
    """

    def __init__(self, calibration=None, *, sensor: DomeSensor | None = None,
                 camera: FisheyeCamera | None = None, ccd: CCD | None = None, spp: int = 32, seed: int = 0,
                 baseline_frames: int = 4, baseline_spp: int = 64, variant: str | None = None,
                 render_options: dict | None = None) -> None:
        from optitact.calib import Calibration, default_calibration

        cal = default_calibration() if calibration is None else calibration
        if not isinstance(cal, Calibration):
            raise TypeError(f"calibration must be an optitact.calib.Calibration, got {type(cal).__name__}")
        cal.check(sensor, camera)
        self.calibration = cal
        self.sensor, self.camera = cal.sensor, cal.camera
        self.ccd = CCD() if ccd is None else ccd
        if not isinstance(self.ccd, CCD):
            raise TypeError(f"ccd must be a CCD, got {type(self.ccd).__name__}")
        self.spp = integer(spp, "spp", minimum=1)
        seed = seed_value(seed)
        if seed is None:
            raise InputError("seed must be a non-negative integer, got None")
        self.seed = seed
        self.baseline_frames = integer(baseline_frames, "baseline_frames", minimum=1)
        self.baseline_spp = integer(baseline_spp, "baseline_spp", minimum=1)
        self.variant = variant
        if render_options is not None and not isinstance(render_options, dict):
            raise TypeError(f"render_options must be a dict, got {type(render_options).__name__}")
        self.render_options = dict(render_options or {})
        reserved = {"camera", "spp", "seed", "variant"} & set(self.render_options)
        if reserved:
            raise InputError(f"render_options must not set {sorted(reserved)} (ChainSimulator's own options)")
        self._pipe = None
        self._background = None

    def describe(self) -> dict:
        """The chain's settings, JSON-ready."""
        return {"camera": self.camera.to_dict(), "ccd": self.ccd.to_dict(), "spp": self.spp, "seed": self.seed,
                "baseline_frames": self.baseline_frames, "baseline_spp": self.baseline_spp,
                "render_options": {k: v for k, v in self.render_options.items()
                                   if isinstance(v, (str, int, float, bool))},
                "calibration": {"model": self.calibration.model,
                                "fingerprint": self.calibration.fingerprint,
                                "provenance": _jsonable(self.calibration.provenance)}}

    def prepare(self) -> None:
        """Render (or load from the cache) the no-load baseline and build the pipeline; done on first use."""
        if self._pipe is not None:
            return
        from ._cache import cached_render

        zero = np.zeros((self.sensor.n_elements, 3))
        rads, frames = [], []
        for k in range(self.baseline_frames):
            s = self.seed + 1 + k
            rad = cached_render(self.sensor, zero, camera=self.camera, spp=self.baseline_spp, seed=s,
                                variant=self.variant)
            rads.append(rad)
            frames.append(self.ccd.expose(rad, seed=s))
        self._background = np.mean(rads, axis=0).astype(np.float32)
        self._pipe = self.calibration.pipeline(baseline=np.stack(frames))

    def frame_seed(self, index: int) -> int:
        """Render and camera seed of frame ``index``."""
        return int(np.random.SeedSequence([self.seed, 7, int(index)]).generate_state(1)[0])

    def _radiance(self, forces: np.ndarray, seed: int) -> np.ndarray:
        from optitact.render import render, spot_pixels

        opts = dict(self.render_options)
        if opts.get("transport", "path") == "path":
            if not np.any(forces[:, 2] > 0):
                return self._background
            opts.update(pixels=spot_pixels(self.sensor, self.camera, forces), background=self._background)
        return render(self.sensor, forces, camera=self.camera, spp=self.spp, seed=seed, variant=self.variant,
                      **opts)

    def estimate(self, forces, *, first_index: int = 0, progress: bool = False,
                 desc: str = "frames") -> ChainEstimate:
        """Estimated forces of a sequence of element-force frames.

        Parameters
        ----------
        forces : (N, 3) or (T, N, 3) array_like
            Element-local forces (N) of each frame.
        first_index : int
            Index of the first frame (seeds; see the class *Notes*).
        progress : bool
            tqdm bar on stderr.
        desc : str
            The bar's label.

        Returns
        -------
        ChainEstimate
            With a leading frame axis even for a single frame.
        """
        from optitact.contact import check_forces, cone_loads
        from optitact.readings import Readings

        arr = real_array(forces, "forces")
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3:
            raise ShapeError(f"forces must have shape (N, 3) or (T, N, 3), got {arr.shape}")
        for f in arr:
            check_forces(f, self.sensor)
        first_index = integer(first_index, "first_index", minimum=0)
        self.prepare()
        t0 = time.perf_counter()
        rows, tipped = [], np.zeros(arr.shape[:2], bool)
        from tqdm import tqdm

        for i in tqdm(range(len(arr)), desc=desc, unit="frame", file=sys.stderr, disable=not progress,
                      leave=False):
            s = self.frame_seed(first_index + i)
            frame = self.ccd.expose(self._radiance(arr[i], s), seed=s)
            rows.append(self._pipe.process(frame))
            tipped[i] = cone_loads(self.sensor, arr[i])[1]
        readings = Readings.stack(rows)
        est, clamped = self.calibration.forces(readings)
        return ChainEstimate(forces=est, clamped=clamped, contact=readings.contact.copy(), truth=arr.copy(),
                             tipped=tipped, readings=readings, seconds=time.perf_counter() - t0)


def extended_calibration(*, mu_max: float = 0.40, frames: int = 100, spp: int = 64, seed: int = 0,
                         progress: bool = False):
    """A calibration of the default sensor and camera whose shear range reaches ``mu_max`` (cached).

    The shipped calibration's design stops at ``|F_t| / F_z`` = 0.35 and
    clamps centroid shifts beyond its fitted range, which caps an estimated
    friction coefficient at about 0.38 (at 0.1 N). This generates a set
    like the shipped one (:func:`optitact.calib.generate`, two-stage
    transport, ``Design(mu_max=mu_max)``), fits the coupled model and keeps
    the JSON in the cache folder; later calls load it (about 30 s the
    first time once the two-stage table is cached).
    """
    from optitact import calib

    from ._cache import cache_dir

    mu_max = positive(mu_max, "mu_max")
    frames = integer(frames, "frames", minimum=8)
    path = cache_dir() / "finger" / f"calibration_mu{mu_max:g}_f{frames}_spp{spp}_s{seed}.json"
    if path.is_file():
        return calib.Calibration.load(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    store = path.with_suffix(".zarr")
    cset = calib.generate(store, frames=frames, spp=spp, seed=seed, design=calib.Design(mu_max=mu_max),
                          progress=progress)
    cal = calib.fit(cset, model="coupled")
    cal.save(path)
    return cal


# ============================================================================ helpers
def _jsonable(obj):
    """Numpy scalars and arrays (nested in dicts, lists, tuples) as plain Python values."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def _rounded(arr, digits: int = 5) -> list:
    return np.round(np.asarray(arr, float), digits).tolist()


def _chain(chain, seed: int, spp: int = 32) -> ChainSimulator:
    if chain is None:
        return ChainSimulator(spp=spp, seed=seed)
    if not isinstance(chain, ChainSimulator):
        raise TypeError(f"chain must be a ChainSimulator, got {type(chain).__name__}")
    return chain


def _ar1(rng: np.random.Generator, n: int, sigma: float, corr: float) -> np.ndarray:
    """Stationary AR(1) noise of standard deviation ``sigma`` and lag-one correlation ``corr``."""
    out = np.empty(n)
    x = rng.normal(0.0, sigma)
    k = math.sqrt(1.0 - corr**2)
    for i in range(n):
        out[i] = x
        x = corr * x + k * rng.normal(0.0, sigma)
    return out


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _world_forces(sensor: DomeSensor, est: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """World force vectors on the elements (T, N, 3) from element-local forces and sensor rotations."""
    sign = np.array([1.0, 1.0, -1.0])
    f_s = np.einsum("nij,tni->tnj", sensor.element_frames, est * sign)
    return np.einsum("tij,tnj->tni", rotations, f_s)


def _local_forces(sensor: DomeSensor, world: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_world_forces`."""
    sign = np.array([1.0, 1.0, -1.0])
    f_s = np.einsum("tij,tni->tnj", rotations, world)
    return np.einsum("nij,tnj->tni", sensor.element_frames, f_s) * sign


def _follow(finger: Finger, targets: np.ndarray, theta0, *, z0: float = 0.0,
            lean: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sensor rotations (T, 3, 3) and z-stage positions (T,) along tool targets (RMRC, warm-started).

    With ``lean`` (deg) the z-stage is a fourth axis holding the sensor's lean along +x
    (:meth:`Finger.rmrc_lean`), and the finger first walks to the first target in 2 mm steps;
    without it the stage stays at ``z0``.
    """
    th, z = np.asarray(theta0, float), float(z0)

    def reach(p):
        if lean is None:
            return finger.rmrc(p, th, z=z).theta, z
        r = finger.rmrc_lean(p, lean, th, z0=z)
        return r.theta, r.z

    if lean is not None:
        here = finger.forward(th, z=z)
        n_walk = int(np.ceil(np.linalg.norm(targets[0] - here) / 2.0))
        for p in here + np.outer(np.arange(1, n_walk) / n_walk, targets[0] - here):
            th, z = reach(p)
    rots, stage = [], []
    for p in targets:
        th, z = reach(p)
        rots.append(finger.sensor_pose(th, z=z)[0])
        stage.append(z)
    return np.array(rots), np.array(stage)


#: Joint angles (rad) with the sensor axis pointing straight down (pitch -90 deg).
POSE_DOWN = np.radians([0.0, 30.0, -120.0])
#: Joint angles (rad) at the middle of a friction-scanning stroke: the sensor axis 9 deg from
#: straight down towards +x, the second link at 50 deg so that a 62.5 mm radial stroke stays
#: clear of the singular (horizontal) second link.
POSE_SCAN = np.radians([0.0, 50.0, -131.0])
#: Joint angles (rad) of contour tracing: the sensor axis 45 deg below the horizontal.
POSE_TRACE = np.radians([0.0, 20.0, -65.0])


# ============================================================================ 1. surface scanning
def _scan_profile(mu_k: float, speed: float, fn0: float, rate: float, slide_time: float,
                  rng: np.random.Generator) -> dict:
    """Simulated normal and friction force of one scan (force-controlled press, stick, slide, stop, lift)."""
    approach, dwell, stop, unload = 0.4, 0.2, 0.3, 0.25
    static_ratio, k_t, relax, wave, lam = 1.12, 0.5, 0.1, 0.03, 3.0
    n = int(round((approach + dwell + slide_time + stop + unload) * rate)) + 1
    t = np.arange(n) / rate
    t_s = approach + dwell
    t_e = t_s + slide_time
    t_u = t_e + stop
    x = speed * np.clip(t - t_s, 0.0, slide_time)
    press = _smoothstep(t / approach) * (1.0 - _smoothstep((t - t_u) / unload))
    fn = fn0 * press * (1.0 + wave * np.sin(2 * np.pi * x / lam + rng.uniform(0, 2 * np.pi))
                        + _ar1(rng, n, 0.01, 0.5))
    fluct = _ar1(rng, n, 0.02, 0.6)
    ft = np.zeros(n)
    t_on = None
    for i in range(n):
        if t_s < t[i] <= t_e:
            if t_on is None:
                stick = k_t * x[i]
                if stick < static_ratio * mu_k * fn[i]:
                    ft[i] = stick
                    continue
                t_on = t[i]
            ft[i] = mu_k * fn[i] * (1.0 + (static_ratio - 1.0) * math.exp(-(t[i] - t_on) / relax) + fluct[i])
        elif t[i] > t_e:
            last = ft[np.searchsorted(t, t_e, side="right") - 1]
            ft[i] = last * (0.5 + 0.5 * math.exp(-(t[i] - t_e) / relax)) * press[i] / max(press.max(), 1e-12)
    return {"t": t, "fn": fn, "ft": ft, "x": x, "t_slide": (t_s, t_e), "t_slip": t_on}


def surface_scanning(*, chain: ChainSimulator | None = None, frictions=(0.39, 0.40, 0.53),
                     speeds=(1.4, 6.2, 25.0), normal_force: float = 0.1, frame_rate: float = 20.0,
                     slide_time: float = 2.5, speed_coefficient: float = 0.01, tolerance: float = 0.02,
                     lean_deg: float = 9.0, finger: Finger | None = None, seed: int = 0,
                     progress: bool = True) -> dict:
    r"""Friction coefficients of flat specimens scanned by the apex element, from estimated forces.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)`` (shipped calibration, 640x480,
        32 spp).
    frictions : sequence of float
        Kinetic friction coefficients of the specimens at 6.2 mm/s
        (published: 0.39, 0.40, 0.53).
    speeds : sequence of float
        Sliding speeds (mm/s), published 1.4, 6.2 and 25.
    normal_force : float
        Pressing force of the apex element (N), published 0.1.
    frame_rate : float
        Camera frames per second, default 20.
    slide_time : float
        Duration of the sliding stroke (s), default 2.5.
    speed_coefficient : float
        ``c`` of :func:`sliding_friction` (default 0.01).
    tolerance : float
        The accepted ``|mu_est - mu_sim|``, published 0.02.
    lean_deg : float
        Lean of the sensor axis from straight down towards the sliding
        direction (deg), default 9, held along the stroke with the z-stage
        (:meth:`Finger.rmrc_lean`); see *Notes*. 0 presses the apex straight
        down.
    finger : Finger, optional
        Default ``Finger()``; the stroke is a straight radial line of the apex
        (world +x) from ``POSE_SCAN``, followed by RMRC frame by frame.
    seed : int
    progress : bool
        tqdm bars on stderr.

    Returns
    -------
    dict
        JSON-ready: ``runs`` (one per friction and speed: ``mu_simulated``
        (the model's kinetic coefficient at that speed), ``mu_estimated``,
        ``mu_std``, ``error``, ``within_tolerance``, ``steady_s``,
        ``mu_truth_steady`` (the same steady-part analysis on the simulated
        forces), ``clamped_fraction`` and ``tipped_fraction`` over the steady
        part, ``local_ratio_steady`` (the element-local ``|F_t| / F_z`` the
        sensor saw), the lean's range, the z-stage travel, and the
        ``series`` ``t, fn, ft, mu`` estimated and true), ``summary``,
        ``settings``, ``seconds``.

    Notes
    -----
    Force model of one run: the z-stage presses the apex element to
    ``normal_force`` (smooth ramp, 0.4 s), dwells 0.2 s, then the finger
    slides at ``v``: the friction force first grows elastically
    (0.5 N/mm) up to the static level ``1.12 mu_k F_n``, then relaxes to the
    kinetic level ``mu_k(v) F_n`` (time constant 0.1 s) with 2 % stick-slip
    fluctuations; the normal force carries 3 % waviness (3 mm wavelength)
    and 1 % noise. After the stroke the finger stops (the shear relaxes to
    half) and lifts. The world forces are turned into element-local ones
    with the sensor orientation from the finger's kinematics, rendered and
    read back; the estimated forces are turned back into world normal and
    tangential components with the same orientation, and
    :func:`optitact.forces.friction_coefficient` finds the steady part.

    Why the lean: the element's columnar feeler tips over when
    ``h |F_t| > r F_z`` (lever arm ``h`` = 3 mm, cone circle ``r`` = 1.25 mm:
    at ``|F_t| / F_z`` of about 0.37-0.40, :func:`optitact.contact.cone_loads`);
    beyond that the centroid stops following the shear, so an element whose
    axis is along the specimen's normal cannot measure ``mu`` = 0.53 at any
    normal force. With the sensor axis leaning by ``beta`` towards the
    sliding direction, the contact force (leaning back by the friction angle
    ``phi = atan mu``) meets the element at ``phi - beta``: the element sees
    ``|F_t| / F_z = tan(phi - beta)`` -- 0.35 for the steady 0.537 (0.53 at
    25 mm/s) with ``beta`` = 9 deg, 0.22 for 0.39 -- and ``-tan(beta)``
    while pressing without sliding. 9 deg keeps the apex feeler the lowest
    one (the nearest ring-1 feeler stays 0.32 mm above the specimen, more
    than the apex's indentation). A three-joint finger cannot hold an
    orientation while it moves (the lean would drift by about 0.55 deg/mm
    along a radial stroke); the z-stage as a fourth axis holds it
    (:meth:`Finger.rmrc_lean`). The world ``mu`` is recovered exactly by
    rotating the estimated forces back, so the lean changes what the element
    sees, not what is measured.
    """
    from tqdm import tqdm

    from optitact.forces import friction_coefficient

    seed = _seed(seed)
    chain = _chain(chain, seed)
    finger = Finger() if finger is None else finger
    fn0 = positive(normal_force, "normal_force")
    rate = positive(frame_rate, "frame_rate")
    slide_time = positive(slide_time, "slide_time")
    tol = positive(tolerance, "tolerance")
    frictions = [positive(m, f"frictions[{i}]") for i, m in enumerate(frictions)]
    speeds = [positive(v, f"speeds[{i}]") for i, v in enumerate(speeds)]
    lean = _real(lean_deg, "lean_deg")
    if not 0.0 <= lean < 45.0:
        raise InputError(f"lean_deg must be in [0, 45) degrees, got {lean!r}")
    sensor = chain.sensor
    t0 = time.perf_counter()
    guess = POSE_SCAN + np.radians([0.0, 0.0, lean - 9.0])  # second link at 50 deg, third at the lean
    start = finger.rmrc_lean(finger.forward(guess), lean, guess)
    theta_c, z_c, apex0 = start.theta, start.z, start.position
    runs = []
    paths = {}  # the stroke depends on the speed only: one RMRC path per speed
    cases = [(m, v) for m in frictions for v in speeds]
    index = 0
    for k, (mu, v) in enumerate(tqdm(cases, desc="surface scanning", unit="run", file=sys.stderr,
                                     disable=not progress)):
        rng = np.random.default_rng([seed, 11, k])
        mu_k = sliding_friction(mu, v, coefficient=speed_coefficient)
        prof = _scan_profile(mu_k, v, fn0, rate, slide_time, rng)
        n = len(prof["t"])
        if v not in paths:
            targets = apex0 + np.outer(prof["x"] - v * slide_time / 2.0, [1.0, 0.0, 0.0])
            paths[v] = _follow(finger, targets, theta_c, z0=z_c, lean=lean)
        rots, stage = paths[v]
        world = np.zeros((n, sensor.n_elements, 3))
        world[:, 0, 0] = -prof["ft"]  # friction opposes the apex's motion (+x)
        world[:, 0, 2] = prof["fn"]
        local = _local_forces(sensor, world, rots)
        est = chain.estimate(local, first_index=index, progress=progress, desc=f"mu {mu:g}, {v:g} mm/s")
        index += n
        west = _world_forces(sensor, est.forces, rots)[:, 0]
        fn_e, ft_e = west[:, 2], np.hypot(west[:, 0], west[:, 1])
        leans = np.degrees(np.arcsin(np.clip(rots[:, 0, 2], -1.0, 1.0)))
        run = {"friction": mu, "speed_mm_s": v, "mu_simulated": mu_k, "frames": n,
               "lean_deg": [float(leans.min()), float(leans.max())],
               "stage_travel_mm": float(np.ptp(stage))}
        try:
            fe = friction_coefficient(ft_e, fn_e, t=prof["t"])
            run.update(mu_estimated=fe.mean, mu_std=fe.std, mu_sem=fe.sem, error=fe.mean - mu_k,
                       within_tolerance=bool(abs(fe.mean - mu_k) <= tol), steady_s=[fe.t_start, fe.t_stop],
                       steady_samples=fe.n, clamped_fraction=float(est.clamped[fe.steady, 0].mean()),
                       tipped_fraction=float(est.tipped[fe.steady, 0].mean()),
                       local_ratio_steady=float(np.median(
                           np.hypot(local[fe.steady, 0, 0], local[fe.steady, 0, 1]) / local[fe.steady, 0, 2])))
            mu_series = fe.mu
        except InputError as exc:
            run.update(mu_estimated=None, error=None, within_tolerance=False, failure=str(exc))
            mu_series = np.where(fn_e > 0.2 * fn0, ft_e / np.where(fn_e > 0, fn_e, 1.0), 0.0)
        try:
            run["mu_truth_steady"] = friction_coefficient(prof["ft"], prof["fn"], t=prof["t"]).mean
        except InputError:
            run["mu_truth_steady"] = None
        run["series"] = {"t": _rounded(prof["t"], 4), "fn_true": _rounded(prof["fn"]),
                         "ft_true": _rounded(prof["ft"]), "fn": _rounded(fn_e), "ft": _rounded(ft_e),
                         "mu": _rounded(mu_series)}
        runs.append(run)
    ok = [r for r in runs if r["error"] is not None]
    summary = {"n_runs": len(runs), "n_within_tolerance": sum(r["within_tolerance"] for r in runs),
               "max_abs_error": max((abs(r["error"]) for r in ok), default=None),
               "max_abs_error_by_friction": {f"{m:g}": max((abs(r["error"]) for r in ok if r["friction"] == m),
                                                           default=None) for m in frictions}}
    return _jsonable({"runs": runs, "summary": summary,
                      "settings": {"normal_force_n": fn0, "frame_rate_hz": rate, "slide_time_s": slide_time,
                                   "speed_coefficient": speed_coefficient, "tolerance": tol,
                                   "finger": finger.to_dict(), "chain": chain.describe(), "seed": seed},
                      "seconds": time.perf_counter() - t0})


def _seed(seed) -> int:
    s = seed_value(seed)
    if s is None:
        raise InputError("seed must be a non-negative integer, got None")
    return s


# ============================================================================ 2. slip
def _rectangle_motion(width: float, height: float, speed: float, rate: float, *, t_acc: float = 0.5,
                      pause: float = 0.5, settle: float = 0.5, laps: int = 1) -> dict:
    """Positions, velocities and the detection gate of a trapezoidal-velocity walk around a rectangle."""
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    seg_t, seg_p, seg_v, seg_gate, side_of = [], [], [], [], []
    t_cursor = 0.0
    dt = 1.0 / rate
    for lap in range(laps):
        for s in range(4):
            a, b = corners[s], corners[(s + 1) % 4]
            length = float(np.linalg.norm(b - a))
            u = (b - a) / length
            acc = speed / t_acc
            t_cruise = max(length / speed - t_acc, 0.0)
            dur = 2 * t_acc + t_cruise
            tt = np.arange(math.ceil((dur + pause) * rate)) * dt
            s_pos = np.where(tt < t_acc, 0.5 * acc * tt**2,
                             np.where(tt < t_acc + t_cruise, 0.5 * speed * t_acc + speed * (tt - t_acc),
                                      length - 0.5 * acc * np.clip(dur - tt, 0.0, None) ** 2))
            vel = np.where(tt < t_acc, acc * tt, np.where(tt < t_acc + t_cruise, speed,
                                                           np.clip(acc * (dur - tt), 0.0, None)))
            s_pos = np.where(tt >= dur, length, s_pos)
            gate = (tt >= t_acc + settle) & (tt < t_acc + t_cruise)
            seg_t.append(t_cursor + tt)
            seg_p.append(a + np.outer(s_pos, u))
            seg_v.append(np.outer(vel, u))
            seg_gate.append(gate)
            side_of.append(np.full(len(tt), 4 * lap + s))
            t_cursor += len(tt) * dt
    return {"t": np.concatenate(seg_t), "xy": np.concatenate(seg_p), "v": np.concatenate(seg_v),
            "gate": np.concatenate(seg_gate), "side": np.concatenate(side_of)}


def _slip_onsets(t: np.ndarray, gate: np.ndarray, n: int, rng: np.random.Generator, *, margin: float = 0.8,
                 spacing: float = 2.0) -> np.ndarray:
    """``n`` onset times inside gated windows, ``margin`` from their ends and ``spacing`` apart.

    The onsets are shared among the windows in proportion to what each can hold, and drawn uniformly
    in equal sub-intervals of a window (stratified), so that the spacing holds.
    """
    idx = np.flatnonzero(gate)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(idx) else []
    spans = [(t[r[0]] + margin, t[r[-1]] - margin) for r in runs]
    spans = [(a, b) for a, b in spans if b >= a]
    cap = np.array([int((b - a) // spacing) + 1 for a, b in spans], int)
    take = np.zeros(len(spans), int)
    order = rng.permutation(len(spans))
    while take.sum() < min(n, cap.sum()):
        for i in order:
            if take[i] < cap[i] and take.sum() < n:
                take[i] += 1
    out = []
    for (a, b), m in zip(spans, take, strict=True):
        if m == 0:
            continue
        width = (b - a + spacing) / m
        for j in range(m):
            out.append(a + j * width + rng.uniform(0.0, max(width - spacing, 0.0)))
    return np.sort(np.array(out, float))


def _match_events(onsets: np.ndarray, detections: np.ndarray, max_delay: float) -> dict:
    """Greedy matching of detections to true onsets: detection within [onset - 1e-9, onset + max_delay]."""
    used = np.zeros(len(detections), bool)
    delays = []
    matched = []
    for t0 in onsets:
        cand = np.flatnonzero(~used & (detections >= t0 - 1e-9) & (detections <= t0 + max_delay))
        if len(cand):
            j = int(cand[np.argmin(detections[cand])])
            used[j] = True
            delays.append(float(detections[j] - t0))
            matched.append(j)
        else:
            matched.append(None)
    tp = len(delays)
    nd = len(detections)
    return {"true_positives": tp, "false_alarms": int(nd - tp), "missed": int(len(onsets) - tp),
            "precision": tp / nd if nd else None, "recall": tp / len(onsets) if len(onsets) else None,
            "delays_s": delays, "mean_delay_s": float(np.mean(delays)) if delays else None,
            "max_delay_s": float(np.max(delays)) if delays else None,
            "false_alarm_times_s": [float(d) for d in detections[~used]], "matched_detection": matched}


def slip_experiment(*, chain: ChainSimulator | None = None, rectangle=(30.0, 20.0), speed: float = 5.0,
                    laps: int = 1, normal_force: float = 0.6, block_mass: float = 0.02,
                    table_friction: float = 0.2, n_slips: int = 6, frame_rate: float = 10.0,
                    threshold: float = 0.06, window: float = 0.6, hold: float = 0.3, max_delay: float = 1.0,
                    finger: Finger | None = None, seed: int = 0, progress: bool = True) -> dict:
    r"""Slip detection while the finger drags a block around a rectangle, with injected slip episodes.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)``.
    rectangle : (float, float)
        Side lengths (mm) of the path, default 30 x 20.
    speed : float
        Cruising speed (mm/s), default 5; each side accelerates and
        decelerates over 0.5 s and the finger pauses 0.5 s at each corner.
    laps : int
        Times round the rectangle, default 1.
    normal_force : float
        The apex element presses on the block's top with this force (N),
        default 0.6.
    block_mass, table_friction : float
        Block mass (kg, default 0.02) and its friction on the table (0.2):
        the drag the finger's shear must supply is
        ``table_friction (m g + F_n)`` (0.16 N by default).
    n_slips : int
        Slip episodes injected (default 6), at random times in the
        constant-speed parts, at least 1 s from their ends and 2.5 s apart.
    frame_rate : float
        Frames per second, default 10.
    threshold, window, hold
        Of :class:`optitact.forces.SlipDetector` (published band 0.06 N/s;
        window 0.6 s: 6 samples).
    max_delay : float
        A detection counts for an episode when it comes at most this long
        after its onset (s), default 1.
    finger : Finger, optional
    seed : int
    progress : bool

    Returns
    -------
    dict
        JSON-ready: ``onsets_s`` (true), ``events`` (detected, from the
        estimated forces), ``scores`` (precision, recall, delays, false
        alarms), ``scores_truth`` (the same detector on the simulated forces),
        the ``series`` (t, x, y, gate, shear true and estimated, derivative),
        ``settings``, ``seconds``.

    Notes
    -----
    The apex element (sensor axis down) presses on the block and drags it;
    the shear on the element opposes the motion, scaled down to zero as the
    finger stops at a corner (the block rests; the shear turns with the next
    side). A slip episode: the contact gives way, the shear falls by a
    fraction 0.4-0.7 of the drag (time constant 0.05 s) with 5 % chatter, stays
    there 0.2-0.5 s (the finger slides over the block) and recovers
    (0.15 s) when the grip returns. Shear texture noise 1 %, normal force
    noise 2 %. Detection runs only while the finger cruises (``gate``: from
    0.5 s after the acceleration to the start of the deceleration): when the
    robot itself changes the load, a derivative means nothing. The detector
    works on the magnitude of the estimated horizontal force, obtained
    through the finger's orientation.
    """
    from optitact.forces import detect_slip

    seed = _seed(seed)
    chain = _chain(chain, seed)
    finger = Finger() if finger is None else finger
    w, h = (positive(v, f"rectangle[{i}]") for i, v in enumerate(rectangle))
    speed = positive(speed, "speed")
    laps = integer(laps, "laps", minimum=1)
    fn0 = positive(normal_force, "normal_force")
    n_slips = integer(n_slips, "n_slips", minimum=0)
    rate = positive(frame_rate, "frame_rate")
    sensor = chain.sensor
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 21])
    mot = _rectangle_motion(w, h, speed, rate, laps=laps)
    t = mot["t"]
    n = len(t)
    drag = positive(table_friction, "table_friction") * (positive(block_mass, "block_mass") * 9.81 + fn0)
    vmag = np.hypot(mot["v"][:, 0], mot["v"][:, 1])
    scale = np.clip(vmag / (0.25 * speed), 0.0, 1.0)
    direction = np.zeros((n, 2))
    moving = vmag > 0
    direction[moving] = mot["v"][moving] / vmag[moving, None]
    # keep the last direction while paused (the shear relaxes along it)
    for i in range(1, n):
        if not moving[i]:
            direction[i] = direction[i - 1]
    mult = 1.0 + _ar1(rng, n, 0.01, 0.5)
    onsets = _slip_onsets(t, mot["gate"], n_slips, rng)
    episodes = []
    for t_on in onsets:
        d = rng.uniform(0.4, 0.7)
        dur = rng.uniform(0.2, 0.5)
        chatter = _ar1(rng, n, 0.05, 0.3)
        during = (t >= t_on) & (t < t_on + dur)
        after = t >= t_on + dur
        drop_end = d * (1.0 - math.exp(-dur / 0.05))
        g = np.ones(n)
        g[during] = 1.0 - d * (1.0 - np.exp(-(t[during] - t_on) / 0.05)) + chatter[during] * (1 - d)
        g[after] = 1.0 - drop_end * np.exp(-(t[after] - t_on - dur) / 0.15)
        mult *= g
        episodes.append({"onset_s": float(t_on), "drop_fraction": d, "duration_s": dur})
    shear = drag * scale * mult
    fn = fn0 * (1.0 + _ar1(rng, n, 0.02, 0.5))
    apex0 = finger.forward(POSE_DOWN)
    targets = apex0 + np.concatenate([mot["xy"] - [w / 2, h / 2], np.zeros((n, 1))], axis=1)
    rots, _ = _follow(finger, targets, POSE_DOWN)
    world = np.zeros((n, sensor.n_elements, 3))
    world[:, 0, :2] = -shear[:, None] * direction
    world[:, 0, 2] = fn
    est = chain.estimate(_local_forces(sensor, world, rots), progress=progress, desc="slip")
    west = _world_forces(sensor, est.forces, rots)[:, 0]
    shear_est = np.hypot(west[:, 0], west[:, 1])
    kw = dict(threshold=threshold, window=window, hold=hold)
    res = detect_slip(t, shear_est, active=mot["gate"], **kw)
    res_true = detect_slip(t, shear, active=mot["gate"], **kw)
    scores = _match_events(onsets, res.onsets, max_delay)
    scores_true = _match_events(onsets, res_true.onsets, max_delay)
    return _jsonable({
        "onsets_s": onsets, "episodes": episodes, "events": [e.as_dict() for e in res.events],
        "events_truth": [e.as_dict() for e in res_true.events], "scores": scores, "scores_truth": scores_true,
        "drag_n": drag, "frames": n,
        "series": {"t": _rounded(t, 4), "x": _rounded(mot["xy"][:, 0], 3), "y": _rounded(mot["xy"][:, 1], 3),
                   "gate": mot["gate"], "shear_true": _rounded(shear), "shear": _rounded(shear_est),
                   "fn": _rounded(west[:, 2]), "derivative": _rounded(res.derivative),
                   "derivative_true": _rounded(res_true.derivative)},
        "settings": {"rectangle_mm": [w, h], "speed_mm_s": speed, "laps": laps, "normal_force_n": fn0,
                     "block_mass_kg": block_mass, "table_friction": table_friction, "n_slips": n_slips,
                     "frame_rate_hz": rate, "threshold_n_s": threshold, "window_s": window, "hold_s": hold,
                     "max_delay_s": max_delay, "chain": chain.describe(), "seed": seed},
        "seconds": time.perf_counter() - t0})


# ============================================================================ 3. contour tracing
def _rot_ccw(v: np.ndarray) -> np.ndarray:
    return np.array([-v[1], v[0]])


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


class _Probe:
    """The finger, the objects and the chain in closed loop: one frame per call, counted."""

    def __init__(self, chain: ChainSimulator, finger: Finger, objects, *, stiffness: float,
                 feeler_height: float, first_index: int, max_frames: int, joint_error: float = 0.0,
                 rng: np.random.Generator | None = None) -> None:
        self.chain, self.finger, self.objects = chain, dataclasses.replace(finger, tool=0.0), objects
        self.k, self.h = stiffness, feeler_height
        self.index, self.frames, self.max_frames = first_index, 0, max_frames
        self.theta = POSE_TRACE.copy()
        self.actual = self.theta
        self.joint_error, self.rng = joint_error, rng

    def move(self, centre: np.ndarray, z: float) -> None:
        self.theta = self.finger.rmrc(centre, self.theta, z=z, max_step=5.0).theta
        self.z = z
        self.actual = self.theta
        if self.joint_error > 0:  # where the joints really are (backlash, encoder error): not known
            self.actual = self.theta + self.rng.normal(0.0, self.joint_error, 3)

    def sense(self) -> dict:
        sensor = self.chain.sensor
        rot_a, origin_a = self.finger.sensor_pose(self.actual, z=self.z)
        local, _ = feeler_forces(sensor, rot_a, origin_a, self.objects, stiffness=self.k,
                                 feeler_height=self.h)
        est = self.chain.estimate(local, first_index=self.index)
        self.index += 1
        self.frames += 1
        # The controller's view: the commanded pose.
        rot, origin = self.finger.sensor_pose(self.theta, z=self.z)
        tips = origin + ((sensor.outer_radius + self.h) * sensor.element_frames[:, 2, :]) @ rot.T
        world = _world_forces(sensor, est.forces, rot[None])[0]
        return {"est": est.forces[0], "world": world, "tips": tips, "rot": rot, "origin": origin,
                "truth": local, "clamped": est.clamped[0]}

    @property
    def exhausted(self) -> bool:
        return self.frames >= self.max_frames


def _start_point(obj, contact_y: float, r_tip: float, gap: float) -> tuple[float, float]:
    """Where the experimenter puts the dome centre (x, y) before the approach along +x.

    From there the first contact is at ``y = contact_y``, and every feeler starts ``gap`` mm clear.
    """
    xs = np.linspace(0.0, 400.0, 4001)

    def first_contact(yc: float):
        d, n = obj.signed_distance(np.stack([xs, np.full_like(xs, yc)], axis=1))
        hit = np.flatnonzero(d <= r_tip)
        if not len(hit):
            return None
        i = hit[0]
        return xs[i], yc - r_tip * n[i, 1], np.flatnonzero((d >= r_tip + gap) & (xs < xs[i]))

    lo, hi = contact_y - 2.0 * r_tip, contact_y + 2.0 * r_tip
    for _ in range(50):  # bisection on the centre's y: the contact's y grows with it
        mid = 0.5 * (lo + hi)
        fc = first_contact(mid)
        if fc is None:
            lo, hi = (mid, hi) if mid < contact_y else (lo, mid)
            continue
        lo, hi = (mid, hi) if fc[1] < contact_y else (lo, mid)
    fc = first_contact(0.5 * (lo + hi))
    if fc is None or not len(fc[2]):
        raise InputError(f"no approach along +x reaches the object at y = {contact_y} mm")
    return float(xs[fc[2][-1]]), 0.5 * (lo + hi)


def _trace_one(obj, chain: ChainSimulator, finger: Finger, *, start_y: float, end_y: float, step: float,
               approach_step: float, retreat: float, contact_threshold: float, table_threshold: float,
               lift: float, stiffness: float, feeler_height: float, max_frames: int, corner_margin: float,
               first_index: int, joint_error_deg: float = 0.0, rng=None, gap: float = 4.0) -> dict:
    from optitact.forces import ContactDetector

    sensor = chain.sensor
    r_tip = sensor.outer_radius + feeler_height
    table = Table(0.0)
    probe = _Probe(chain, finger, (table, obj), stiffness=stiffness, feeler_height=feeler_height,
                   first_index=first_index, max_frames=max_frames, joint_error=math.radians(joint_error_deg),
                   rng=rng)
    tool0 = dataclasses.replace(finger, tool=0.0)
    c_nominal = tool0.forward(POSE_TRACE)
    centre = np.array([*_start_point(obj, start_y, r_tip, gap), 0.0])
    # ---- seek the table: lower the z-stage until an element feels 0.2 N
    z_stage = r_tip + 6.0 - c_nominal[2]
    centre[2] = c_nominal[2] + z_stage
    probe.move(centre, z_stage)
    det = ContactDetector(table_threshold)
    table_est = None
    while not probe.exhausted:
        s = probe.sense()
        state = det.update(s["est"][:, 2])
        if state.any():
            e = int(np.argmax(np.where(state, s["est"][:, 2], -np.inf)))
            table_est = float(s["tips"][e, 2] + s["est"][e, 2] / stiffness)
            break
        z_stage -= 1.0
        probe.move(np.array([centre[0], centre[1], c_nominal[2] + z_stage]), z_stage)
    if table_est is None:
        return {"failure": "the table was not found", "frames": probe.frames}
    # ---- lift: the lowest feeler tip `lift` mm above the estimated table
    lowest = float(s["tips"][:, 2].min())
    z_stage += (table_est - lowest) + lift
    c_z = c_nominal[2] + z_stage
    table_frames = probe.frames
    # ---- trace: advance/retreat rules with square search
    det = ContactDetector(contact_threshold)
    n_in, d = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    c = centre[:2].copy()
    path, contacts, normals, forces = [c.copy()], [], [], []
    travel, turns, n_turns, lost = 0.0, 0, 0, False
    failure, table_touches = None, 0
    while not probe.exhausted:
        try:
            probe.move(np.array([c[0], c[1], c_z]), z_stage)
        except (UnreachableError, SingularityError) as exc:
            failure, lost = f"stopped: {exc}", True
            break
        s = probe.sense()
        state = det.update(s["est"][:, 2])
        total = s["world"][state].sum(axis=0)
        if state.any() and total[2] > math.hypot(total[0], total[1]):
            # Pushed up more than sideways: the table (a finger that sagged), not the object's wall.
            table_touches += 1
            state[:] = False
        if state.any():
            fz = np.where(state, s["est"][:, 2], -np.inf)
            e = int(np.argmax(fz))
            nhat = _unit(total)
            point = s["tips"][e] + (s["est"][e, 2] / stiffness) * nhat
            contacts.append(point[:2])
            forces.append(float(np.linalg.norm(total)))
            n2 = _unit(total[:2])
            if np.linalg.norm(n2) > 0:
                n_in = -n2
                d = _rot_ccw(n_in)
            normals.append(-n_in)
            travel, turns = 0.0, 0
            if point[1] >= end_y:
                break
            c = c - n_in * retreat + d * step
        else:
            if not contacts and travel >= gap + 4.0 * (retreat + step):
                failure, lost = "the object was not found on the first approach", True
                break
            if contacts and travel >= retreat + step:  # the first approach goes on until it touches
                turns += 1
                n_turns += 1
                if turns > 4:
                    lost = True
                    break
                n_in, d = -d, n_in
                travel = 0.0
            c = c + n_in * approach_step
            travel += approach_step
        path.append(c.copy())
    pts = np.array(contacts).reshape(-1, 2)
    dev = np.abs(obj.signed_distance(pts)[0]) if len(pts) else np.zeros(0)
    corners = obj.corners
    if len(corners) and len(pts):
        near = np.min(np.linalg.norm(pts[:, None, :] - corners[None], axis=2), axis=1) < corner_margin
    else:
        near = np.zeros(len(pts), bool)
    keep = dev[~near]
    return {"contacts": pts, "path": np.array(path), "normals": np.array(normals).reshape(-1, 2),
            "contact_force_n": forces, "deviation_mm": dev, "near_corner": near,
            "max_deviation_mm": float(dev.max()) if len(dev) else None,
            "mean_deviation_mm": float(dev.mean()) if len(dev) else None,
            "max_deviation_except_corners_mm": float(keep.max()) if len(keep) else None,
            "n_contacts": int(len(pts)), "square_search_turns": n_turns, "lost": lost, "failure": failure,
            "table_touches": table_touches,
            "reached_end": bool(len(pts) and pts[-1, 1] >= end_y),
            "frames": probe.frames, "table": {"true_z": 0.0, "estimated_z": table_est, "frames": table_frames},
            "trace_height_mm": float(c_z), "outline": obj.outline(), "corners": corners}


def contour_tracing(*, chain: ChainSimulator | None = None, objects=("cylinder", "box"),
                    finger: Finger | None = None, span: float = 18.0, step: float = 5.0,
                    approach_step: float = 1.0, retreat: float = 2.0, contact_threshold: float = 0.3,
                    table_threshold: float = 0.2, lift: float = 5.0, stiffness: float = 0.5,
                    feeler_height: float = 1.0, max_frames: int = 120, corner_margin: float = 5.0,
                    joint_error_deg: float = 0.0, seed: int = 0, progress: bool = True) -> dict:
    r"""Trace the contour of a cylinder and a box on a table with the dome, from estimated forces.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)``.
    objects : sequence
        ``"cylinder"`` (radius 30 mm), ``"box"`` (40 x 40 mm, a corner
        facing the finger) or :class:`Cylinder` / :class:`Box` instances
        (placed in front of the finger, near x = 200 mm).
    finger : Finger, optional
        Default ``Finger()``, in ``POSE_TRACE`` (sensor axis 45 deg down).
    span : float
        The trace runs from ``y = -span`` to ``y = +span`` (mm), default 18.
    step : float
        Advance along the contour after each contact (mm), published 5.
    approach_step, retreat : float
        Approach increment towards the object and retreat after a contact
        (mm), default 1 and 2.
    contact_threshold, table_threshold : float
        Per-element normal force thresholds (N), published 0.3 and 0.2
        (with hysteresis, :class:`optitact.forces.ContactDetector`).
    lift : float
        Clearance of the lowest feeler above the table while tracing (mm),
        published 5.
    stiffness, feeler_height : float
        Of :func:`feeler_forces`.
    max_frames : int
        Frame budget per object (default 120).
    corner_margin : float
        Contacts nearer than this to a box corner (mm) are left out of
        ``max_deviation_except_corners_mm``.
    joint_error_deg : float
        Standard deviation (deg) of an unmeasured joint-angle error drawn
        at each move (backlash, encoder and gear errors of a real finger):
        the contact happens at the actual pose, the controller computes
        with the commanded one. Default 0: an ideal finger, so the
        deviations measure the sensing alone.
    seed : int
    progress : bool

    Returns
    -------
    dict
        JSON-ready: one entry per object under ``objects`` with its
        ``contacts`` (estimated contact points, mm), ``path`` (dome-centre
        path), ``deviation_mm`` per contact, ``max_deviation_mm``,
        ``max_deviation_except_corners_mm``, ``table`` (true and estimated
        height), ``frames``, ``square_search_turns``; ``settings``,
        ``seconds``.

    Notes
    -----
    1. *Seek the table*: the dome, tilted 45 deg down, is lowered by the
       z-stage in 1 mm steps until an element's estimated normal force
       reaches 0.2 N; the table height is that element's feeler tip plus
       its estimated indentation ``F_z / k``.
    2. *Lift* so that the lowest feeler clears the table by ``lift``.
    3. *Trace* in that horizontal plane, moving the dome centre with RMRC:
       approach the object in ``approach_step`` increments along the
       inward direction until an element reads 0.3 N (the first approach,
       from 4 mm clear, goes on until it touches, up to 4 mm plus four
       square-search sides); then record the
       contact point (the loaded feeler's tip, moved out by its estimated
       indentation along the estimated force), take the estimated force's
       horizontal direction as the surface normal, *retreat* ``retreat`` mm
       along it and *advance* ``step`` mm along the tangent. When the
       approach runs ``retreat + step`` mm without contact (the surface
       turned away, at a corner), *square search*: turn the search
       direction by 90 deg towards the object and approach again (at most
       4 turns). A contact whose estimated force pushes up more than
       sideways is the table (only a finger with joint errors sags that far):
       it is counted (``table_touches``), not recorded, and the approach
       goes on.

    The published deviations (about 3.6 mm on a cylinder, 2.7 mm on a box
    away from the corners) are of the real finger, whose positioning errors
    dominate them; with an ideal finger (``joint_error_deg=0``) the contact
    points here are off only by the estimated indentation's error (the
    feeler tip's position is known from the kinematics), a few hundredths
    of a millimetre; ``joint_error_deg`` adds the finger's own errors.
    """
    from tqdm import tqdm

    seed = _seed(seed)
    chain = _chain(chain, seed)
    finger = Finger() if finger is None else finger
    span = positive(span, "span")
    opts = dict(step=positive(step, "step"), approach_step=positive(approach_step, "approach_step"),
                retreat=positive(retreat, "retreat"),
                contact_threshold=positive(contact_threshold, "contact_threshold"),
                table_threshold=positive(table_threshold, "table_threshold"), lift=positive(lift, "lift"),
                stiffness=positive(stiffness, "stiffness"),
                feeler_height=positive(feeler_height, "feeler_height", allow_zero=True),
                max_frames=integer(max_frames, "max_frames", minimum=1),
                corner_margin=positive(corner_margin, "corner_margin", allow_zero=True),
                joint_error_deg=positive(joint_error_deg, "joint_error_deg", allow_zero=True))
    t0 = time.perf_counter()
    r_tip = chain.sensor.outer_radius + opts["feeler_height"]
    front = float(dataclasses.replace(finger, tool=0.0).forward(POSE_TRACE)[0] + r_tip) - 12.0
    out = {}
    index = 0
    items = list(objects)
    for k, item in enumerate(tqdm(items, desc="contour tracing", unit="object", file=sys.stderr,
                                  disable=not progress)):
        if item == "cylinder":
            obj, name = Cylinder(center=(front + 30.0, 0.0), radius=30.0), "cylinder"
        elif item == "box":
            half_diag = 40.0 / math.sqrt(2.0)
            obj, name = Box(center=(front + half_diag, 0.0), size=(40.0, 40.0), angle_deg=45.0), "box"
        elif isinstance(item, (Cylinder, Box)):
            obj, name = item, f"{type(item).__name__.lower()}{k}"
        else:
            raise InputError(f"objects must hold 'cylinder', 'box', Cylinder or Box, got {item!r}")
        res = _trace_one(obj, chain, finger, start_y=-span, end_y=span, first_index=index,
                         rng=np.random.default_rng([seed, 31, k]), **opts)
        index += 100_000
        res["object"] = {"kind": type(obj).__name__.lower(), **dataclasses.asdict(obj)}
        out[name] = res
    return _jsonable({"objects": out, "settings": {**opts, "span_mm": span, "finger": finger.to_dict(),
                                                   "chain": chain.describe(), "seed": seed},
                      "seconds": time.perf_counter() - t0})


#: Published largest deviations of traced contours (mm): the cylinder, and the box away from its corners.
PUBLISHED_DEVIATION_MM = {"cylinder": 3.6, "box": 2.7}


def joint_error_study(*, chain: ChainSimulator | None = None, joint_errors_deg=(0.0, 0.25, 0.5, 1.0),
                      repeats: int = 3, objects=("cylinder", "box"), baseline: dict | None = None,
                      seed: int = 0, progress: bool = True, **trace_options) -> dict:
    """Contour-tracing deviations against the finger's own (unmeasured) joint errors.

    With an ideal finger the traced contour is off only by the sensing error (hundredths of a
    millimetre); the published deviations (about 3.6 mm on the cylinder, 2.7 mm on the box away
    from its corners) are dominated by the real finger's positioning. This traces each object
    ``repeats`` times at each joint-angle error level (:func:`contour_tracing`'s
    ``joint_error_deg``, different seeds) and reports the largest deviation per trace, so the
    published figures can be read as an equivalent joint error.

    Parameters
    ----------
    chain : ChainSimulator, optional
    joint_errors_deg : sequence of float
        Standard deviations of the joint-angle error (deg), default 0, 0.25, 0.5, 1.
    repeats : int
        Traces per level and object (default 3; an ideal finger is traced once).
    objects : sequence
        As for :func:`contour_tracing`.
    baseline : dict, optional
        A :func:`contour_tracing` result of the ideal finger with this seed, reused for level 0.
    seed : int
    progress : bool
    **trace_options
        Passed to :func:`contour_tracing` (``span``, ``max_frames``, ...).

    Returns
    -------
    dict
        JSON-ready: ``joint_error_deg``, and per object ``max_deviation_mm`` (the cylinder's
        largest deviation, the box's away from its corners) as a list per level (one value per
        repeat), their ``median`` and ``mean``, the ``published_mm`` figure, and ``seconds``.
    """
    seed = _seed(seed)
    chain = _chain(chain, seed)
    levels = [positive(v, f"joint_errors_deg[{i}]", allow_zero=True) for i, v in enumerate(joint_errors_deg)]
    repeats = integer(repeats, "repeats", minimum=1)
    t0 = time.perf_counter()
    names = [o if isinstance(o, str) else f"{type(o).__name__.lower()}{k}" for k, o in enumerate(objects)]
    per = {n: [] for n in names}
    for level in levels:
        runs = {n: [] for n in names}
        for r in range(1 if level == 0 else repeats):
            if level == 0 and baseline is not None and r == 0:
                res = baseline
            else:
                res = contour_tracing(chain=chain, objects=objects, joint_error_deg=level,
                                      seed=seed + 1000 * r, progress=progress, **trace_options)
            for n in names:  # without corners this is the plain largest deviation
                runs[n].append(res["objects"].get(n, {}).get("max_deviation_except_corners_mm"))
        for n in names:
            per[n].append(runs[n])
    out = {"joint_error_deg": levels, "repeats": repeats, "objects": {}}
    for n in names:
        vals = per[n]
        rows = [[v for v in row if v is not None] for row in vals]
        out["objects"][n] = {"max_deviation_mm": vals,
                             "median": [float(np.median(r)) if r else None for r in rows],
                             "mean": [float(np.mean(r)) if r else None for r in rows],
                             "published_mm": PUBLISHED_DEVIATION_MM.get(n)}
    out["seconds"] = time.perf_counter() - t0
    return _jsonable(out)


# ============================================================================ all three
def experiment(*, seed: int = 0, full: bool = False, progress: bool = True,
               chain: ChainSimulator | None = None, calibration=None) -> dict:
    """The three finger experiments through the real chain: surface scanning, slip, contour tracing.

    Parameters
    ----------
    seed : int
        Seeds everything (the chain's frames, the force models, the slip onsets).
    full : bool
        Published sizes (3 frictions x 3 speeds, 2.5 s strokes at 20 Hz; two laps with 12 slips;
        cylinder and box, and :func:`joint_error_study`): about eight minutes on 2 CPU cores at
        640x480, 32 spp. Otherwise a quick run
        (the three frictions at 6.2 mm/s with 1.2 s strokes at 10 Hz; one lap with 4 slips; the
        cylinder only, a shorter span), about a minute.
    progress : bool
        tqdm bars on stderr.
    chain : ChainSimulator, optional
        Default ``ChainSimulator(calibration, seed=seed)`` (640x480, 32 spp).
    calibration : Calibration or "extended", optional
        For the default chain: the shipped calibration (None), one of yours,
        or ``"extended"`` (:func:`extended_calibration`: the shipped design
        widened to ``|F_t| / F_z`` <= 0.40, made and cached on first use).

    Returns
    -------
    dict
        JSON-ready: ``surface_scanning``, ``slip``, ``contour_tracing`` (see the three functions),
        with ``full`` also ``joint_error_study``; ``seed``, ``full``, ``seconds``.
    """
    seed = _seed(seed)
    t0 = time.perf_counter()
    if chain is None:
        if isinstance(calibration, str):
            if calibration != "extended":
                raise InputError(f"calibration must be a Calibration, None or 'extended', got {calibration!r}")
            calibration = extended_calibration(progress=progress)
        chain = ChainSimulator(calibration, seed=seed)
    elif calibration is not None:
        raise InputError("give chain or calibration, not both (the chain has its calibration)")
    chain = _chain(chain, seed)
    study = None
    if full:
        scan = surface_scanning(chain=chain, seed=seed, progress=progress)
        slip = slip_experiment(chain=chain, laps=2, n_slips=12, seed=seed, progress=progress)
        trace = contour_tracing(chain=chain, seed=seed, progress=progress)
        study = joint_error_study(chain=chain, baseline=trace, seed=seed, progress=progress)
    else:
        scan = surface_scanning(chain=chain, speeds=(6.2,), slide_time=1.2, frame_rate=10.0, seed=seed,
                                progress=progress)
        slip = slip_experiment(chain=chain, rectangle=(24.0, 16.0), n_slips=4, seed=seed, progress=progress)
        trace = contour_tracing(chain=chain, objects=("cylinder",), span=8.0, max_frames=60, seed=seed,
                                progress=progress)
    out = {"surface_scanning": scan, "slip": slip, "contour_tracing": trace, "seed": seed, "full": bool(full),
           "seconds": time.perf_counter() - t0}
    if study is not None:
        out["joint_error_study"] = study
    return out


# ============================================================================ plots
def _need(result: dict, *keys):
    try:
        for k in keys:
            result = result[k]
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must come from the matching finger experiment; missing {exc}") from None
    return result


def _draw_scanning(fig, result: dict) -> None:
    runs = _need(result, "runs")
    frictions = sorted({r["friction"] for r in runs})
    speeds = sorted({r["speed_mm_s"] for r in runs})
    axes = fig.subplots(len(frictions) + 1, len(speeds), squeeze=False)
    for r in runs:
        ax = axes[frictions.index(r["friction"]), speeds.index(r["speed_mm_s"])]
        s = r["series"]
        t = np.asarray(s["t"])
        ax.plot(t, s["fn_true"], color="0.6", lw=1, label="F_n true")
        ax.plot(t, s["fn"], color="tab:blue", lw=1.2, label="F_n est.")
        ax.plot(t, s["ft_true"], color="0.6", lw=1, ls="--", label="|F_t| true")
        ax.plot(t, s["ft"], color="tab:orange", lw=1.2, label="|F_t| est.")
        ax.set_xlabel("t (s)", fontsize=7)
        ax.set_ylabel("force (N)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax2 = ax.twinx()
        ax2.plot(t, s["mu"], color="tab:green", lw=1, label="μ est.")
        ax2.axhline(r["mu_simulated"], color="tab:green", ls=":", lw=1)
        ax2.set_ylim(0.0, max(0.8, r["mu_simulated"] * 1.5))
        ax2.tick_params(labelsize=6, colors="tab:green")
        if r.get("steady_s"):
            ax.axvspan(*r["steady_s"], color="tab:green", alpha=0.1)
        est = "failed" if r["mu_estimated"] is None else f"{r['mu_estimated']:.3f}±{r['mu_std']:.3f}"
        ax.set_title(f"μ={r['friction']:g}, {r['speed_mm_s']:g} mm/s: sim {r['mu_simulated']:.3f}, est {est}",
                     fontsize=7)
    axes[0, 0].legend(fontsize=5, loc="upper left")
    for ax in axes[-1, 1:]:
        ax.remove()
    ax = axes[-1, 0]
    gs = ax.get_subplotspec().get_gridspec()
    ax.remove()
    ax = fig.add_subplot(gs[-1, :])
    for m in frictions:
        rs = [r for r in runs if r["friction"] == m and r["mu_estimated"] is not None]
        ax.errorbar([r["speed_mm_s"] for r in rs], [r["mu_estimated"] for r in rs],
                    yerr=[r["mu_std"] for r in rs], marker="o", capsize=3, label=f"est., μ={m:g}")
        rs = [r for r in runs if r["friction"] == m]
        ax.plot([r["speed_mm_s"] for r in rs], [r["mu_simulated"] for r in rs], "kx:", lw=1, ms=6)
    ax.set_xscale("log")
    ax.set_xticks(speeds, [f"{v:g}" for v in speeds])
    ax.minorticks_off()
    ax.set_xlim(min(speeds) / 1.5, max(speeds) * 1.5)
    ax.set_xlabel("speed (mm/s)")
    ax.set_ylabel("μ")
    ax.set_title("estimated (markers, ±1 sd) vs simulated (crosses) friction coefficient", fontsize=8)
    ax.legend(fontsize=6)


def _draw_slip(fig, result: dict) -> None:
    s = _need(result, "series")
    t = np.asarray(s["t"])
    ax1, ax2, ax3 = fig.subplots(1, 3, gridspec_kw={"width_ratios": [3, 3, 1.3]})
    gate = np.asarray(s["gate"], bool)
    for ax in (ax1, ax2):
        ax.fill_between(t, 0, 1, where=~gate, transform=ax.get_xaxis_transform(), color="0.9", lw=0)
        for t0 in result["onsets_s"]:
            ax.axvline(t0, color="tab:red", lw=0.8, ls="--")
    ax1.plot(t, s["shear_true"], color="0.5", lw=1, label="true")
    ax1.plot(t, s["shear"], color="tab:orange", lw=1, label="estimated")
    ax1.set_xlabel("t (s)")
    ax1.set_ylabel("|F_t| (N)")
    ax1.legend(fontsize=6)
    ax1.set_title("shear; red: injected slip onsets, grey: detection off", fontsize=8)
    ax2.plot(t, s["derivative"], color="tab:blue", lw=1)
    th = result["settings"]["threshold_n_s"]
    ax2.axhspan(-th, th, color="tab:green", alpha=0.15)
    for e in result["events"]:
        ax2.plot(e["onset"], e["peak_rate"], "kv", ms=5)
    sc = result["scores"]
    delay = "n/a" if sc["mean_delay_s"] is None else f"{sc['mean_delay_s']:.2f} s"
    prec = "n/a" if sc["precision"] is None else f"{sc['precision']:.2f}"
    rec = "n/a" if sc["recall"] is None else f"{sc['recall']:.2f}"
    ax2.set_title(f"d|F_t|/dt, band ±{th:g} N/s; precision {prec}, recall {rec}, mean delay {delay}",
                  fontsize=8)
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("N/s")
    ax3.plot(s["x"], s["y"], color="0.3")
    ax3.set_aspect("equal")
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_title("finger path", fontsize=8)


def _draw_joint_error(ax, study: dict) -> None:
    levels = np.asarray(_need(study, "joint_error_deg"), float)
    for k, (name, o) in enumerate(_need(study, "objects").items()):
        color = f"C{k}"
        for lv, row in zip(levels, o["max_deviation_mm"], strict=True):
            vals = [v for v in row if v is not None]
            ax.plot([lv] * len(vals), vals, "o", color=color, alpha=0.5, ms=4)
        label = f"{name} (except corners)" if name == "box" else name
        ax.plot(levels, np.array(o["median"], dtype=float), "-", color=color, label=f"{label}, median")
        if o.get("published_mm") is not None:
            ax.axhline(o["published_mm"], color=color, ls=":", lw=1)
            ax.text(levels.max(), o["published_mm"], f" published {name} {o['published_mm']:g} mm", color=color,
                    fontsize=6, va="bottom", ha="right")
    ax.set_xlabel("joint-angle error of the finger, sd (deg)")
    ax.set_ylabel("largest deviation (mm)")
    ax.set_title("traced contour vs the finger's own errors", fontsize=8)
    ax.legend(fontsize=6, loc="upper left")


def _draw_contour(fig, result: dict, study: dict | None = None) -> None:
    objs = _need(result, "objects")
    axes = np.atleast_1d(fig.subplots(1, max(len(objs), 1) + (study is not None)))
    if study is not None:
        _draw_joint_error(axes[-1], study)
        axes = axes[:-1]
    for ax, (name, r) in zip(axes, objs.items(), strict=False):
        if "outline" not in r:
            ax.set_title(f"{name}: {r.get('failure')}", fontsize=8)
            continue
        out = np.asarray(r["outline"])
        ax.plot(out[:, 0], out[:, 1], "k-", lw=1.5, label="true contour")
        path = np.asarray(r["path"])
        ax.plot(path[:, 0], path[:, 1], ".-", color="0.6", lw=0.8, ms=3, label="dome centre")
        pts = np.asarray(r["contacts"]).reshape(-1, 2)
        if len(pts):
            sc = ax.scatter(pts[:, 0], pts[:, 1], c=r["deviation_mm"], cmap="viridis", s=25, zorder=3,
                            label="contacts")
            fig.colorbar(sc, ax=ax, label="deviation (mm)", shrink=0.8)
        ax.set_aspect("equal")
        lo = np.vstack([pts, path]).min(axis=0) - 10 if len(pts) else path.min(axis=0) - 10
        hi = np.vstack([pts, path]).max(axis=0) + 10 if len(pts) else path.max(axis=0) + 10
        ax.set_xlim(lo[0], max(hi[0], out[:, 0].min() + 20))
        ax.set_ylim(lo[1], hi[1])
        md, mc = r["max_deviation_mm"], r["max_deviation_except_corners_mm"]
        text = f"max dev {md:.2f} mm" if md is not None else "no contact"
        if len(r.get("corners", [])) and mc is not None:
            text += f", except corners {mc:.2f} mm"
        ax.set_title(f"{name}: {text}", fontsize=8)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.legend(fontsize=6, loc="lower left")


def _save(fig, path):
    if path is not None:
        fig.savefig(path, dpi=100, format="png")
    return fig


def plot_surface_scanning(result: dict, path=None):
    """Figure of :func:`surface_scanning`: forces and μ over time per run, and μ against speed.

    Returns the :class:`matplotlib.figure.Figure` (no pyplot), saved as PNG at ``path`` when given.
    """
    from matplotlib.figure import Figure

    n_rows = len({r["friction"] for r in _need(result, "runs")}) + 1
    fig = Figure(figsize=(13, 2.6 * n_rows), layout="constrained")
    _draw_scanning(fig, result)
    return _save(fig, path)


def plot_slip(result: dict, path=None):
    """Figure of :func:`slip_experiment`: shear, its derivative against the band, the path."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 3.6), layout="constrained")
    _draw_slip(fig, result)
    return _save(fig, path)


def plot_contour(result: dict, path=None):
    """Figure of :func:`contour_tracing`: true contours, traced path and contact points."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6 * max(len(_need(result, "objects")), 1), 5), layout="constrained")
    _draw_contour(fig, result)
    return _save(fig, path)


def plot_joint_error_study(result: dict, path=None):
    """Figure of :func:`joint_error_study`: largest deviation against the joint error, published lines."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4), layout="constrained")
    _draw_joint_error(fig.subplots(), result)
    return _save(fig, path)


def plot_experiment(result: dict, path=None):
    """One figure of :func:`experiment`: scanning, slip and contour tracing, saved as PNG at ``path``."""
    from matplotlib.figure import Figure

    scan = _need(result, "surface_scanning")
    n_rows = len({r["friction"] for r in _need(scan, "runs")}) + 1
    fig = Figure(figsize=(15, 2.4 * n_rows + 4 + 5), layout="constrained")
    top, mid, bottom = fig.subfigures(3, 1, height_ratios=[2.4 * n_rows, 4, 5])
    _draw_scanning(top, scan)
    _draw_slip(mid, _need(result, "slip"))
    _draw_contour(bottom, _need(result, "contour_tracing"), result.get("joint_error_study"))
    fig.suptitle(f"robotic finger with the dome sensor (seed {result.get('seed')}, full={result.get('full')})")
    return _save(fig, path)
