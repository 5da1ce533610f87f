"""Physically based synthetic camera frames of the optical tactile sensor (Mitsuba 3).

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

import re
import sys
from dataclasses import dataclass

import numpy as np

from optitact._validate import integer, positive, seed_value
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.optics.contact import Contacts, check_forces, contact_patches
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

from optitact.render.backend import select_variant
from optitact.render.scene import RenderSettings

__all__ = ["render", "render_contacts", "RenderResult", "spot_pixels", "TRANSPORTS", "pass_seeds"]

_VARIANT_NAME = re.compile(r"^(scalar|llvm|cuda)(_ad)?_(rgb|mono|spectral)(_polarized)?(_double)?$")
#: Light transport modes of :func:`render`.
TRANSPORTS = ("path", "two_stage")
#: Samples per pixel rendered in one Mitsuba launch; larger spp runs as several passes.
SPP_PER_PASS = 16

#: Renders of fewer samples (pixels x samples per pixel) than this build the scene with the shell
#: instanced (see :func:`~optitact.render.scene.build_scene`): its faster build outweighs the slower
#: traversal below about 4 million samples on a CPU (0.09 s saved against ~0.05 us per sample).
INSTANCED_BELOW_SAMPLES = 1 << 22


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


def pass_seeds(seed: int, n_passes: int) -> list[int]:
    """Mitsuba seeds (uint32) of the passes of one frame, derived from its seed."""
    return [int(s) for s in np.random.SeedSequence(seed).generate_state(n_passes)]


def _check_variant(variant) -> None:
    """Refuse a malformed variant name before Mitsuba is imported (availability is checked later)."""
    if variant is None:
        return
    if not isinstance(variant, str):
        raise TypeError(f"variant must be a Mitsuba variant name (str), got {type(variant).__name__}")
    if not _VARIANT_NAME.match(variant):
        raise InputError(f"variant must be a Mitsuba variant name such as 'llvm_ad_rgb' or 'scalar_rgb' "
                         f"(<scalar|llvm|cuda>[_ad]_<rgb|mono|spectral>[_polarized][_double]), got {variant!r}")


def _check_camera(camera) -> None:
    """Any camera model renders, with either transport."""
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a FisheyeCamera, got {type(camera).__name__} (or another camera "
                        f"model of optitact.optics.camera: PinholeCamera, OpenCVFisheyeCamera)")


def _check_crop(crop, camera: Camera) -> tuple[int, int, int, int] | None:
    if crop is None:
        return None
    if isinstance(crop, (str, bytes)) or not hasattr(crop, "__len__"):
        raise TypeError(f"crop must be a sequence (row0, col0, height, width), got {type(crop).__name__}")
    if len(crop) != 4:
        raise InputError(f"crop must be (row0, col0, height, width), got {crop!r}")
    r0, c0, h, w = (integer(v, f"crop[{i}]", minimum=0) for i, v in enumerate(crop))
    if h < 1 or w < 1 or r0 + h > camera.height or c0 + w > camera.width:
        raise InputError(
            f"crop window (row0={r0}, col0={c0}, height={h}, width={w}) must lie inside the "
            f"{camera.height}x{camera.width} image and be non-empty"
        )
    return r0, c0, h, w


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
        Render only these pixels (e.g. :func:`spot_pixels`), in one launch
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
    ``seed`` (:func:`pass_seeds`); the passes are averaged in float64.
    """
    if not isinstance(sensor, DomeSensor):
        raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
    f = check_forces(forces, sensor)
    windows = None
    if target_error is not None:
        cam = FisheyeCamera() if camera is None else camera
        _check_camera(cam)
        pixel, label = _loaded_region_pixels(sensor, cam, f)
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
    if not isinstance(sensor, DomeSensor):
        raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
    if not isinstance(contacts, Contacts):
        raise TypeError(f"contacts must be a Contacts, got {type(contacts).__name__}")
    camera = FisheyeCamera() if camera is None else camera
    _check_camera(camera)
    settings = RenderSettings() if settings is None else settings
    if not isinstance(settings, RenderSettings):
        raise TypeError(f"settings must be a RenderSettings, got {type(settings).__name__}")
    spp = integer(spp, "spp", minimum=1)
    _check_variant(variant)
    seed = seed_value(seed)
    if seed is None:
        raise InputError("seed must be a non-negative integer, got None")
    crop = _check_crop(crop, camera)
    if transport not in TRANSPORTS:
        raise InputError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if transport == "two_stage":
        if target_error is not None:
            raise InputError("target_error is for transport='path' (two_stage has no Monte Carlo noise)")
        return _render_two_stage(sensor, contacts, camera, settings, crop=crop, pixels=pixels,
                                 background=background, n_sub=n_sub, table=table, variant=variant,
                                 progress=progress), None
    index, background = _check_pixels(pixels, background, camera, crop)
    if target_error is not None:
        target_error = positive(target_error, "target_error")
        max_spp = integer(max_spp, "max_spp", minimum=spp)
        if crop is not None:
            raise InputError("target_error works on full frames or pixels=, not crop=")
        windows = np.asarray(windows if windows is not None else np.full(camera.height * camera.width, -1))
        if windows.shape != (camera.height * camera.width,) or windows.dtype.kind not in "iu":
            raise InputError(f"windows must be a flat int array of {camera.height * camera.width} labels, "
                             f"got {windows.dtype} {windows.shape}")
    if index is not None and index.size == 0:
        return background.copy(), 0

    mi, _ = select_variant(variant)
    from optitact.render.scene import build_scene

    n_pixels = (index.size if index is not None else crop[2] * crop[3] if crop is not None
                else camera.width * camera.height)
    n_samples = n_pixels * (spp if target_error is None else max_spp)
    scene = build_scene(mi, sensor, camera, contacts, settings, crop=crop, pixels=index,
                        instanced=n_samples < INSTANCED_BELOW_SAMPLES)
    if target_error is None:
        n_passes = -(-spp // SPP_PER_PASS)
        counts = [spp // n_passes + (1 if i < spp % n_passes else 0) for i in range(n_passes)]
    else:
        # Right-sized sampling: passes of SPP_PER_PASS until every window's estimate has the target
        # relative standard error (at least spp, at most max_spp samples).
        n_passes = max(-(-max_spp // SPP_PER_PASS), 2)
        counts = [SPP_PER_PASS] * n_passes
        n_min = max(-(-spp // SPP_PER_PASS), 4)
        label = windows[index] if index is not None else windows
        keep = label >= 0
        n_win = int(label.max()) + 1 if keep.any() else 0
        base = (background.reshape(-1)[index] if index is not None else np.zeros(label.size))[keep]
        sums = []
    acc = None
    done = 0
    passes = zip(counts, pass_seeds(seed, n_passes), strict=True)
    if progress:
        from tqdm import tqdm

        passes = tqdm(passes, total=n_passes, desc="render", unit="pass", file=sys.stderr)
    for count, pass_seed in passes:
        img = np.asarray(mi.render(scene, spp=count, seed=pass_seed), dtype=np.float64)[..., 0]
        acc = img * count if acc is None else acc + img * count
        done += count
        if target_error is not None:
            flat = img.reshape(-1)[:label.size][keep] - base
            sums.append(np.bincount(label[keep], weights=flat, minlength=n_win))
            if len(sums) >= n_min:
                arr = np.array(sums)
                se = arr.std(axis=0, ddof=1) / np.sqrt(len(sums))
                if np.all(se <= target_error * np.abs(arr.mean(axis=0))):
                    break
    img = (acc / done).astype(np.float32)
    if index is None:
        return img, done
    out = background.copy()
    out.reshape(-1)[index] = img.reshape(-1)[:index.size]
    return out, done


def _render_two_stage(sensor, contacts, camera, settings, *, crop, pixels, background, n_sub, table,
                      variant, progress):
    from optitact.render.emission import EmissionTable, emission_table
    from optitact.render.background import noload_radiance
    from optitact.render.twostage import render_two_stage

    n_sub = integer(n_sub, "n_sub", minimum=1)
    if pixels is not None:
        raise InputError("transport='two_stage' renders exactly the pixels patches cover; pixels= is "
                         "for transport='path'")
    if table is not None and not isinstance(table, EmissionTable):
        raise TypeError(f"table must be an EmissionTable, got {type(table).__name__}")
    if background is not None:
        _, background = _check_pixels(np.ones(camera.shape, bool), background, camera, None)
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


def _check_pixels(pixels, background, camera: Camera, crop):
    """Validate ``pixels``/``background``: flat indices and a float32 canvas, or (None, None)."""
    if pixels is None:
        if background is not None:
            raise InputError("background is only used with pixels=")
        return None, None
    if crop is not None:
        raise InputError("give crop or pixels, not both")
    mask = np.asarray(pixels)
    if mask.dtype != bool:
        raise TypeError(f"pixels must be a bool mask of shape {camera.shape}, got dtype {mask.dtype}")
    if mask.shape != camera.shape:
        raise InputError(f"pixels must have the camera's shape {camera.shape}, got {mask.shape}")
    if background is None:
        canvas = np.zeros(camera.shape, np.float32)
    else:
        canvas = np.asarray(background)
        if canvas.dtype.kind not in "uif":
            raise TypeError(f"background must be a real image, got dtype {canvas.dtype}")
        if canvas.shape != camera.shape:
            raise InputError(f"background must have the camera's shape {camera.shape}, got "
                             f"{canvas.shape}")
        if not np.isfinite(canvas).all():
            raise InputError("background must be finite")
        if canvas.size and (canvas.min() < 0 or canvas.max() > np.finfo(np.float32).max):
            raise InputError(f"background must be radiance in [0, {np.finfo(np.float32).max:.3g}] (float32), "
                             f"got values in [{canvas.min():.3g}, {canvas.max():.3g}]")
        canvas = canvas.astype(np.float32)
    return np.flatnonzero(mask), canvas


def _loaded_region_pixels(sensor: DomeSensor, camera: Camera, forces: np.ndarray):
    """Flat pixels (and their element) the pipeline reads for the elements with ``Fz > 0``."""
    from optitact.pipeline.regions import fold_regions

    return fold_regions(sensor, camera).region_pixels(forces[:, 2] > 0)


def spot_pixels(sensor: DomeSensor, camera: Camera, forces, *,
                margin: float = 0.0) -> np.ndarray:
    """(H, W) bool: the pixels the pipeline reads for the loaded elements (where spots can show).

    The union of the region footprints (:func:`optitact.pipeline.regions.split_regions`)
    of elements with ``Fz > 0``, grown by ``margin`` pixels.
    """
    f = check_forces(forces, sensor)
    mask = np.zeros(camera.height * camera.width, bool)
    mask[_loaded_region_pixels(sensor, camera, f)[0]] = True
    mask = mask.reshape(camera.shape)
    if margin > 0:
        import cv2

        r = int(np.ceil(margin))
        mask = cv2.dilate(mask.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
    return mask
