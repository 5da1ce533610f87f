"""The no-load frame two-stage rendering composites over: path-traced once per camera, or resampled.

The guided light the rim injects shows faintly even with nothing pressed
(the rim ring, a faint inner ring): :func:`noload_radiance` is that
converged frame, path-traced for an on-axis :class:`FisheyeCamera` (cached on
disk) and, for any other camera model, resampled through the dome from the
nominal camera's frame, so a registered camera costs no new path trace.

Convention
----------
Global ``(x, y, z)`` mm as in :mod:`optitact.optics.sensor`; pixels ``(row, col)``
with the origin at the top-left pixel centre, as in :mod:`optitact.optics.camera`.
"""

from __future__ import annotations

import numpy as np

from optitact._validate import check_type
from optitact.optics.camera import Camera, FisheyeCamera, check_camera_inside, trace_through_dome
from optitact.optics.sensor import DomeSensor

from optitact.render.scene import RenderSettings

__all__ = ["NOLOAD_SEED", "NOLOAD_SPP", "measuring_camera", "noload_radiance"]


#: Samples per pixel and seed of the cached no-load frame stage 1 is measured against.
NOLOAD_SPP, NOLOAD_SEED = 1024, 7


def measuring_camera(camera) -> FisheyeCamera:
    """The camera a table is measured through: an on-axis FisheyeCamera (default ``FisheyeCamera()``)."""
    if camera is None:
        return FisheyeCamera()
    if not isinstance(camera, FisheyeCamera):
        raise TypeError(f"camera (the camera a stage-1 table is measured through) must be a FisheyeCamera or "
                        f"None (FisheyeCamera()), got {type(camera).__name__}; the table serves every camera "
                        f"model: render through yours with table=emission_table(sensor)")
    return camera


def noload_radiance(sensor: DomeSensor, camera: Camera, *, settings: RenderSettings | None = None,
                    variant: str | None = None, resample: bool = True,
                    nominal: FisheyeCamera | None = None) -> np.ndarray:
    """The converged no-load frame of a camera: path-traced (``NOLOAD_SPP``, cached on disk) or resampled.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
        Any camera model. A :class:`~optitact.optics.camera.FisheyeCamera` (or any
        camera with ``resample=False``) is path-traced (minutes on a CPU at
        640 x 480, once: cached).
    settings : RenderSettings, optional
    variant : str, optional
    resample : bool
        For a camera of another model (default True): resample the nominal
        camera's path-traced no-load frame through the dome instead of
        path-tracing this camera's (milliseconds once the nominal frame is
        cached); see Notes.
    nominal : FisheyeCamera, optional
        The on-axis camera whose no-load frame is resampled (default
        ``FisheyeCamera()``, 640 x 480, the default measuring camera). Choose
        one with at least the camera's pixels per degree.

    Returns
    -------
    (H, W) float32
        Radiance per pixel.

    Notes
    -----
    Each pixel's ray of ``camera`` (from its position, exact undistortion) is
    followed through the dome: where it enters the dome's cavity it refracts
    at the inner sphere and meets the outer sphere at ``P``, and the nominal
    camera's pixel that sees ``P`` (:func:`~optitact.optics.camera.pixel_from_dome`)
    is sampled bilinearly; where it crosses the base plane (``z = 0``) outside
    the inner sphere (the shell's base, where the rim light enters, and
    beyond) the nominal camera's pixel whose ray crosses the base plane at the
    same point is sampled. Where that pixel lies outside the nominal image,
    the nominal frame's azimuthal mean at the same distance from its centre is
    used (the no-load frame of the designed sensor is rotationally
    symmetric); rays that see neither (looking below the base plane, or no
    ray of the lens model) get 0, as the nominal frame shows beyond its rim.
    Approximations: the radiance leaving a point is taken to be the same in
    the camera's direction as in the nominal camera's (the no-load light is
    mostly the guided light scattered out of the shell, a few degrees apart
    for a camera a fraction of a mm off axis and a degree or two tilted),
    the Fresnel transmittance of the two views is taken as equal, and the
    nominal frame's resolution and Monte Carlo noise carry over. Measured
    for an 80 x 60 Kannala-Brandt camera 0.36 mm off axis and 1.9 deg tilted
    resampled from a 160 x 120 nominal frame against its own path-traced
    no-load frame: see ``tests/render/test_twostage.py``
    (``test_resampled_background_matches_a_path_traced_one``).
    """
    from optitact.render.cache import cached_render

    check_type(camera, Camera, "camera")
    if isinstance(camera, FisheyeCamera) or not resample:
        return cached_render(sensor, np.zeros((sensor.n_elements, 3)), camera=camera, spp=NOLOAD_SPP,
                             seed=NOLOAD_SEED, variant=variant, settings=settings)
    nominal = measuring_camera(nominal)
    base = noload_radiance(sensor, nominal, settings=settings, variant=variant)
    return _resample_noload(sensor, camera, nominal, np.asarray(base, np.float64))


def _resample_noload(sensor: DomeSensor, camera: Camera, nominal: FisheyeCamera,
                     base: np.ndarray) -> np.ndarray:
    """:func:`noload_radiance` of ``camera`` resampled from ``nominal``'s frame ``base`` (see its Notes)."""
    from scipy.ndimage import map_coordinates

    c = camera.position
    check_camera_inside(sensor, c)
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    d = camera.ray_from_pixel(np.stack([rows, cols], axis=-1).astype(np.float64)).reshape(-1, 3)
    ray = np.isfinite(d).all(axis=1)
    d = np.where(ray[:, None], d, [0.0, 0.0, 1.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        p, dome = trace_through_dome(c, d, sensor.inner_radius, sensor.outer_radius,
                                     float(sensor.refractive_index))
        dome &= ray
        target = np.full((d.shape[0], 2), np.nan)
        if dome.any():
            target[dome] = nominal.project(p[dome], sensor, outside="nan")
        # the base plane: where the ray crosses z = 0, seen by the nominal camera's straight ray
        rest = ray & ~np.isfinite(target).all(axis=1) & (d[:, 2] > 0) & (c[2] < 0)
        x0 = c + (-c[2] / d[:, 2])[:, None] * d
        target[rest] = nominal.pixel_from_ray(x0[rest] - nominal.position)
    out = np.zeros(d.shape[0])
    found = np.isfinite(target).all(axis=1)
    h, w = nominal.shape
    inside = (found & (target[:, 0] >= 0) & (target[:, 0] <= h - 1)
              & (target[:, 1] >= 0) & (target[:, 1] <= w - 1))
    out[inside] = map_coordinates(base, target[inside].T, order=1, mode="nearest")
    # outside the nominal image: its azimuthal mean at the same radius (1-pixel rings, linear between)
    far = found & ~inside
    if far.any():
        cy, cx = nominal.center
        nr, nc = np.mgrid[0:h, 0:w]
        ring = np.hypot(nr - cy, nc - cx).reshape(-1)
        k = np.floor(ring).astype(np.int64)
        total = np.bincount(k, weights=base.reshape(-1))
        count = np.bincount(k)
        full = count > 0
        radii = np.flatnonzero(full) + 0.5
        profile = total[full] / count[full]
        r = np.hypot(target[far, 0] - cy, target[far, 1] - cx)
        out[far] = np.where(r <= ring.max(), np.interp(r, radii, profile), 0.0)
    return out.reshape(camera.shape).astype(np.float32)
