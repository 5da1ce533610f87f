"""Cameras looking through the dome: the camera models' common base, the default fisheye, and the optics.

One concept, a camera looking at the dome's outer surface through the acrylic
shell. :class:`Camera` is the common interface of the models (intrinsics,
distortion and pose); :class:`FisheyeCamera` (the default) is an equidistant
fisheye on the dome axis looking up it; :class:`optitact.optics.camera_models.PinholeCamera`
and :class:`optitact.optics.camera_models.OpenCVFisheyeCamera` take intrinsics,
distortion and a pose exactly as OpenCV defines them.

A spot on the outer dome surface is seen through the inner spherical surface
only: its light refracts once, at the inner sphere, on its way to the camera.
:func:`pixel_from_dome` and :func:`dome_from_pixel` map outer-surface points to
pixels and back in closed form for every camera model; :func:`radial_map` is
the rotationally symmetric map of a camera on the dome axis (the default
:class:`FisheyeCamera`). A camera's own methods (:meth:`Camera.project`,
:meth:`Camera.unproject`, :meth:`Camera.visible`, ...) are these optics, which is
why the models and the optics share this module.

Convention
----------
Image indices are ``(row, col)`` with the origin at the centre of the top-left
pixel, as in scikit-image and SciPy; a pixel covers ``[col - 0.5, col + 0.5)``.
OpenCV's pixel ``(u, v)`` is ``(col, row)`` (the same origin).
Physical coordinates are global ``(x, y, z)`` in mm (see :mod:`optitact.optics.sensor`),
the *dome frame*: z up the dome axis, the base plane at z = 0.
The *camera frame* is OpenCV's: x right (growing columns), y down (growing
rows), z forward along the optical axis. A camera's pose maps dome points to
camera points as OpenCV's ``rvec``/``tvec`` do: ``X_cam = R X_dome + t``.
The default camera sits on the dome axis at ``(0, 0, z)`` and looks along +z
with ``R = I``: image columns grow with global +x and rows with global +y (a
right-handed camera frame seen from below, not mirrored).
"""

from __future__ import annotations

import importlib
import math
import numbers
import os
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from typing import ClassVar

import numpy as np

from optitact._validate import check_keys, check_type, finite, integer, positive, real_array, shape_tail
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["Camera", "FisheyeCamera", "MAX_FRAME_PIXELS", "RadialMap", "bracketed_newton", "camera_from_dict",
           "camera_model", "check_camera_inside", "check_frame_size", "dome_from_pixel", "pixel_from_dome",
           "radial_map", "rotation_from_rvec", "trace_through_dome"]

#: Largest image (width x height, pixels) a camera or a frame may have: 4096 x 4096. The
#: pipeline's set-up grows with the pixels of the element regions: for a full-field camera about
#: 70 bytes per image pixel at its peak and 55 kept (cached per camera; 20 MiB at 640 x 480,
#: 0.3 GiB at 2560 x 1920, about 1.4 GiB at 4096 x 4096), so a bigger frame is refused before
#: anything is allocated. Override with the environment variable ``OPTITACT_MAX_FRAME_PIXELS``
#: (an integer number of pixels).
MAX_FRAME_PIXELS = 4096 * 4096
_MAX_PIXELS_ENV = "OPTITACT_MAX_FRAME_PIXELS"


def check_frame_size(width: int, height: int, source: str = "frame") -> None:
    """Refuse an image of more than :data:`MAX_FRAME_PIXELS` pixels (or the environment's limit).

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    source : str
        What the size belongs to (a file name, ``"camera"``), for the message.

    Raises
    ------
    InputError
        For a larger image, naming the limit and how to raise it.
    """
    limit = MAX_FRAME_PIXELS
    text = os.environ.get(_MAX_PIXELS_ENV)
    if text:
        try:
            limit = int(text)
        except ValueError:
            raise InputError(f"{_MAX_PIXELS_ENV} must be an integer number of pixels, got {text!r}") from None
    if int(width) * int(height) > limit:
        raise InputError(
            f"{source}: frame too large: {width}x{height} = {int(width) * int(height):,} pixels, more than "
            f"the {limit:,} this camera model accepts (optitact.optics.camera.MAX_FRAME_PIXELS; the set-up "
            f"needs about 70 bytes per pixel); downsample the frames, or set {_MAX_PIXELS_ENV} to "
            f"allow more")


#: Camera models by the ``model`` key of their :meth:`Camera.to_dict` (filled by the classes).
CAMERA_MODELS: dict[str, type] = {}

#: Where each camera model the package ships is defined: :meth:`Camera.from_dict` imports the
#: module of a model not yet registered, so that any process reads any shipped model's
#: parameters whatever it imported before (a setup file names ``opencv_fisheye`` in a process
#: that never imported :mod:`optitact.optics.camera_models`).
SHIPPED_CAMERA_MODELS: dict[str, str] = {"equidistant": "optitact.optics.camera",
                                         "pinhole": "optitact.optics.camera_models",
                                         "opencv_fisheye": "optitact.optics.camera_models"}


