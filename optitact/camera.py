"""Closed-form camera model: an equidistant fisheye inside the dome, looking up its axis.

Convention
----------
Image indices are ``(row, col)`` with the origin at the centre of the top-left
pixel, as in scikit-image and SciPy; a pixel covers ``[col - 0.5, col + 0.5)``.
Physical coordinates are global ``(x, y, z)`` in mm (see :mod:`optitact.sensor`).
The camera sits on the dome axis at ``(0, 0, z)`` and looks along +z; image
columns grow with global +x and rows with global +y (a right-handed camera
frame seen from below, not mirrored).
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import asdict, dataclass, fields
from functools import lru_cache

import numpy as np

from ._validate import check_keys, check_type, finite, integer, positive, real_array, shape_tail
from .errors import InputError
from .sensor import DomeSensor

__all__ = ["FisheyeCamera", "MAX_FRAME_PIXELS", "RadialMap", "check_frame_size", "pixel_from_dome",
           "dome_from_pixel", "radial_map"]

#: Largest distance (mm) a point given to :func:`pixel_from_dome` may lie off the outer surface.
SURFACE_TOLERANCE = 1e-4

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
            f"the {limit:,} this camera model accepts (optitact.camera.MAX_FRAME_PIXELS; the set-up "
            f"needs about 70 bytes per pixel); downsample the frames, or set {_MAX_PIXELS_ENV} to "
            f"allow more")


@dataclass(frozen=True)
class FisheyeCamera:
    """Equidistant fisheye camera (``r = f * alpha``) on the dome axis.

    Parameters
    ----------
    width, height : int
        Image size in pixels, default 640 x 480; at least 2 each and at most
        :data:`MAX_FRAME_PIXELS` in all (see :func:`check_frame_size`). The
        pipeline needs more than 2: too small a frame for the sensor is
        refused by :func:`optitact.regions.split_regions` ("frame too
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
        """Return the parameters as a JSON-friendly dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> FisheyeCamera:
        """Build a camera from :meth:`to_dict` output; unknown keys are a ValueError."""
        return cls(**check_keys(d, [f.name for f in fields(cls)], "camera parameters", noun="parameter"))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

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
    def project(self, points, sensor: DomeSensor) -> np.ndarray:
        """Pixels ``(row, col)`` where points on the outer dome surface appear; see :func:`pixel_from_dome`."""
        return pixel_from_dome(points, sensor=sensor, camera=self)

    def unproject(self, pixels, sensor: DomeSensor, *, outside: str = "raise") -> np.ndarray:
        """Outer-surface dome points seen at pixels ``(row, col)``; see :func:`dome_from_pixel`."""
        return dome_from_pixel(pixels, sensor=sensor, camera=self, outside=outside)

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


def radial_map(sensor: DomeSensor, zc: float) -> RadialMap:
    """The radial map of an on-axis camera at height ``zc`` (mm) inside ``sensor`` (cached).

    ``radial_map(sensor, camera.z).theta(alpha)`` is the polar angle of the
    outer-surface point seen by a ray at angle ``alpha`` from the axis;
    ``theta_max`` and ``alpha_max`` bound what the camera sees (see
    :meth:`FisheyeCamera.max_polar_angle`).
    """
    check_type(sensor, DomeSensor, "sensor")
    return _radial_map_cached(sensor.inner_radius, sensor.outer_radius,
                              sensor.refractive_index, float(zc))


def _check_optics(sensor, camera) -> None:
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, FisheyeCamera, "camera")


def pixel_from_dome(points, *, sensor: DomeSensor, camera: FisheyeCamera) -> np.ndarray:
    """Project points on the outer dome surface into the image, seen through the dome.

    Parameters
    ----------
    points : (..., 3) array_like
        Global points (mm) on the outer surface (within ``SURFACE_TOLERANCE``),
        visible through the inner surface: polar angle up to ``theta_max``
        (88.3 deg for the default sensor and camera; points nearer the base
        are seen only through the rim).
    sensor : DomeSensor
    camera : FisheyeCamera

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
    sphere at ``P``. By symmetry ``P``'s azimuth equals the ray's and its polar
    angle is a monotone function ``theta(alpha)`` of the ray angle, which is
    inverted by Newton's method from a tabulated start; the round trip with
    :func:`dome_from_pixel` is exact to ~1e-12 mm.
    """
    _check_optics(sensor, camera)
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
    theta = np.arctan2(np.hypot(p[..., 0], p[..., 1]), p[..., 2])
    phi = np.arctan2(p[..., 1], p[..., 0])
    rmap = radial_map(sensor, camera.z)
    if np.any(theta > rmap.theta_max + 1e-12):
        raise InputError(
            f"points must be visible through the inner surface (polar angle <= "
            f"{math.degrees(rmap.theta_max):.3f} deg for this camera), got "
            f"{math.degrees(theta.max()):.3f} deg"
        )
    alpha = rmap.alpha(theta)
    return camera._pixel_from_polar(alpha, phi)


def dome_from_pixel(pixels, *, sensor: DomeSensor, camera: FisheyeCamera,
                    outside: str = "raise") -> np.ndarray:
    """Outer-surface dome points seen at pixel positions ``(row, col)``.

    Parameters
    ----------
    pixels : (..., 2) array_like
        Pixel positions ``(row, col)`` (sub-pixel allowed).
    sensor : DomeSensor
    camera : FisheyeCamera
    outside : {"raise", "nan"}
        What to do with pixels whose ray misses the dome (passes below its
        base): raise ``InputError`` (default) or return NaN rows for them
        (use :meth:`FisheyeCamera.dome_mask` to find them beforehand).

    Returns
    -------
    (..., 3) ndarray
        Global points on the outer dome surface (mm).

    Notes
    -----
    See :func:`pixel_from_dome` for the optics.
    """
    _check_optics(sensor, camera)
    if outside not in ("raise", "nan"):
        raise InputError(f"outside must be 'raise' or 'nan', got {outside!r}")
    alpha, phi = camera._polar_from_pixel(pixels)
    rmap = radial_map(sensor, camera.z)
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
