"""Path-traced renders kept in the user cache (:func:`~optitact.io.cache.cache_dir`), keyed by their inputs.

Built on :mod:`optitact.render.pathtrace` (not on the package's :func:`optitact.render.render`, which
sits above this module): a cached render is the ``transport="path"`` frame of the given forces.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict
from pathlib import Path

import numpy as np

from optitact import __version__
from optitact.io.cache import cache_dir
from optitact.io.files import json_fingerprint, write_npy
from optitact.optics.contact import check_forces, contact_patches
from optitact.render.backend import select_variant
from optitact.render.pathtrace import path_trace, spot_pixels
from optitact.render.scene import RenderSettings

__all__ = ["cached_render", "render_cache_path"]


def cached_render(sensor, forces, *, camera, spp: int, seed: int, variant: str | None = None,
                  spot_pixels_only: bool = False, settings=None) -> np.ndarray:
    """:func:`optitact.render.render` through the cache, keyed by every input that changes the image.

    The key holds the sensor, camera, forces (exact float64 bytes), spp, seed,
    render settings, the variant, the mode and the package version. With
    ``spot_pixels_only`` only :func:`optitact.render.pathtrace.spot_pixels` are rendered
    (the rest of the image is 0). Written atomically
    (temporary file, then rename), so a killed run leaves no half file.
    """
    used = select_variant(variant)[1]
    settings = RenderSettings() if settings is None else settings
    f = np.ascontiguousarray(forces, dtype=np.float64)
    path = render_cache_path(sensor, f, camera=camera, spp=spp, seed=seed, variant=used,
                             spot_pixels_only=spot_pixels_only, settings=settings)
    if path.is_file():
        return np.load(path)
    pixels = spot_pixels(sensor, camera, f) if spot_pixels_only else None
    check_forces(f, sensor)
    img, _ = path_trace(sensor, contact_patches(sensor, f), camera=camera, spp=spp, seed=seed, variant=used,
                        settings=settings, pixels=pixels)
    write_npy(path, img)
    return img


def render_cache_path(sensor, forces, *, camera, spp: int, seed: int, variant: str | None = None,
                      spot_pixels_only: bool = False, settings=None) -> Path:
    """The file :func:`cached_render` keeps the render of these inputs in (there once rendered).

    Lets a caller tell which renders are cached before it starts them (to announce only the others).
    """
    used = select_variant(variant)[1]
    settings = RenderSettings() if settings is None else settings
    f = np.ascontiguousarray(forces, dtype=np.float64)
    name = json_fingerprint({"sensor": sensor.to_dict(), "camera": camera.to_dict(), "spp": spp,
                             "seed": seed, "settings": asdict(settings), "variant": used,
                             "version": __version__, "forces": hashlib.sha256(f.tobytes()).hexdigest(),
                             "spot_pixels_only": bool(spot_pixels_only)}, 24)
    return cache_dir() / "renders" / f"{name}.npy"
