"""Path-traced frames: Mitsuba's Monte Carlo light transport, in passes, and the checks of a render request.

:func:`path_trace` renders contact patches by brute-force path tracing (the
reference transport of :func:`optitact.render.render`, ``transport="path"``),
in passes of at most :data:`SPP_PER_PASS` samples seeded by :func:`pass_seeds`;
:func:`spot_pixels` picks the pixels worth rendering for a load. The checks
every render request passes, whichever its transport (:func:`check_request`,
:func:`check_camera`, :func:`check_pixels`), live here too, as the lowest
module that needs them.

Layering: this module imports no other module of :mod:`optitact.render` but
the scene and the backend; :mod:`optitact.render.cache`,
:mod:`optitact.render.emission` and the package's :func:`~optitact.render.render`
build on it, never the other way round.

Import cost: importing this module does not import mitsuba; the first
render does, after pointing Dr.Jit at a usable libLLVM.
"""

from __future__ import annotations

import re
import sys

import numpy as np

from optitact._validate import integer, positive, seed_value
from optitact.errors import InputError
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.optics.contact import Contacts, check_forces
from optitact.optics.sensor import DomeSensor

from optitact.render.backend import select_variant
from optitact.render.scene import RenderSettings

__all__ = ["SPP_PER_PASS", "check_camera", "check_pixels", "check_request", "loaded_region_pixels",
           "pass_seeds", "path_trace", "spot_pixels"]

_VARIANT_NAME = re.compile(r"^(scalar|llvm|cuda)(_ad)?_(rgb|mono|spectral)(_polarized)?(_double)?$")
#: Samples per pixel rendered in one Mitsuba launch; larger spp runs as several passes.
SPP_PER_PASS = 16

#: Renders of fewer samples (pixels x samples per pixel) than this build the scene with the shell
#: instanced (see :func:`~optitact.render.scene.build_scene`): on a CPU its faster build outweighs
#: its slower traversal below about this many samples.
INSTANCED_BELOW_SAMPLES = 1 << 22


def pass_seeds(seed: int, n_passes: int) -> list[int]:
    """Mitsuba seeds (uint32) of the passes of one frame, derived from its seed.

    Parameters
    ----------
    seed : int
        The frame's seed (>= 0).
    n_passes : int
        How many passes the frame is rendered in.

    Returns
    -------
    list of int
        One seed per pass, the same for the same ``seed`` and distinct between passes.
    """
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


def check_camera(camera) -> None:
    """Refuse anything but a camera model; any model renders, with either transport.

    Parameters
    ----------
    camera : Camera
        The camera to render through.

    Raises
    ------
    TypeError
        For anything that is not a :class:`~optitact.optics.camera.Camera`.
    """
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


def check_request(sensor, contacts, *, camera, settings, spp, seed, variant, crop):
    """Check the inputs every render takes, whichever its transport, before Mitsuba is imported.

    Parameters
    ----------
    sensor : DomeSensor
    contacts : Contacts
    camera : Camera or None
        None: ``FisheyeCamera()``.
    settings : RenderSettings or None
        None: ``RenderSettings()``.
    spp : int
        Samples per pixel (>= 1).
    seed : int
        Seed (>= 0).
    variant : str or None
        A Mitsuba variant name (its availability is checked when it is loaded).
    crop : (row0, col0, height, width) or None
        A window inside the image.

    Returns
    -------
    camera : Camera
    settings : RenderSettings
    spp : int
    seed : int
    crop : tuple of 4 int, or None
        The inputs with their defaults filled in and numbers made plain ints.

    Raises
    ------
    TypeError, InputError
        For the first invalid input, in the order above.
    """
    if not isinstance(sensor, DomeSensor):
        raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
    if not isinstance(contacts, Contacts):
        raise TypeError(f"contacts must be a Contacts, got {type(contacts).__name__}")
    camera = FisheyeCamera() if camera is None else camera
    check_camera(camera)
    settings = RenderSettings() if settings is None else settings
    if not isinstance(settings, RenderSettings):
        raise TypeError(f"settings must be a RenderSettings, got {type(settings).__name__}")
    spp = integer(spp, "spp", minimum=1)
    _check_variant(variant)
    seed = seed_value(seed)
    if seed is None:
        raise InputError("seed must be a non-negative integer, got None")
    crop = _check_crop(crop, camera)
    return camera, settings, spp, seed, crop


