"""Closed-form camera models: their common base and the default on-axis equidistant fisheye.

:class:`FisheyeCamera` (the default) is an equidistant fisheye on the dome axis
looking up it; :class:`optitact.optics.camera_models.PinholeCamera` and
:class:`optitact.optics.camera_models.OpenCVFisheyeCamera` take intrinsics, distortion
and a pose exactly as OpenCV defines them. Every model is a :class:`Camera`:
:func:`pixel_from_dome` and :func:`dome_from_pixel` (the optics through the
dome, in :mod:`optitact.optics.dome_optics` and importable from here) work for all of
them.

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
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from optitact._validate import check_keys, check_type, finite, integer, positive, real_array, shape_tail
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

if TYPE_CHECKING:  # re-exported lazily by __getattr__ at the end (dome_optics imports this module)
    pass

__all__ = ["Camera", "FisheyeCamera", "MAX_FRAME_PIXELS", "camera_from_dict", "check_frame_size"]

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
        from optitact.optics.dome_optics import pixel_from_dome

        return pixel_from_dome(points, sensor=sensor, camera=self, outside=outside, refraction=refraction)

    def unproject(self, pixels, sensor: DomeSensor, *, outside: str = "raise",
                  refraction: bool = True) -> np.ndarray:
        """Outer-surface dome points seen at pixels ``(row, col)``; see :func:`dome_from_pixel`."""
        from optitact.optics.dome_optics import dome_from_pixel

        return dome_from_pixel(pixels, sensor=sensor, camera=self, outside=outside, refraction=refraction)

    def visible(self, points, sensor: DomeSensor) -> np.ndarray:
        """Bool (...,): outer-surface points this camera sees through the inner surface.

        Points below the base plane are not seen; a seen point may still fall
        outside the image.
        """
        from optitact.optics.dome_optics import _generic_pixel_from_dome

        check_type(sensor, DomeSensor, "sensor")
        p = finite(shape_tail(real_array(points, "points"), (3,), "points", "(..., 3)"), "points")
        out = np.zeros(p.shape[:-1], bool)
        up = p[..., 2] >= 0
        if up.any():
            out[up] = np.isfinite(_generic_pixel_from_dome(p[up], sensor, self, True)).all(axis=-1)
        return out

    def dome_mask(self, sensor: DomeSensor) -> np.ndarray:
        """(H, W) bool: pixel centres whose ray reaches the outer dome surface (z >= 0)."""
        from optitact.optics.dome_optics import dome_from_pixel

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
        from optitact.optics.dome_optics import _max_polar_angle_cached

        check_type(sensor, DomeSensor, "sensor")
        return _max_polar_angle_cached(self, sensor)


def camera_from_dict(d: dict) -> Camera:
    """Build any camera model from its :meth:`Camera.to_dict` (no ``model`` key: :class:`FisheyeCamera`)."""
    return Camera.from_dict(d)


def rotation_from_rvec(rvec) -> np.ndarray:
    """Rotation matrix of a Rodrigues vector (axis times angle, rad), as ``cv2.Rodrigues``."""
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
        from optitact.optics.dome_optics import radial_map

        rows, cols = np.mgrid[0:self.height, 0:self.width]
        alpha, _ = self._polar_from_pixel(np.stack([rows, cols], axis=-1))
        return alpha <= radial_map(sensor, self.z).alpha_max

    def max_polar_angle(self, sensor: DomeSensor) -> float:
        """The largest polar angle (rad, from the dome axis) of an outer-surface point this camera sees.

        Points farther from the apex are hidden below the inner surface's base
        (seen only through the rim); about 88.35 deg for the default sensor
        and camera. See :func:`optitact.optics.dome_optics.radial_map`.
        """
        from optitact.optics.dome_optics import radial_map

        return radial_map(sensor, self.z).theta_max


CAMERA_MODELS[FisheyeCamera.model] = FisheyeCamera


# The optics through the dome live in optitact.optics.dome_optics, which imports the models above; its
# names stay importable from here, resolved on first use (a top-level import would be circular).
_DOME_OPTICS = frozenset({
    "SURFACE_TOLERANCE", "RadialMap", "radial_map", "_radial_map_cached", "_check_optics", "_index",
    "_bracketed_newton", "_trace", "_rays_to", "_check_inside", "_generic_pixel_from_dome",
    "_max_polar_angle_cached", "pixel_from_dome", "dome_from_pixel"})


def __getattr__(name: str):
    if name in _DOME_OPTICS:
        from optitact.optics import dome_optics

        return getattr(dome_optics, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _DOME_OPTICS)
