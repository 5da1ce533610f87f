"""A user cache folder for expensive, reproducible intermediates (rendered radiance).

The folder is ``$OPTITACT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/optitact``
(``~/.cache/optitact``): never next to the user's data.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .io import json_fingerprint, write_npy

__all__ = ["cache_dir", "cached_render"]


def cache_dir() -> Path:
    """The cache folder (created on first use)."""
    env = os.environ.get("OPTITACT_CACHE_DIR")
    if env:
        root = Path(env)
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "optitact"
    root.mkdir(parents=True, exist_ok=True)
    return root


def cached_render(sensor, forces, *, camera, spp: int, seed: int, variant: str | None = None,
                  spot_pixels_only: bool = False, settings=None) -> np.ndarray:
    """:func:`optitact.render.render` through the cache, keyed by every input that changes the image.

    The key holds the sensor, camera, forces (exact float64 bytes), spp, seed,
    render settings, the variant, the mode and the package version. With
    ``spot_pixels_only`` only :func:`optitact.render.spot_pixels` are rendered
    (the rest of the image is 0). Written atomically
    (temporary file, then rename), so a killed run leaves no half file.
    """
    from . import __version__
    from .render import RenderSettings, render, select_variant

    used = select_variant(variant)[1]
    settings = RenderSettings() if settings is None else settings
    f = np.ascontiguousarray(forces, dtype=np.float64)
    name = json_fingerprint({"sensor": sensor.to_dict(), "camera": camera.to_dict(), "spp": spp,
                             "seed": seed, "settings": asdict(settings), "variant": used,
                             "version": __version__, "forces": hashlib.sha256(f.tobytes()).hexdigest(),
                             "spot_pixels_only": bool(spot_pixels_only)}, 24)
    path = cache_dir() / "renders" / f"{name}.npy"
    if path.is_file():
        return np.load(path)
    if spot_pixels_only:
        from .render import spot_pixels

        img = render(sensor, f, camera=camera, spp=spp, seed=seed, variant=used, settings=settings,
                     pixels=spot_pixels(sensor, camera, f))
    else:
        img = render(sensor, f, camera=camera, spp=spp, seed=seed, variant=used, settings=settings)
    write_npy(path, img)
    return img