def camera_model(name: str) -> type:
    """The camera class of a ``model`` name, importing the shipped model's module where needed.

    Raises
    ------
    InputError
        For a name that is neither registered nor shipped (listing the valid ones).
    """
    if name not in CAMERA_MODELS and isinstance(name, str) and name in SHIPPED_CAMERA_MODELS:
        importlib.import_module(SHIPPED_CAMERA_MODELS[name])
    if name not in CAMERA_MODELS:
        valid = sorted(set(CAMERA_MODELS) | set(SHIPPED_CAMERA_MODELS))
        raise InputError(f"camera parameters: unknown model {name!r}; valid: {valid}")
    return CAMERA_MODELS[name]


class Camera(ABC):
    """Common interface of the camera models: intrinsics, distortion and pose, seen through the dome.

    Subclasses are frozen dataclasses with ``width`` and ``height`` (pixels)
    and a ``model`` name; they are compared and hashed by value (a pipeline's
    set-up is cached per sensor and camera). :class:`FisheyeCamera` is the
    default; :mod:`optitact.optics.camera_models` has OpenCV's pinhole and fisheye
    models.

    Convention
    ----------
    Pixels are ``(row, col)``; rays and points are in the dome frame (mm);
    :attr:`rotation` ``R`` and the camera's centre :attr:`position` ``C``
    relate the frames: ``X_cam = R (X_dome - C)`` with the camera frame
    OpenCV's (x right, y down, z forward).
    """

    model: ClassVar[str] = ""
    width: int
    height: int

    # ------------------------------------------------------------------ what a model provides
    @property
    @abstractmethod
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation from the dome frame to the camera frame (OpenCV's ``R``)."""

    @property
    @abstractmethod
    def position(self) -> np.ndarray:
        """(3,) the camera's projection centre in the dome frame (mm): ``-R^T t``."""

    @abstractmethod
    def _pixel_from_camera_ray(self, d: np.ndarray) -> np.ndarray:
        """Pixels ``(row, col)`` of camera-frame directions ``(..., 3)``; NaN where the model sees nothing."""

    @abstractmethod
    def _camera_ray_from_pixel(self, p: np.ndarray) -> np.ndarray:
        """Unit camera-frame directions of pixels ``(..., 2)``; NaN where no ray maps there."""

    def to_dict(self) -> dict:
        """Return the parameters as a JSON-friendly dict (with its ``model`` key)."""
        d = {"model": self.model}
        for f in fields(self):
            v = getattr(self, f.name)
            d[f.name] = list(v) if isinstance(v, tuple) else v
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        """Build a camera from :meth:`to_dict` output, the model chosen by its ``model`` key.

        A dict without ``model`` is today's :class:`FisheyeCamera` (setup
        files and calibrations written before the other models existed);
        called on a subclass, the dict must be of that model.

        Raises
        ------
        TypeError
            For a non-mapping.
        InputError
            For an unknown model (listing the valid ones), a model other than
            the class's, unknown keys or invalid values.
        """
        if not isinstance(d, Mapping):
            raise TypeError(f"camera parameters must be a dict, got {type(d).__name__}")
        model = d.get("model", "equidistant" if cls is Camera else cls.model)
        if not isinstance(model, str):
            raise InputError(f"camera parameters: model must be a name (str), got {model!r}")
        model_cls = camera_model(model)
        if cls is Camera:
            return model_cls.from_dict(d)
        if model != cls.model:
            raise InputError(f"camera parameters: model {model!r} is not a {cls.__name__} ({cls.model!r}); "
                             f"read it with optitact.optics.camera.camera_from_dict")
        params = {k: v for k, v in d.items() if k != "model"}
        return cls(**check_keys(params, [f.name for f in fields(cls)], "camera parameters", noun="parameter"))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

    # ------------------------------------------------------------------ rays
    def ray_from_pixel(self, pixels) -> np.ndarray:
        """Unit ray directions (dome frame) for pixel positions ``(row, col)``, shape (..., 3).

        Undistortion is exact (Newton's method to rounding, not OpenCV's fixed
        iteration count); pixels no ray maps to (beyond the distortion's
        monotone range) give NaN rows.
        """
        p = finite(shape_tail(real_array(pixels, "pixels"), (2,), "pixels", "(..., 2) (row, col)"), "pixels")
        return self._camera_ray_from_pixel(p) @ self.rotation

    def pixel_from_ray(self, directions) -> np.ndarray:
        """Pixel positions ``(row, col)`` of ray directions (dome frame, need not be unit), shape (..., 2).

        Directions the model cannot image (behind a pinhole camera, beyond
        the distortion's monotone range) give NaN rows.
        """
        d = finite(shape_tail(real_array(directions, "directions"), (3,), "directions", "(..., 3)"),
                   "directions")
        return self._pixel_from_camera_ray(d @ self.rotation.T)

    def pixel_from_point(self, points) -> np.ndarray:
        """Pixels ``(row, col)`` of dome-frame points (mm) seen straight, without the dome.

        The same as ``cv2.projectPoints`` (``cv2.fisheye.projectPoints`` for
        the fisheye model) with the camera's ``rvec``, ``tvec``, ``K`` and
        ``D``, swapped to ``(row, col)``; NaN where the model sees nothing.
        """
        p = finite(shape_tail(real_array(points, "points"), (3,), "points", "(..., 3)"), "points")
        return self.pixel_from_ray(p - self.position)

    # ------------------------------------------------------------------ through the dome
    def project(self, points, sensor: DomeSensor, *, outside: str = "raise",
                refraction: bool = True) -> np.ndarray:
        """Pixels ``(row, col)`` where points on the outer dome surface appear; see :func:`pixel_from_dome`."""
        return pixel_from_dome(points, sensor=sensor, camera=self, outside=outside, refraction=refraction)

    def unproject(self, pixels, sensor: DomeSensor, *, outside: str = "raise",
                  refraction: bool = True) -> np.ndarray:
        """Outer-surface dome points seen at pixels ``(row, col)``; see :func:`dome_from_pixel`."""
        return dome_from_pixel(pixels, sensor=sensor, camera=self, outside=outside, refraction=refraction)

    def visible(self, points, sensor: DomeSensor) -> np.ndarray:
        """Bool (...,): outer-surface points this camera sees through the inner surface.

        Points below the base plane are not seen; a seen point may still fall
        outside the image.
        """
        check_type(sensor, DomeSensor, "sensor")
        p = finite(shape_tail(real_array(points, "points"), (3,), "points", "(..., 3)"), "points")
        out = np.zeros(p.shape[:-1], bool)
        up = p[..., 2] >= 0
        if up.any():
            out[up] = np.isfinite(_generic_pixel_from_dome(p[up], sensor, self, True)).all(axis=-1)
        return out

    def dome_mask(self, sensor: DomeSensor) -> np.ndarray:
        """(H, W) bool: pixel centres whose ray reaches the outer dome surface (z >= 0)."""
        check_type(sensor, DomeSensor, "sensor")
        rows, cols = np.mgrid[0:self.height, 0:self.width]
        pts = dome_from_pixel(np.stack([rows, cols], axis=-1).astype(np.float64), sensor=sensor, camera=self,
                              outside="nan")
        return np.isfinite(pts[..., 0])

    def max_polar_angle(self, sensor: DomeSensor) -> float:
        """The largest polar angle (rad) up to which the camera sees the dome at every azimuth.

        For an on-axis camera the whole cap within it is visible and nothing
        beyond it; for an off-axis or tilted camera the visible region is not
        a cap and this is its largest inscribed cap (720 azimuths, each
        bisected to 1e-12 rad): use :meth:`visible` for single points.
        """
        check_type(sensor, DomeSensor, "sensor")
        return _max_polar_angle_cached(self, sensor)


def camera_from_dict(d: dict) -> Camera:
    """Build any camera model from its :meth:`Camera.to_dict` (no ``model`` key: :class:`FisheyeCamera`)."""
    return Camera.from_dict(d)


def rotation_from_rvec(rvec) -> np.ndarray:
    """Rotation matrix of a Rodrigues vector (axis times angle, rad), as ``cv2.Rodrigues``.

    Parameters
    ----------
    rvec : (3,) array_like
        Rotation axis times angle (rad), OpenCV's ``rvec``.

    Returns
    -------
    (3, 3) ndarray
        The rotation matrix (the identity for a zero vector).
    """
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


@dataclass(frozen=True)
class FisheyeCamera(Camera):
    """Equidistant fisheye camera (``r = f * alpha``) on the dome axis: the default camera.

    Parameters
    ----------
    width, height : int
        Image size in pixels, default 640 x 480; at least 2 each and at most
        :data:`MAX_FRAME_PIXELS` in all (see :func:`check_frame_size`). The
        pipeline needs more than 2: too small a frame for the sensor is
        refused by :func:`optitact.pipeline.regions.split_regions` ("frame too
        small", naming the minimum).
    fov_deg : float
        Full field of view across the image's shorter side (deg), default 140;
        the image circle of that field touches the shorter sides.
    z : float
        Height of the projection centre on the dome axis (mm), default -5
        (below the dome's base plane, as a fiberscope under the dome).

    Examples
    --------
    >>> cam = FisheyeCamera()
    >>> s = DomeSensor.default()
    >>> px = cam.project(s.element_positions, s)
    >>> bool(np.allclose(cam.unproject(px, s), s.element_positions, atol=1e-9))
    True
    """

    model: ClassVar[str] = "equidistant"
    width: int = 640
    height: int = 480
    fov_deg: float = 140.0
    z: float = -5.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "width", integer(self.width, "width", minimum=2))
        object.__setattr__(self, "height", integer(self.height, "height", minimum=2))
        check_frame_size(self.width, self.height, "camera")
        object.__setattr__(self, "fov_deg", positive(self.fov_deg, "fov_deg"))
        if self.fov_deg >= 360.0:
            raise InputError(f"fov_deg must be in (0, 360), got {self.fov_deg}")
        if isinstance(self.z, bool) or not isinstance(self.z, numbers.Real):
            raise TypeError(f"z must be a real number (mm), got {type(self.z).__name__}")
        if not math.isfinite(self.z):
            raise InputError(f"z must be finite (mm), got {self.z!r}")
        object.__setattr__(self, "z", float(self.z))

    def to_dict(self) -> dict:
        """Return the parameters as a JSON-friendly dict.

        Without a ``model`` key (as before the other models existed, so
        fingerprints of calibrations made for it are unchanged): a camera dict
        without one is this model.
        """
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> FisheyeCamera:
        """Build a camera from :meth:`to_dict` output; unknown keys are a ValueError.

        A ``model`` key, if present, must be ``"equidistant"``.
        """
        if isinstance(d, Mapping) and "model" in d:
            if d["model"] != cls.model:
                raise InputError(f"camera parameters: model {d['model']!r} is not a FisheyeCamera "
                                 f"('equidistant'); read it with optitact.optics.camera.camera_from_dict")
            d = {k: v for k, v in d.items() if k != "model"}
        return cls(**check_keys(d, [f.name for f in fields(cls)], "camera parameters", noun="parameter"))

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) identity: the camera frame is the dome frame's orientation."""
        return np.eye(3)

    @property
    def position(self) -> np.ndarray:
        """(3,) ``(0, 0, z)``: on the dome axis."""
        return np.array([0.0, 0.0, self.z])

    @property
    def center(self) -> tuple[float, float]:
        """Principal point ``(row, col)``: the image centre."""
        return ((self.height - 1) / 2.0, (self.width - 1) / 2.0)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels per radian: ``f = (min(W, H) / 2) / (fov / 2)``."""
        return (min(self.width, self.height) / 2.0) / (math.radians(self.fov_deg) / 2.0)

    # ------------------------------------------------------------------ rays
    def ray_from_pixel(self, pixels) -> np.ndarray:
        """Unit ray directions (global) for pixel positions ``(row, col)``, shape (..., 3).

        Notes
        -----
        With ``(dr, dc) = (row, col) - center``, ``r = hypot(dr, dc)``, the
        equidistant model gives the angle from the axis ``alpha = r / f`` and the
        azimuth ``phi = atan2(dr, dc)``; the direction is
        ``(sin a cos phi, sin a sin phi, cos a)``.
        """
        alpha, phi = self._polar_from_pixel(pixels)
        return np.stack([np.sin(alpha) * np.cos(phi), np.sin(alpha) * np.sin(phi),
                         np.cos(alpha)], axis=-1)

    def pixel_from_ray(self, directions) -> np.ndarray:
        """Pixel positions ``(row, col)`` of ray directions (need not be unit), shape (..., 2)."""
        d = finite(shape_tail(real_array(directions, "directions"), (3,), "directions",
                              "(..., 3)"), "directions")
        alpha = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
        phi = np.arctan2(d[..., 1], d[..., 0])
        return self._pixel_from_polar(alpha, phi)

    def _pixel_from_camera_ray(self, d: np.ndarray) -> np.ndarray:
        alpha = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
        return self._pixel_from_polar(alpha, np.arctan2(d[..., 1], d[..., 0]))

    def _camera_ray_from_pixel(self, p: np.ndarray) -> np.ndarray:
        return self.ray_from_pixel(p)

    def _polar_from_pixel(self, pixels) -> tuple[np.ndarray, np.ndarray]:
        p = finite(shape_tail(real_array(pixels, "pixels"), (2,), "pixels", "(..., 2) (row, col)"),
                   "pixels")
        cy, cx = self.center
        dr, dc = p[..., 0] - cy, p[..., 1] - cx
        return np.hypot(dr, dc) / self.focal_px, np.arctan2(dr, dc)

    def _pixel_from_polar(self, alpha: np.ndarray, phi: np.ndarray) -> np.ndarray:
        cy, cx = self.center
        r = self.focal_px * alpha
        return np.stack([cy + r * np.sin(phi), cx + r * np.cos(phi)], axis=-1)

    # ------------------------------------------------------------------ through the dome
    def visible(self, points, sensor: DomeSensor) -> np.ndarray:
        """Bool (...,): outer-surface points seen through the inner surface (polar angle <= the limit)."""
        check_type(sensor, DomeSensor, "sensor")
        p = finite(shape_tail(real_array(points, "points"), (3,), "points", "(..., 3)"), "points")
        theta = np.arccos(np.clip(p[..., 2] / sensor.outer_radius, -1.0, 1.0))
        return theta <= self.max_polar_angle(sensor)

    def dome_mask(self, sensor: DomeSensor) -> np.ndarray:
        """(H, W) bool: pixel centres whose ray reaches the outer dome surface (z >= 0)."""
        rows, cols = np.mgrid[0:self.height, 0:self.width]
        alpha, _ = self._polar_from_pixel(np.stack([rows, cols], axis=-1))
        return alpha <= radial_map(sensor, self.z).alpha_max

    def max_polar_angle(self, sensor: DomeSensor) -> float:
        """The largest polar angle (rad, from the dome axis) of an outer-surface point this camera sees.

        Points farther from the apex are hidden below the inner surface's base
        (seen only through the rim); about 88.35 deg for the default sensor
        and camera. See :func:`radial_map`.
        """
        return radial_map(sensor, self.z).theta_max


CAMERA_MODELS[FisheyeCamera.model] = FisheyeCamera


# ------------------------------------------------------------------ the optics through the dome

#: Largest distance (mm) a point given to :func:`pixel_from_dome` may lie off the outer surface.
SURFACE_TOLERANCE = 1e-4


class RadialMap:
    """Polar angle of the seen dome point as a function of the ray angle, and its inverse.

    The camera is on the axis, so the map is rotationally symmetric: a ray at
    angle ``alpha`` from the axis, refracted at the inner surface, meets the
    outer surface at polar angle ``theta(alpha)`` with the same azimuth.
    """

    def __init__(self, r_in: float, r_out: float, n: float, zc: float) -> None:
        if not -r_in < zc < r_in:
            raise InputError(
                f"camera z must lie inside the dome's inner sphere (|z| < {r_in} mm), got {zc}"
            )
        self.r_in, self.r_out, self.n, self.zc = r_in, r_out, n, zc
        # alpha_max: the last ray that still crosses the inner surface above the base
        # plane and reaches the outer surface at z >= 0.
        lo, hi = 0.0, math.pi
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            th, ok = self.theta(np.array([mid]))
            if ok[0] and th[0] <= math.pi / 2:
                lo = mid
            else:
                hi = mid
        self.alpha_max = lo
        self.theta_max = float(self.theta(np.array([lo]))[0][0])
        self._alpha_tab = np.linspace(0.0, lo, 4097)
        self._theta_tab = self.theta(self._alpha_tab)[0]
        if np.any(np.diff(self._theta_tab) <= 0):
            raise InputError("camera position gives a non-monotone view of the dome")

    def theta(self, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Polar angle of the outer-surface point hit by rays at ``alpha``, and validity."""
        sa, ca = np.sin(alpha), np.cos(alpha)
        zc = self.zc
        cd = zc * ca
        t = -cd + np.sqrt(cd * cd - zc * zc + self.r_in**2)
        qx, qz = t * sa, zc + t * ca  # hit on the inner sphere (rho, z)
        nx, nz = qx / self.r_in, qz / self.r_in
        cos_i = sa * nx + ca * nz
        eta = 1.0 / self.n
        cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
        tx = eta * sa + (cos_t - eta * cos_i) * nx
        tz = eta * ca + (cos_t - eta * cos_i) * nz
        qt = qx * tx + qz * tz
        s = -qt + np.sqrt(qt * qt - self.r_in**2 + self.r_out**2)
        px, pz = qx + s * tx, qz + s * tz
        return np.arctan2(px, pz), (qz >= 0) & (pz >= 0)

    def alpha(self, theta: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`theta` on ``[0, pi/2]``: table start, then Newton steps."""
        a = np.interp(theta, self._theta_tab, self._alpha_tab)
        h = 1e-7
        for _ in range(6):
            th = self.theta(a)[0]
            slope = (self.theta(a + h)[0] - self.theta(a - h)[0]) / (2 * h)
            a = np.clip(a - (th - theta) / slope, 0.0, self.alpha_max)
        return a


@lru_cache(maxsize=32)
def _radial_map_cached(r_in: float, r_out: float, n: float, zc: float) -> RadialMap:
    return RadialMap(r_in, r_out, n, zc)


def radial_map(sensor: DomeSensor, zc: float, *, refraction: bool = True) -> RadialMap:
    """The radial map of an on-axis camera at height ``zc`` (mm) inside ``sensor`` (cached).

    ``radial_map(sensor, camera.z).theta(alpha)`` is the polar angle of the
    outer-surface point seen by a ray at angle ``alpha`` from the axis;
    ``theta_max`` and ``alpha_max`` bound what the camera sees (see
    :meth:`FisheyeCamera.max_polar_angle`). ``refraction=False`` gives the
    map of straight rays (a refractive index of 1).
    """
    check_type(sensor, DomeSensor, "sensor")
    return _radial_map_cached(sensor.inner_radius, sensor.outer_radius,
                              sensor.refractive_index if refraction else 1.0, float(zc))


def _check_optics(sensor, camera, outside: str = "raise") -> None:
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, Camera, "camera")
    if outside not in ("raise", "nan"):
        raise InputError(f"outside must be 'raise' or 'nan', got {outside!r}")


def _index(sensor: DomeSensor, refraction) -> float:
    if not isinstance(refraction, (bool, np.bool_)):
        raise TypeError(f"refraction must be True or False, got {type(refraction).__name__}")
    return sensor.refractive_index if refraction else 1.0


def bracketed_newton(fun, lo: np.ndarray, hi: np.ndarray, x: np.ndarray, iters: int = 200) -> np.ndarray:
    """Roots of increasing functions, elementwise, to rounding: Newton's steps kept inside a bracket.

    Newton's steps, replaced by bisection when one leaves the bracket; the
    bracket shrinks around every root, so it cannot diverge. Used for the
    refraction point of :func:`pixel_from_dome` and for the exact
    undistortion of :mod:`optitact.optics.camera_models`.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (f, f')``: the values and derivatives of the increasing
        functions at ``x`` (arrays of ``x``'s shape).
    lo, hi : ndarray
        Brackets with ``f(lo) <= 0 <= f(hi)``, elementwise.
    x : ndarray
        Starting points, within ``[lo, hi]``.
    iters : int
        Most steps (default 200); it stops earlier once every step is below
        rounding (``2e-16`` relative) or lands on a zero.

    Returns
    -------
    ndarray
        The roots, shaped as ``x``.
    """
    lo, hi, x = lo.copy(), hi.copy(), x.copy()
    for _ in range(iters):
        f, fp = fun(x)
        neg = f < 0
        lo = np.where(neg, x, lo)
        hi = np.where(neg, hi, x)
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = x - f / fp
        bad = ~np.isfinite(xn) | (xn < lo) | (xn > hi)
        xn = np.where(bad, 0.5 * (lo + hi), xn)
        done = (np.abs(xn - x) <= 2e-16 * np.maximum(1.0, np.abs(x))) | (f == 0)
        x = xn
        if done.all():
            break
    return x


def trace_through_dome(c: np.ndarray, d: np.ndarray, r_in: float, r_out: float,
                       n: float) -> tuple[np.ndarray, np.ndarray]:
    """The outer-surface points that camera rays reach through the inner sphere, and their validity.

    Closed form: the ray ``c + t d`` meets the inner sphere at ``Q`` (the
    camera is inside it), refracts by Snell's law in vector form and meets
    the outer sphere at ``P``. The forward half of :func:`dome_from_pixel`,
    for rays given in the dome frame.

    Parameters
    ----------
    c : (3,) ndarray
        The rays' origin (the camera's :attr:`Camera.position`, mm, dome
        frame), inside the inner sphere (see :func:`check_camera_inside`).
    d : (..., 3) ndarray
        Ray directions in the dome frame (need not be unit).
    r_in, r_out : float
        The dome's inner and outer radius (mm).
    n : float
        The dome's refractive index (1: straight rays).

    Returns
    -------
    points : (..., 3) ndarray
        ``P`` on the outer sphere (mm, dome frame).
    valid : (...,) bool ndarray
        Where ``Q`` and ``P`` both lie at ``z >= 0`` (the ray sees the dome).
    """
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ c
    t = -b + np.sqrt(b * b - (c @ c - r_in * r_in))
    q = c + t[..., None] * d
    nh = q / r_in
    cos_i = np.sum(d * nh, axis=-1)
    eta = 1.0 / n
    cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
    tr = eta * d + (cos_t - eta * cos_i)[..., None] * nh
    qt = np.sum(q * tr, axis=-1)
    s = -qt + np.sqrt(qt * qt - r_in * r_in + r_out * r_out)
    p = q + s[..., None] * tr
    return p, (q[..., 2] >= 0) & (p[..., 2] >= 0)


def _rays_to(p: np.ndarray, c: np.ndarray, r_in: float, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays from ``c`` that reach outer-surface points ``p`` (N, 3) after refraction, and validity.

    The path ``c -> Q -> p`` lies in the plane through the sphere's centre,
    ``c`` and ``p`` (the normal at ``Q`` passes through the centre). In that
    plane ``Q = r_in (cos psi e1 + sin psi e2)`` with ``e1`` towards ``p``
    and ``c = (c1, c2)``, ``c2 >= 0``; Snell's law is the root of the
    increasing ``f(psi) = sin_i - n sin_t =
    (c1 sin psi - c2 cos psi) / |Q - c| + n |p| sin psi / |p - Q|``,
    bracketed by 0 (``f <= 0``) and the straight line's ``psi_s``
    (``f >= 0``), found to rounding by bracketed Newton steps.
    """
    rp = np.linalg.norm(p, axis=-1)
    e1 = p / rp[:, None]
    c1 = e1 @ c
    perp = c - c1[:, None] * e1
    c2 = np.linalg.norm(perp, axis=-1)
    small = c2 <= 1e-15 * r_in
    # any unit vector normal to e1 where c lies on the line through p (then psi = 0)
    alt = np.cross(e1, np.where(np.abs(e1[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    e2 = np.where(small[:, None], alt, perp) / np.where(small, np.linalg.norm(alt, axis=-1), c2)[:, None]
    cc = c @ c
    u = p - c
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    b = u @ c
    qs = c + (-b + np.sqrt(b * b - cc + r_in * r_in))[:, None] * u
    psi_s = np.maximum(np.arctan2(np.sum(qs * e2, -1), np.sum(qs * e1, -1)), 0.0)

    def fun(psi):
        sn, cs = np.sin(psi), np.cos(psi)
        a, da = c1 * sn - c2 * cs, c1 * cs + c2 * sn
        l1 = np.sqrt(r_in * r_in + cc - 2.0 * r_in * da)
        dl1 = r_in * a / l1
        bb, dbb = n * rp * sn, n * rp * cs
        l2 = np.sqrt(rp * rp + r_in * r_in - 2.0 * rp * r_in * cs)
        dl2 = rp * r_in * sn / l2
        return a / l1 + bb / l2, (da * l1 - a * dl1) / (l1 * l1) + (dbb * l2 - bb * dl2) / (l2 * l2)

    psi = np.where(small, 0.0, bracketed_newton(fun, np.zeros_like(psi_s), psi_s, psi_s))
    q = r_in * (np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2)
    d = q - c
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d, q[:, 2] >= 0


def check_camera_inside(sensor: DomeSensor, c: np.ndarray) -> None:
    """Refuse a camera position outside the dome's inner sphere, where the closed-form optics do not hold.

    Parameters
    ----------
    sensor : DomeSensor
    c : (3,) ndarray
        The camera's projection centre (:attr:`Camera.position`, mm, dome frame).

    Raises
    ------
    InputError
        Where ``c`` is not strictly inside the inner sphere, naming both.
    """
    if not np.linalg.norm(c) < sensor.inner_radius:
        raise InputError(f"the camera's position {np.round(c, 6).tolist()} mm must lie inside the dome's "
                         f"inner sphere (radius {sensor.inner_radius} mm)")


def _generic_pixel_from_dome(p: np.ndarray, sensor: DomeSensor, camera: Camera, refraction) -> np.ndarray:
    """Pixels of outer-surface points (..., 3) for any model; NaN for points it does not see."""
    n = _index(sensor, refraction)
    c = camera.position
    check_camera_inside(sensor, c)
    flat = p.reshape(-1, 3)
    if c[0] == 0.0 and c[1] == 0.0:  # on the axis: the radial map, as fast as the default camera
        rmap = radial_map(sensor, c[2], refraction=bool(refraction))
        theta = np.arctan2(np.hypot(flat[:, 0], flat[:, 1]), flat[:, 2])
        phi = np.arctan2(flat[:, 1], flat[:, 0])
        ok = theta <= rmap.theta_max + 1e-12
        alpha = rmap.alpha(np.minimum(theta, rmap.theta_max))
        d = np.stack([np.sin(alpha) * np.cos(phi), np.sin(alpha) * np.sin(phi), np.cos(alpha)], axis=-1)
    else:
        d, ok = _rays_to(flat, c, sensor.inner_radius, n)
    px = camera._pixel_from_camera_ray(d @ camera.rotation.T)
    px[~ok] = np.nan
    return px.reshape(p.shape[:-1] + (2,))


@lru_cache(maxsize=32)
def _max_polar_angle_cached(camera: Camera, sensor: DomeSensor) -> float:
    phi = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    r = sensor.outer_radius

    def seen(theta):
        pts = r * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
        return np.isfinite(_generic_pixel_from_dome(pts, sensor, camera, True)).all(axis=-1)

    lo, hi = np.zeros_like(phi), np.full_like(phi, np.pi / 2)
    if not seen(lo).all():
        return 0.0
    top = seen(hi)
    lo[top] = hi[top]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ok = seen(mid)
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return float(lo.min())


def pixel_from_dome(points, *, sensor: DomeSensor, camera: Camera, outside: str = "raise",
                    refraction: bool = True) -> np.ndarray:
    """Project points on the outer dome surface into the image, seen through the dome.

    Parameters
    ----------
    points : (..., 3) array_like
        Global points (mm) on the outer surface (within ``SURFACE_TOLERANCE``),
        visible through the inner surface: for the default camera polar angle
        up to ``theta_max`` (88.3 deg for the default sensor; points nearer
        the base are seen only through the rim); see :meth:`Camera.visible`.
    sensor : DomeSensor
    camera : Camera
        Any camera model (:class:`FisheyeCamera`, or those of
        :mod:`optitact.optics.camera_models`).
    outside : {"raise", "nan"}
        What to do with points the camera does not see: raise ``InputError``
        (default) or return NaN rows for them.
    refraction : bool
        False: straight rays, as if the dome's refractive index were 1 (then
        the projection is OpenCV's ``projectPoints`` of the points).

    Returns
    -------
    (..., 2) ndarray
        Pixel positions ``(row, col)``; they may fall outside the image.

    Notes
    -----
    A spot lies at the acrylic side of the outer surface, so light from it
    crosses only the inner surface on its way to the camera: the camera ray
    ``C + t d`` meets the inner sphere at ``Q``, refracts by Snell's law
    (``n_air sin i = n sin t``, vector form
    ``t = eta d + (cos_t - eta cos_i) n_hat``, ``eta = 1/n``) and meets the outer
    sphere at ``P``. For a camera on the axis ``P``'s azimuth equals the ray's
    and its polar angle is a monotone function ``theta(alpha)`` of the ray
    angle, which is inverted by Newton's method from a tabulated start. Off
    the axis, ``C``, ``Q``, ``P`` and the dome's centre are coplanar and
    ``Q`` is the root of Snell's law along the inner circle of that plane
    (bracketed Newton, see ``_rays_to``). The ray is then mapped through
    the camera's rotation and lens model. The round trip with
    :func:`dome_from_pixel` is exact to ~1e-12 mm.
    """
    _check_optics(sensor, camera, outside)
    n = _index(sensor, refraction)
    p = finite(shape_tail(real_array(points, "points"), (3,), "points", "(..., 3)"), "points")
    radius = np.linalg.norm(p, axis=-1)
    off = np.abs(radius - sensor.outer_radius)
    if np.any(off > SURFACE_TOLERANCE):
        raise InputError(
            f"points must lie on the outer dome surface (radius {sensor.outer_radius} mm "
            f"+- {SURFACE_TOLERANCE}), got a point at radius {radius.ravel()[np.argmax(off)]:.6g}"
        )
    if np.any(p[..., 2] < -SURFACE_TOLERANCE):
        raise InputError(f"points must have z >= 0 (on the dome), got z = {p[..., 2].min():.6g}")
    if not isinstance(camera, FisheyeCamera):
        px = _generic_pixel_from_dome(p, sensor, camera, refraction)
        bad = ~np.isfinite(px).all(axis=-1)
        if outside == "raise" and bad.any():
            i = np.unravel_index(np.argmax(bad), bad.shape)
            raise InputError(f"points must be visible to this camera through the inner surface, got "
                             f"{np.round(p[i], 6).tolist()} (and {int(bad.sum()) - 1} more); see "
                             f"Camera.visible")
        return px
    theta = np.arctan2(np.hypot(p[..., 0], p[..., 1]), p[..., 2])
    phi = np.arctan2(p[..., 1], p[..., 0])
    rmap = radial_map(sensor, camera.z) if n == sensor.refractive_index else radial_map(
        sensor, camera.z, refraction=False)
    bad = theta > rmap.theta_max + 1e-12
    if outside == "raise" and np.any(bad):
        raise InputError(
            f"points must be visible through the inner surface (polar angle <= "
            f"{math.degrees(rmap.theta_max):.3f} deg for this camera), got "
            f"{math.degrees(theta.max()):.3f} deg"
        )
    if np.any(bad):
        alpha = rmap.alpha(np.minimum(theta, rmap.theta_max))
        px = camera._pixel_from_polar(alpha, phi)
        px[bad] = np.nan
        return px
    alpha = rmap.alpha(theta)
    return camera._pixel_from_polar(alpha, phi)


def dome_from_pixel(pixels, *, sensor: DomeSensor, camera: Camera,
                    outside: str = "raise", refraction: bool = True) -> np.ndarray:
    """Outer-surface dome points seen at pixel positions ``(row, col)``.

    Parameters
    ----------
    pixels : (..., 2) array_like
        Pixel positions ``(row, col)`` (sub-pixel allowed).
    sensor : DomeSensor
    camera : Camera
    outside : {"raise", "nan"}
        What to do with pixels whose ray misses the dome (passes below its
        base, or no ray maps there): raise ``InputError`` (default) or return
        NaN rows for them (use :meth:`Camera.dome_mask` to find them
        beforehand).
    refraction : bool
        False: straight rays, as if the dome's refractive index were 1.

    Returns
    -------
    (..., 3) ndarray
        Global points on the outer dome surface (mm).

    Notes
    -----
    See :func:`pixel_from_dome` for the optics: here the closed form runs
    forwards (undistort the pixel exactly, rotate the ray into the dome
    frame, intersect the inner sphere, refract, intersect the outer sphere).
    """
    _check_optics(sensor, camera, outside)
    n = _index(sensor, refraction)
    if not isinstance(camera, FisheyeCamera):
        p = finite(shape_tail(real_array(pixels, "pixels"), (2,), "pixels", "(..., 2) (row, col)"), "pixels")
        c = camera.position
        check_camera_inside(sensor, c)
        d = camera._camera_ray_from_pixel(p) @ camera.rotation
        nod = ~np.isfinite(d).all(axis=-1)
        with np.errstate(invalid="ignore"):
            pts, ok = trace_through_dome(c, np.where(nod[..., None], [0.0, 0.0, 1.0], d), sensor.inner_radius,
                             sensor.outer_radius, n)
        miss = nod | ~ok
        if outside == "raise" and miss.any():
            i = np.unravel_index(np.argmax(miss), miss.shape)
            why = "no ray of the lens model maps there" if nod[i] else "its ray passes below the dome's base"
            raise InputError(f"pixels must see the dome, got {np.round(p[i], 6).tolist()}: {why} (and "
                             f"{int(miss.sum()) - 1} more); see Camera.dome_mask")
        pts[miss] = np.nan
        return pts
    alpha, phi = camera._polar_from_pixel(pixels)
    rmap = radial_map(sensor, camera.z) if n == sensor.refractive_index else radial_map(
        sensor, camera.z, refraction=False)
    miss = alpha > rmap.alpha_max * (1 + 1e-12)
    if outside == "raise" and np.any(miss):
        raise InputError(
            f"pixels must see the dome (ray angle <= {math.degrees(rmap.alpha_max):.3f} deg "
            f"from the axis), got {math.degrees(alpha[miss].max()):.3f} deg"
        )
    theta = rmap.theta(np.minimum(alpha, rmap.alpha_max))[0]
    r = sensor.outer_radius
    pts = np.stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi),
                    r * np.cos(theta)], axis=-1)
    pts[miss] = np.nan
    return pts