def check_pixels(pixels, background, camera: Camera, crop):
    """Check a ``pixels`` mask and the ``background`` it is composited over.

    Parameters
    ----------
    pixels : (H, W) bool array_like or None
        The pixels to render (the camera's shape).
    background : (H, W) array_like or None
        Radiance the rendered pixels are composited over (default zeros);
        only with ``pixels``.
    camera : Camera
    crop : tuple or None
        The request's crop window; ``pixels`` and ``crop`` exclude each other.

    Returns
    -------
    index : (K,) int ndarray or None
        The flat indices of the pixels to render (None without ``pixels``).
    canvas : (H, W) float32 ndarray or None
        The background as float32 radiance (None without ``pixels``).

    Raises
    ------
    TypeError, InputError
        For a mask that is not bool or not of the camera's shape, a
        background without ``pixels``, or one that is not finite float32 radiance.
    """
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


def path_trace(sensor: DomeSensor, contacts: Contacts, *, camera: Camera | None = None, spp: int = 64,
               seed: int = 0, variant: str | None = None, settings: RenderSettings | None = None,
               crop: tuple[int, int, int, int] | None = None, pixels=None, background=None,
               progress: bool = False, target_error: float | None = None, max_spp: int = 4096,
               windows=None) -> tuple[np.ndarray, int]:
    """Path-trace contact patches: the radiance image and the samples per pixel it took.

    Parameters
    ----------
    sensor, contacts, camera, spp, seed, variant, settings, crop, pixels, background, progress
        As for :func:`optitact.render.render_contacts` with ``transport="path"``.
    target_error, max_spp
        As for :func:`optitact.render.render_contacts` with ``transport="path"``.
    windows : (H*W,) int array_like, optional
        With ``target_error``: the pixels whose sums must converge, labelled
        (-1: none); default none.

    Returns
    -------
    radiance : (H, W) float32 ndarray
        The image (``crop``'s shape with ``crop``).
    spp : int
        Samples per pixel rendered (with ``target_error``, where the passes
        stopped; 0 when no pixel was rendered).

    Notes
    -----
    Every input is checked before Mitsuba is imported. ``spp`` is rendered in
    passes of at most ``SPP_PER_PASS`` samples whose seeds derive from
    ``seed`` (:func:`pass_seeds`); the passes are averaged in float64.
    """
    camera, settings, spp, seed, crop = check_request(sensor, contacts, camera=camera, settings=settings,
                                                      spp=spp, seed=seed, variant=variant, crop=crop)
    index, background = check_pixels(pixels, background, camera, crop)
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


def loaded_region_pixels(sensor: DomeSensor, camera: Camera,
                         forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels the pipeline reads for the loaded elements (``Fz > 0``), and their element.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
    forces : (N, 3) ndarray
        Element-local forces (checked, e.g. by
        :func:`optitact.optics.contact.check_forces`).

    Returns
    -------
    pixels : (K,) int ndarray
        Flat pixel indices of the loaded elements' regions
        (:func:`optitact.pipeline.regions.fold_regions`).
    elements : (K,) int ndarray
        The element each pixel belongs to.
    """
    from optitact.pipeline.regions import fold_regions

    return fold_regions(sensor, camera).region_pixels(forces[:, 2] > 0)


def spot_pixels(sensor: DomeSensor, camera: Camera, forces, *,
                margin: float = 0.0) -> np.ndarray:
    """(H, W) bool: the pixels the pipeline reads for the loaded elements (where spots can show).

    The union of the region footprints (:func:`optitact.pipeline.regions.split_regions`)
    of elements with ``Fz > 0``, grown by ``margin`` pixels; pass it as
    ``pixels=`` to :func:`optitact.render.render` to path-trace only those.
    """
    f = check_forces(forces, sensor)
    mask = np.zeros(camera.height * camera.width, bool)
    mask[loaded_region_pixels(sensor, camera, f)[0]] = True
    mask = mask.reshape(camera.shape)
    if margin > 0:
        import cv2

        r = int(np.ceil(margin))
        mask = cv2.dilate(mask.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
    return mask
