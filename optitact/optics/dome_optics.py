"""Where a dome point appears in a camera and back: refraction through the acrylic shell.

A spot on the outer dome surface is seen through the inner spherical surface
only: its light refracts once, at the inner sphere, on its way to the camera.
:func:`pixel_from_dome` and :func:`dome_from_pixel` map outer-surface points to
pixels and back in closed form for every camera model of
:mod:`optitact.optics.camera` and :mod:`optitact.optics.camera_models`; :func:`radial_map` is
the rotationally symmetric map of a camera on the dome axis (the default
:class:`optitact.optics.camera.FisheyeCamera`). The same functions are importable
from :mod:`optitact.optics.camera` and from :mod:`optitact`.

Convention
----------
Image indices are ``(row, col)`` with the origin at the centre of the top-left
pixel, as in scikit-image and SciPy. Physical coordinates are global
``(x, y, z)`` in mm, the *dome frame* of :mod:`optitact.optics.sensor`: z up the dome
axis, the base plane at z = 0; a camera's pose relates it to the camera frame
as described in :mod:`optitact.optics.camera`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from optitact._validate import check_type, finite, real_array, shape_tail
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["RadialMap", "dome_from_pixel", "pixel_from_dome", "radial_map"]

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


def _bracketed_newton(fun, lo: np.ndarray, hi: np.ndarray, x: np.ndarray, iters: int = 200) -> np.ndarray:
    """Roots of increasing functions ``fun(x) -> (f, f')`` with ``f(lo) <= 0 <= f(hi)``, to rounding.

    Newton's steps, replaced by bisection when one leaves the bracket; the
    bracket shrinks around every root, so it cannot diverge.
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


def _trace(c: np.ndarray, d: np.ndarray, r_in: float, r_out: float, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Outer-surface points reached by rays ``c + t d`` (dome frame) through the inner sphere, and validity.

    Closed form: the ray meets the inner sphere at ``Q`` (the camera is
    inside it), refracts by Snell's law in vector form and meets the outer
    sphere at ``P``; valid where ``Q`` and ``P`` lie at ``z >= 0``.
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

    psi = np.where(small, 0.0, _bracketed_newton(fun, np.zeros_like(psi_s), psi_s, psi_s))
    q = r_in * (np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2)
    d = q - c
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d, q[:, 2] >= 0


def _check_inside(sensor: DomeSensor, c: np.ndarray) -> None:
    if not np.linalg.norm(c) < sensor.inner_radius:
        raise InputError(f"the camera's position {np.round(c, 6).tolist()} mm must lie inside the dome's "
                         f"inner sphere (radius {sensor.inner_radius} mm)")


def _generic_pixel_from_dome(p: np.ndarray, sensor: DomeSensor, camera: Camera, refraction) -> np.ndarray:
    """Pixels of outer-surface points (..., 3) for any model; NaN for points it does not see."""
    n = _index(sensor, refraction)
    c = camera.position
    _check_inside(sensor, c)
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
        _check_inside(sensor, c)
        d = camera._camera_ray_from_pixel(p) @ camera.rotation
        nod = ~np.isfinite(d).all(axis=-1)
        with np.errstate(invalid="ignore"):
            pts, ok = _trace(c, np.where(nod[..., None], [0.0, 0.0, 1.0], d), sensor.inner_radius,
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
