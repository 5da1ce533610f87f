"""Kinematics of the dome sensor's 3-joint finger on a z-stage: DH forward map, Jacobians, RMRC.

The finger of the sensor's inventors: three revolute joints (a yaw joint and
two pitch joints) on a vertical z-stage, with the dome sensor at the
fingertip. :class:`Finger` gives the forward kinematics from
Denavit-Hartenberg parameters (base tilts ``phi1``, ``phi2``), the Jacobian,
resolved motion rate control with a condition-number check or damped least
squares (:meth:`Finger.rmrc`), the same with the z-stage as a fourth axis
holding the sensor's lean (:meth:`Finger.rmrc_lean`), and RMRC along a path
(:meth:`Finger.follow`).

Convention
----------
World frame: ``(x, y, z)`` in mm, ``z`` up. The sensor frame is
:mod:`optitact.optics.sensor`'s (origin at the dome's base-circle centre, ``z``
towards the apex); the finger carries it with ``z_s`` along the last link and
``x_s`` along the last joint axis. Joint angles in radians.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from optitact._validate import finite, integer, positive, real_array, real_number
from optitact.errors import InputError, ShapeError

__all__ = ["as_point", "UnreachableError", "SingularityError", "Finger", "RMRCResult", "POSE_DOWN", "POSE_SCAN",
           "POSE_TRACE"]

class UnreachableError(InputError):
    """A target position lies outside the finger's workspace (or RMRC did not reach it)."""


class SingularityError(InputError):
    """The Jacobian is (nearly) singular on the way to a target: its condition number is too large."""


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])



def _triple(value, name: str) -> tuple[float, float, float]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise TypeError(f"{name} must be a sequence of 3 numbers (one per joint), got {value!r}")
    return tuple(real_number(v, f"{name}[{i}]") for i, v in enumerate(value))


def _vector3(value, name: str, what: str) -> np.ndarray:
    """``value`` as a finite float64 array of shape (3,); ``what`` says what the three numbers are."""
    v = finite(real_array(value, name), name)
    if v.shape != (3,):
        raise ShapeError(f"{name} must have shape (3,) ({what}), got {v.shape}")
    return v


def _joints(theta, name: str = "theta") -> np.ndarray:
    return _vector3(theta, name, "one angle per joint, rad")


def as_point(value, name: str) -> np.ndarray:
    """``value`` as a finite 3-vector (x, y, z in mm); InputError or ShapeError naming ``name``."""
    return _vector3(value, name, "x, y, z in mm")


def _rmrc_options(tol, max_iter, max_step, cond_max) -> tuple[float, int, float | None, float]:
    """Validated ``tol``, ``max_iter``, ``max_step`` (None allowed) and ``cond_max`` of an RMRC call."""
    return (positive(tol, "tol"), integer(max_iter, "max_iter", minimum=1),
            None if max_step is None else positive(max_step, "max_step"), positive(cond_max, "cond_max"))


def _direction(value, name: str = "direction") -> np.ndarray:
    d = _vector3(value, name, "a world direction")
    n = float(np.linalg.norm(d))
    if not n > 0:
        raise InputError(f"{name} must be a non-zero vector, got {d.tolist()}")
    return d / n


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
        object.__setattr__(self, "phi1_deg", real_number(self.phi1_deg, "phi1_deg"))
        object.__setattr__(self, "phi2_deg", real_number(self.phi2_deg, "phi2_deg"))
        object.__setattr__(self, "tool", real_number(self.tool, "tool"))

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
        z = real_number(z, "z")
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
        rd = as_point(target, "target")
        th = _joints(theta0, "theta0").copy()
        z = real_number(z, "z")
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
        rd = as_point(target, "target")
        lean = real_number(lean_deg, "lean_deg")
        if not -90.0 < lean < 90.0:
            raise InputError(f"lean_deg must be in (-90, 90) degrees, got {lean!r}")
        sd = math.sin(math.radians(lean))
        d = _direction(direction)
        th = _joints(theta0, "theta0").copy()
        z = real_number(z0, "z0")
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


    # ------------------------------------------------------------------ along a path
    def follow(self, targets, theta0, *, z0: float = 0.0,
               lean_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Sensor rotations and z-stage positions along tool targets (RMRC from each pose to the next).

        Parameters
        ----------
        targets : (T, 3) array_like
            Tool positions (mm, world), in order.
        theta0 : (3,) array_like
            Starting joint angles (rad).
        z0 : float
            Starting z-stage position (mm).
        lean_deg : float, optional
            None (default): :meth:`rmrc` with the stage held at ``z0``. A lean
            (deg): :meth:`rmrc_lean` holding the sensor's lean towards +x with
            the z-stage as a fourth axis; the finger first walks to the first
            target in 2 mm steps.

        Returns
        -------
        rotations : (T, 3, 3) ndarray
            Sensor rotations (:meth:`sensor_pose`) at each target.
        stage : (T,) ndarray
            z-stage positions (mm).
        """
        pts = finite(real_array(targets, "targets"), "targets")
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ShapeError(f"targets must have shape (T, 3) (tool positions, mm), got {pts.shape}")
        th, z = _joints(theta0, "theta0"), real_number(z0, "z0")

        def reach(p):
            if lean_deg is None:
                return self.rmrc(p, th, z=z).theta, z
            r = self.rmrc_lean(p, lean_deg, th, z0=z)
            return r.theta, r.z

        if lean_deg is not None:
            here = self.forward(th, z=z)
            n_walk = int(np.ceil(np.linalg.norm(pts[0] - here) / 2.0))
            for p in here + np.outer(np.arange(1, n_walk) / n_walk, pts[0] - here):
                th, z = reach(p)
        rots, stage = [], []
        for p in pts:
            th, z = reach(p)
            rots.append(self.sensor_pose(th, z=z)[0])
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
