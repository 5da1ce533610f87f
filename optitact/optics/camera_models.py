"""OpenCV's camera models (pinhole with radial-tangential distortion, Kannala-Brandt fisheye) in the dome.

:class:`PinholeCamera` projects as ``cv2.projectPoints`` and
:class:`OpenCVFisheyeCamera` as ``cv2.fisheye.projectPoints``, with the same
``K``, ``D``, ``rvec`` and ``tvec``; :func:`read_opencv_calibration` reads
OpenCV's calibration output and :func:`camera_from_opencv` takes ``K`` and
``D`` arrays (both in :mod:`optitact.optics.opencv_files`). Both
models are :class:`optitact.optics.camera.Camera`: every function that
takes a camera (the pipeline, :func:`optitact.optics.camera.pixel_from_dome`, ...) takes them.

Convention
----------
Pixels are ``(row, col)`` = OpenCV's ``(v, u)``, origin at the centre of the
top-left pixel. The pose is OpenCV's: ``X_cam = R X_dome + tvec`` with ``R``
the Rodrigues rotation of ``rvec``; the dome frame has z up the dome axis
(mm), the camera frame x right, y down, z forward. The default pose
(``rvec = 0``, ``tvec = (0, 0, 5)``) puts the camera on the dome axis at
z = -5 mm looking up it, as the default :class:`optitact.optics.camera.FisheyeCamera`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np

from optitact._validate import integer, real_number
from optitact.optics.camera import CAMERA_MODELS, Camera, bracketed_newton, check_frame_size, rotation_from_rvec
from optitact.errors import InputError

__all__ = ["OpenCVFisheyeCamera", "PinholeCamera", "pose_from_position"]

#: Largest undistorted normalised radius ``tan(angle)`` a pinhole camera images (an 89.4 deg ray).
PINHOLE_MAX_RADIUS = 100.0


def _vector(value, name: str, sizes) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a sequence of real numbers, got {value!r}") from None
    if arr.size not in sizes:
        raise InputError(f"{name} must have {' or '.join(map(str, sizes))} entries, got {arr.size}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


def _rvec_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    if m.shape != (3, 3) or not np.isfinite(m).all():
        raise InputError(f"rvec as a matrix must be a finite 3x3 rotation, got shape {m.shape}")
    if not (np.allclose(m @ m.T, np.eye(3), rtol=0, atol=1e-9) and np.linalg.det(m) > 0):
        raise InputError("rvec as a matrix must be a rotation (orthonormal, determinant +1)")
    from scipy.spatial.transform import Rotation

    return tuple(float(v) for v in Rotation.from_matrix(m).as_rotvec())


def pose_from_position(position, rotation=(0.0, 0.0, 0.0)) -> dict:
    """OpenCV's ``rvec`` and ``tvec`` of a camera at ``position`` (dome frame, mm) with ``rotation``.

    Parameters
    ----------
    position : (3,) array_like
        The projection centre in the dome frame (mm).
    rotation : (3,) Rodrigues vector or (3, 3) matrix
        Dome-to-camera rotation ``R`` (identity: looking up the dome axis).

    Returns
    -------
    dict
        ``{"rvec": ..., "tvec": ...}`` with ``tvec = -R position``, to pass
        as keyword arguments to a camera.

    Examples
    --------
    >>> pose_from_position((0.3, 0.0, -5.0))["tvec"]
    (-0.3, -0.0, 5.0)
    """
    rot = np.asarray(rotation, dtype=np.float64)
    rvec = _rvec_from_matrix(rot) if rot.shape == (3, 3) else _vector(rot, "rotation", (3,))
    c = np.asarray(_vector(position, "position", (3,)))
    return {"rvec": rvec, "tvec": tuple(float(v) for v in -(rotation_from_rvec(rvec) @ c))}


@dataclass(frozen=True)
class _OpenCVCamera(Camera):
    """Intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, distortion ``dist``, pose ``rvec``/``tvec``."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple = ()
    rvec: tuple = (0.0, 0.0, 0.0)
    tvec: tuple = (0.0, 0.0, 5.0)

    _dist_sizes: ClassVar[tuple[int, ...]] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "width", integer(self.width, "width", minimum=2))
        object.__setattr__(self, "height", integer(self.height, "height", minimum=2))
        check_frame_size(self.width, self.height, "camera")
        for name in ("fx", "fy", "cx", "cy"):
            v = real_number(getattr(self, name), name)
            if not math.isfinite(v):
                raise InputError(f"{name} must be finite (pixels), got {v!r}")
            if name in ("fx", "fy") and v <= 0:
                raise InputError(f"{name} must be > 0 (pixels), got {v!r}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "dist", self._check_dist(self.dist))
        rv = np.asarray(self.rvec, dtype=np.float64) if not isinstance(self.rvec, str) else None
        if rv is not None and rv.shape == (3, 3):
            object.__setattr__(self, "rvec", _rvec_from_matrix(rv))
        else:
            object.__setattr__(self, "rvec", _vector(self.rvec, "rvec", (3,)))
        object.__setattr__(self, "tvec", _vector(self.tvec, "tvec (mm)", (3,)))

    def _check_dist(self, dist) -> tuple:
        if dist is None or (hasattr(dist, "__len__") and len(dist) == 0):
            return (0.0,) * self._dist_sizes[0]
        return _vector(dist, f"dist ({self.model} distortion coefficients)", self._dist_sizes)

    # ------------------------------------------------------------------ OpenCV's arrays
    @property
    def K(self) -> np.ndarray:  # noqa: N802 - OpenCV's name
        """(3, 3) camera matrix, as OpenCV's ``cameraMatrix``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:  # noqa: N802 - OpenCV's name
        """Distortion coefficients, as OpenCV's ``distCoeffs`` / ``D``."""
        return np.array(self.dist)

    @cached_property
    def rotation(self) -> np.ndarray:
        """(3, 3) dome-to-camera rotation, ``cv2.Rodrigues(rvec)``."""
        r = rotation_from_rvec(self.rvec)
        r.flags.writeable = False
        return r

    @cached_property
    def position(self) -> np.ndarray:
        """(3,) projection centre in the dome frame (mm): ``-R^T tvec``."""
        c = -(self.rotation.T @ np.array(self.tvec))
        c.flags.writeable = False
        return c

    @staticmethod
    def _invert_radial(g, rd: np.ndarray, xmax: float) -> tuple[np.ndarray, float]:
        """Root ``x`` in ``[0, xmax]`` of ``g(x) = min(rd, g(xmax))`` for increasing ``g``; and ``g(xmax)``."""
        gmax = float(g(np.array(xmax))[0])
        target = np.minimum(rd, gmax).ravel()

        def fun(x):
            v, dv = g(x)
            return v - target, dv

        x = bracketed_newton(fun, np.zeros_like(target), np.full_like(target, xmax), np.minimum(target, xmax))
        return x.reshape(rd.shape), gmax

    def _pixel(self, xd: np.ndarray, yd: np.ndarray) -> np.ndarray:
        return np.stack([self.fy * yd + self.cy, self.fx * xd + self.cx], axis=-1)

    def _normalised(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (p[..., 1] - self.cx) / self.fx, (p[..., 0] - self.cy) / self.fy


@dataclass(frozen=True)
class PinholeCamera(_OpenCVCamera):
    """OpenCV's pinhole camera with radial-tangential (and rational, thin-prism) distortion.

    Projects exactly as ``cv2.projectPoints(X, rvec, tvec, K, dist)``.

    Parameters
    ----------
    width, height : int
        Image size in pixels (the calibration's ``image_width``/``image_height``).
    fx, fy, cx, cy : float
        Focal lengths and principal point (pixels; ``cx`` along columns).
    dist : sequence of 4, 5, 8 or 12 floats, optional
        OpenCV's ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]])``;
        default no distortion. The tilted-sensor model (14 coefficients) is
        not supported.
    rvec : (3,) Rodrigues vector or (3, 3) matrix, optional
        Dome-to-camera rotation; default identity (looking up the dome axis).
    tvec : (3,) float, optional
        Dome-to-camera translation (mm), ``X_cam = R X_dome + tvec``; default
        ``(0, 0, 5)``: the camera at z = -5 mm on the axis. See
        :func:`pose_from_position`.

    Notes
    -----
    With ``(x, y) = (X / Z, Y / Z)`` in the camera frame, ``r^2 = x^2 + y^2``,
    ``x'' = x (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4`` (``y''`` likewise),
    ``col = fx x'' + cx``, ``row = fy y'' + cy``. Only points in front
    (``Z > 0``) within the radius where the radial distortion is monotone
    (``d(r rad(r))/dr > 0``, at most :data:`PINHOLE_MAX_RADIUS`) are imaged;
    pixels are undistorted by Newton's method on the 2-D map (analytic
    Jacobian) from the radial inverse, to rounding.

    Examples
    --------
    >>> cam = PinholeCamera(640, 480, fx=300.0, fy=300.0, cx=319.5, cy=239.5, dist=(-0.1, 0.01, 0, 0))
    >>> cam.pixel_from_point([[0.0, 0.0, 10.0]]).tolist()  # on the axis: the principal point
    [[239.5, 319.5]]
    """

    model: ClassVar[str] = "pinhole"
    _dist_sizes: ClassVar[tuple[int, ...]] = (5, 4, 8, 12)

    def _check_dist(self, dist) -> tuple:
        n = np.size(dist) if dist is not None else 0
        if n == 14:
            raise InputError("dist: 14 coefficients are OpenCV's tilted-sensor model (tauX, tauY), which this "
                             "camera does not support; use 4, 5, 8 or 12 coefficients (k1, k2, p1, p2[, k3[, "
                             "k4, k5, k6[, s1..s4]]])")
        return super()._check_dist(dist)

    def _coefficients(self) -> tuple[float, ...]:
        d = self.dist + (0.0,) * (12 - len(self.dist))
        return d  # k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4

    def _distort(self, x, y, jacobian: bool = False):
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = self._coefficients()
        r2 = x * x + y * y
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        rad = num / den
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
        if not jacobian:
            return xd, yd
        dnum, dden = k1 + r2 * (2 * k2 + 3 * k3 * r2), k4 + r2 * (2 * k5 + 3 * k6 * r2)
        drad = (dnum * den - num * dden) / (den * den)
        j11 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * s1 * x + 4 * s2 * r2 * x
        j12 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * s1 * y + 4 * s2 * r2 * y
        j21 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * s3 * x + 4 * s4 * r2 * x
        j22 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * s3 * y + 4 * s4 * r2 * y
        return xd, yd, j11, j12, j21, j22

    def _radial(self, r):
        """``g(r) = r rad(r)`` and ``g'(r)`` (radial distortion only)."""
        k1, k2, _, _, k3, k4, k5, k6 = self._coefficients()[:8]
        r2 = r * r
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = r * (2 * k1 + r2 * (4 * k2 + 6 * k3 * r2))
        dden = r * (2 * k4 + r2 * (4 * k5 + 6 * k6 * r2))
        with np.errstate(divide="ignore", invalid="ignore"):  # den = 0: beyond the imaged range
            return r * num / den, num / den + r * (dnum * den - num * dden) / (den * den), den

    @cached_property
    def max_radius(self) -> float:
        """Largest undistorted normalised radius imaged: the first fold (Jacobian <= 0) at any azimuth."""
        phi = np.linspace(0.0, 2.0 * np.pi, 180, endpoint=False)
        r = np.concatenate([[0.0], np.geomspace(1e-3, PINHOLE_MAX_RADIUS, 3000)])

        def good(rr, ph):
            x, y = rr * np.cos(ph), rr * np.sin(ph)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                _, _, j11, j12, j21, j22 = self._distort(x, y, jacobian=True)
                return (j11 * j22 - j12 * j21 > 0) & (self._radial(rr)[1] > 0) & (self._radial(rr)[2] > 0)

        ok = good(r[:, None], phi[None, :])  # (r, phi)
        if ok.all():
            return PINHOLE_MAX_RADIUS
        first = np.argmin(ok, axis=0)  # first bad radius per azimuth (0 where all good)
        first = np.where(ok.all(axis=0), len(r) - 1, first)
        lo, hi = r[np.maximum(first - 1, 0)], r[first]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            g = good(mid, phi)
            lo, hi = np.where(g, mid, lo), np.where(g, hi, mid)
        return float(lo.min())

    def _pixel_from_camera_ray(self, d: np.ndarray) -> np.ndarray:
        z = d[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = d[..., 0] / z, d[..., 1] / z
        ok = (z > 0) & (np.hypot(x, y) <= self.max_radius)
        x, y = np.where(ok, x, 0.0), np.where(ok, y, 0.0)
        px = self._pixel(*self._distort(x, y))
        px[~ok] = np.nan
        return px

    def _camera_ray_from_pixel(self, p: np.ndarray) -> np.ndarray:
        xd, yd = self._normalised(p)
        rd = np.hypot(xd, yd)
        rmax = self.max_radius
        # radial inverse for a start, then Newton on the full 2-D map
        r0, _ = self._invert_radial(lambda r: self._radial(r)[:2], rd, rmax)
        scale = np.divide(r0, rd, out=np.ones_like(rd), where=rd > 0)
        x, y = xd * scale, yd * scale
        for _ in range(50):
            fx_, fy_, j11, j12, j21, j22 = self._distort(x, y, jacobian=True)
            ex, ey = fx_ - xd, fy_ - yd
            det = j11 * j22 - j12 * j21
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (j22 * ex - j12 * ey) / det
                dy = (j11 * ey - j21 * ex) / det
            dx, dy = np.where(np.isfinite(dx), dx, 0.0), np.where(np.isfinite(dy), dy, 0.0)
            # a step beyond the imaged range (past the fold) is shortened to land inside it
            nr = np.hypot(x - dx, y - dy)
            shrink = np.where(nr > rmax, 0.5, 1.0)
            dx, dy = dx * shrink, dy * shrink
            x, y = x - dx, y - dy
            if np.all(np.abs(dx) + np.abs(dy) <= 1e-16 * (1 + np.abs(x) + np.abs(y))):
                break
        fx_, fy_ = self._distort(x, y)
        res = np.hypot(fx_ - xd, fy_ - yd)
        ok = (res <= 1e-11 * (1 + rd)) & (np.hypot(x, y) <= rmax * (1 + 1e-9))
        d = np.stack([x, y, np.ones_like(x)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        d[~ok] = np.nan
        return d


@dataclass(frozen=True)
class OpenCVFisheyeCamera(_OpenCVCamera):
    """OpenCV's fisheye camera (Kannala-Brandt, ``cv2.fisheye``), distortion ``(k1, k2, k3, k4)``.

    Projects exactly as ``cv2.fisheye.projectPoints(X, rvec, tvec, K, D)``
    (no skew) for points in front of the camera, and beyond 90 deg by the
    same polynomial in the ray angle.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    fx, fy, cx, cy : float
        Focal lengths and principal point (pixels; ``cx`` along columns).
    dist : sequence of 4 floats, optional
        ``(k1, k2, k3, k4)``; default 0 (the equidistant model ``r = f theta``).
    rvec, tvec : optional
        The pose, as for :class:`PinholeCamera`.

    Notes
    -----
    With ``theta = atan2(hypot(X, Y), Z)`` the ray's angle from the optical
    axis, ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
    k4 theta^8)``, ``(x', y') = theta_d (X, Y) / hypot(X, Y)``,
    ``col = fx x' + cx``, ``row = fy y' + cy``. Rays up to the angle where
    ``theta_d`` stops increasing (at most 180 deg) are imaged; pixels are
    undistorted by bracketed Newton steps on ``theta_d``, to rounding.

    Examples
    --------
    >>> cam = OpenCVFisheyeCamera(640, 480, fx=200.0, fy=200.0, cx=319.5, cy=239.5)
    >>> bool(np.allclose(cam.pixel_from_ray(cam.ray_from_pixel([[10.0, 20.0]])), [[10.0, 20.0]], atol=1e-9))
    True
    """

    model: ClassVar[str] = "opencv_fisheye"
    _dist_sizes: ClassVar[tuple[int, ...]] = (4,)

    def _theta_d(self, t):
        k1, k2, k3, k4 = self.dist
        t2 = t * t
        return (t * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))),
                1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4))))

    @cached_property
    def max_angle(self) -> float:
        """Largest ray angle from the optical axis imaged (rad): where ``theta_d`` stops increasing, <= pi."""
        t = np.linspace(0.0, math.pi, 100_001)
        bad = np.flatnonzero(self._theta_d(t)[1] <= 0)
        if bad.size == 0:
            return math.pi
        lo, hi = t[bad[0] - 1], t[bad[0]]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self._theta_d(mid)[1] > 0 else (lo, mid)
        return float(lo)

    def _pixel_from_camera_ray(self, d: np.ndarray) -> np.ndarray:
        rxy = np.hypot(d[..., 0], d[..., 1])
        theta = np.arctan2(rxy, d[..., 2])
        td = self._theta_d(theta)[0]
        scale = np.divide(td, rxy, out=np.zeros_like(td), where=rxy > 0)
        px = self._pixel(d[..., 0] * scale, d[..., 1] * scale)
        px[theta > self.max_angle] = np.nan
        return px

    def _camera_ray_from_pixel(self, p: np.ndarray) -> np.ndarray:
        xd, yd = self._normalised(p)
        rd = np.hypot(xd, yd)
        theta, tdmax = self._invert_radial(self._theta_d, rd, self.max_angle)
        s = np.divide(np.sin(theta), rd, out=np.zeros_like(rd), where=rd > 0)
        d = np.stack([xd * s, yd * s, np.cos(theta)], axis=-1)
        d[rd > tdmax] = np.nan
        return d


for _cls in (PinholeCamera, OpenCVFisheyeCamera):
    CAMERA_MODELS[_cls.model] = _cls
