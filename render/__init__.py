"""Physically based synthetic camera frames of the optical tactile sensor (Mitsuba 3).

The package's face: :func:`render` (element forces) and :func:`render_contacts`
(given patches) check a request and hand it to one of the two light
transports, brute-force path tracing (:mod:`optitact.render.pathtrace`) or
the two-stage transport (:mod:`optitact.render.twostage`, over the no-load
frame of :mod:`optitact.render.background` and the emission table of
:mod:`optitact.render.emission`).

Layering: this module sits on top of its submodules; none of them imports it
(what they share, such as :func:`~optitact.render.pathtrace.pass_seeds`,
:data:`~optitact.render.pathtrace.SPP_PER_PASS` and
:func:`~optitact.render.pathtrace.spot_pixels`, lives in
:mod:`optitact.render.pathtrace`, imported from there).

Import cost: importing :mod:`optitact.render` does not import mitsuba; the
first :func:`render` call does, after pointing Dr.Jit at a usable libLLVM.

Examples
--------
>>> import numpy as np, optitact
>>> from optitact.render import render
>>> s = optitact.optics.sensor.DomeSensor.default()
>>> f = np.zeros((41, 3)); f[0, 2] = 0.5
>>> cam = optitact.optics.camera.FisheyeCamera(width=64, height=48)
>>> img = render(s, f, camera=cam, spp=4, seed=1)
>>> img.shape, img.dtype
((48, 64), dtype('float32'))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.optics.contact import Contacts, check_forces, contact_patches
from optitact.optics.sensor import DomeSensor

from optitact.render.pathtrace import (check_camera, check_pixels, check_request, loaded_region_pixels,
                                       path_trace)
from optitact.render.scene import RenderSettings

__all__ = ["render", "render_contacts", "RenderResult", "TRANSPORTS"]

#: Light transport modes of :func:`render`.
TRANSPORTS = ("path", "two_stage")


@dataclass(frozen=True, eq=False)
class RenderResult:
    """What :func:`render` returns with ``full_output=True``.

    Attributes
    ----------
    radiance : (H, W) float32 ndarray
        The image :func:`render` returns by default.
    spp : int or None
        Samples per pixel rendered (with ``target_error``, where the passes
        stopped; 0 when no pixel was rendered); None for
        ``transport="two_stage"``, which has no Monte Carlo samples.
    """

    radiance: np.ndarray
    spp: int | None


def render(sensor: DomeSensor, forces, *, camera: Camera | None = None, spp: int = 64,
           seed: int = 0, variant: str | None = None, settings: RenderSettings | None = None,
           crop: tuple[int, int, int, int] | None = None, pixels=None, background=None,
           progress: bool = False, transport: str = "path", n_sub: int = 8,
           table=None, target_error: float | None = None, max_spp: int = 4096,
           full_output: bool = False) -> np.ndarray | RenderResult:
    """Render the radiance image the camera sees for element-local forces.

    Parameters
    ----------
    sensor : DomeSensor
    forces : (N, 3) array_like
        Element-local forces ``(Fx, Fy, Fz)`` in N.
    camera : Camera, optional
        Any camera model (:class:`~optitact.optics.camera.FisheyeCamera`,
        :class:`~optitact.optics.camera_models.PinholeCamera`,
        :class:`~optitact.optics.camera_models.OpenCVFisheyeCamera`, with its pose);
        default ``FisheyeCamera()`` (640 x 480); both transports take every
        model.
    spp : int
        Samples per pixel (>= 1), default 64.
    seed : int
        Seed (>= 0); the same seed and settings give the same frame
        (bit-identical on scalar_rgb, equal to float rounding on JIT variants).
    variant : str, optional
        Mitsuba variant; default: the fastest that works (cuda > llvm > scalar).
    settings : RenderSettings, optional
        Physical and numerical settings, default ``RenderSettings()``.
    crop : (row0, col0, height, width), optional
        Render only this window; the result then has shape ``(height, width)``.
    pixels : (H, W) bool array_like, optional
        Render only these pixels (e.g. :func:`~optitact.render.pathtrace.spot_pixels`), in one launch
        with a packed film; the others come from ``background`` (or are 0).
        Each rendered pixel is integrated exactly as in a full frame.
    background : (H, W) array_like, optional
        With ``pixels``: the image the rendered pixels are composited over,
        typically a cached no-load render (the guided light does not depend
        on a few small contacts far away).
    progress : bool
        Show a progress bar over render passes on stderr.
    transport : {"path", "two_stage"}
        ``"path"`` (default, the reference): brute-force path tracing of the
        whole light transport at ``spp``. ``"two_stage"``: the light guided to
        each patch comes from a cached table measured once by path tracing
        (:func:`~optitact.render.emission.emission_table`), and the patches
        are traced in closed form as emitters seen through the dome
        (:func:`~optitact.render.twostage.render_two_stage`): no Monte Carlo
        noise, milliseconds per frame, any camera model with no per-camera
        set-up; ``spp`` and ``pixels`` are not used. ``background`` defaults
        to the camera's no-load frame
        (:func:`~optitact.render.background.noload_radiance`: path-traced and
        cached for a FisheyeCamera, resampled through the dome from the
        default camera's for other models).
    n_sub : int
        ``"two_stage"`` only: sub-pixel rays per side on patch edges (default 8).
    table : EmissionTable, optional
        ``"two_stage"`` only: the stage-1 table (default: the one of this
        sensor and settings measured through ``FisheyeCamera()``, shipped for
        the default sensor, else measured once and cached); it serves every
        camera.
    target_error : float, optional
        ``"path"`` only, right-sized sampling: render passes of
        ``SPP_PER_PASS`` samples (at least ``spp``, at least 4 passes) until
        the summed radiance of every loaded element's region (minus
        ``background``) has this relative standard error, estimated from the
        spread of the passes, or ``max_spp`` is reached.
    max_spp : int
        Most samples per pixel with ``target_error`` (default 4096).
    full_output : bool
        Return a :class:`RenderResult` (the radiance and what the render
        measured, e.g. the samples per pixel ``target_error`` used) instead of
        the radiance alone.

    Returns
    -------
    (H, W) float32 ndarray, or RenderResult with ``full_output=True``
        Radiance (arbitrary units, linear in ``settings.rim_radiance``).

    Notes
    -----
    Every input is checked before Mitsuba is imported. ``spp`` is rendered in
    passes of at most ``SPP_PER_PASS`` samples whose seeds derive from
    ``seed`` (:func:`~optitact.render.pathtrace.pass_seeds`); the passes are averaged in float64.
    """
    if not isinstance(sensor, DomeSensor):
        raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
    f = check_forces(forces, sensor)
    windows = None
    if target_error is not None:
        cam = FisheyeCamera() if camera is None else camera
        check_camera(cam)
        pixel, label = loaded_region_pixels(sensor, cam, f)
        windows = np.full(cam.height * cam.width, -1, np.int64)
        windows[pixel] = label
    return render_contacts(sensor, contact_patches(sensor, forces), camera=camera, spp=spp,
                           seed=seed, variant=variant, settings=settings, crop=crop,
                           pixels=pixels, background=background, progress=progress,
                           transport=transport, n_sub=n_sub, table=table, target_error=target_error,
                           max_spp=max_spp, windows=windows, full_output=full_output)


def render_contacts(sensor: DomeSensor, contacts: Contacts, *,
                    camera: Camera | None = None, spp: int = 64, seed: int = 0,
                    variant: str | None = None, settings: RenderSettings | None = None,
                    crop: tuple[int, int, int, int] | None = None, pixels=None,
                    background=None, progress: bool = False, transport: str = "path",
                    n_sub: int = 8, table=None, target_error: float | None = None,
                    max_spp: int = 4096, windows=None,
                    full_output: bool = False) -> np.ndarray | RenderResult:
    """Render given contact patches (e.g. from :func:`optitact.optics.contact.contact_patches`).

    Parameters are those of :func:`render`, with ``contacts`` in place of
    ``forces``: patches need not come from the contact model (a single patch
    at a chosen dome point, say); with ``target_error``, ``windows`` is a
    flat (H*W,) int array labelling the pixels whose sums must converge
    (-1: none), which :func:`render` makes from the loaded elements' regions.
    """
    img, spp = _render_contacts(sensor, contacts, camera=camera, spp=spp, seed=seed, variant=variant,
                                settings=settings, crop=crop, pixels=pixels, background=background,
                                progress=progress, transport=transport, n_sub=n_sub, table=table,
                                target_error=target_error, max_spp=max_spp, windows=windows)
    return RenderResult(img, spp) if full_output else img


def _render_contacts(sensor, contacts, *, camera, spp, seed, variant, settings, crop, pixels, background,
                     progress, transport, n_sub, table, target_error, max_spp, windows):
    """:func:`render_contacts`: the radiance and the samples per pixel used (None for two_stage)."""
    camera, settings, spp, seed, crop = check_request(sensor, contacts, camera=camera, settings=settings,
                                                      spp=spp, seed=seed, variant=variant, crop=crop)
    if transport not in TRANSPORTS:
        raise InputError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if transport == "two_stage":
        if target_error is not None:
            raise InputError("target_error is for transport='path' (two_stage has no Monte Carlo noise)")
        return _render_two_stage(sensor, contacts, camera, settings, crop=crop, pixels=pixels,
                                 background=background, n_sub=n_sub, table=table, variant=variant,
                                 progress=progress), None
    return path_trace(sensor, contacts, camera=camera, spp=spp, seed=seed, variant=variant, settings=settings,
                      crop=crop, pixels=pixels, background=background, progress=progress,
                      target_error=target_error, max_spp=max_spp, windows=windows)


def _render_two_stage(sensor, contacts, camera, settings, *, crop, pixels, background, n_sub, table,
                      variant, progress):
    from optitact.render.background import noload_radiance
    from optitact.render.emission import EmissionTable, emission_table
    from optitact.render.twostage import render_two_stage

    n_sub = integer(n_sub, "n_sub", minimum=1)
    if pixels is not None:
        raise InputError("transport='two_stage' renders exactly the pixels patches cover; pixels= is "
                         "for transport='path'")
    if table is not None and not isinstance(table, EmissionTable):
        raise TypeError(f"table must be an EmissionTable, got {type(table).__name__}")
    if background is not None:
        _, background = check_pixels(np.ones(camera.shape, bool), background, camera, None)
    else:
        background = noload_radiance(sensor, camera, settings=settings, variant=variant)
    if table is None:
        table = emission_table(sensor, settings=settings, variant=variant, progress=progress)
    img = render_two_stage(sensor, contacts, camera=camera, table=table, background=background,
                           settings=settings, n_sub=n_sub)
    if crop is not None:
        r0, c0, h, w = crop
        img = img[r0:r0 + h, c0:c0 + w].copy()
    return img
