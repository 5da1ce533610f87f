"""A user cache folder for expensive, reproducible intermediates (rendered radiance, precomputes).

The folder is ``$OPTITACT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/optitact``
(``~/.cache/optitact``): never next to the user's data. :func:`cached_arrays`
keeps named arrays there (the pipeline's precompute, ``precompute/``), keyed
by a fingerprint of what they are computed from; ``OPTITACT_PRECOMPUTE_CACHE=0``
turns that cache off.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .io import atomic_write, json_fingerprint, write_npy

__all__ = ["CACHE_KEEP", "PRECOMPUTE_FORMAT", "cache_dir", "cached_arrays", "cached_render",
           "precompute_cache_enabled", "render_cache_path"]

#: Format of :func:`cached_arrays`' files; part of every key, bumped when what is stored changes.
PRECOMPUTE_FORMAT = 1
#: Files :func:`cached_arrays` keeps per folder: the least recently used beyond them are removed.
CACHE_KEEP = 64


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
    from .render import RenderSettings, render, select_variant

    used = select_variant(variant)[1]
    settings = RenderSettings() if settings is None else settings
    f = np.ascontiguousarray(forces, dtype=np.float64)
    path = render_cache_path(sensor, f, camera=camera, spp=spp, seed=seed, variant=used,
                             spot_pixels_only=spot_pixels_only, settings=settings)
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


def render_cache_path(sensor, forces, *, camera, spp: int, seed: int, variant: str | None = None,
                      spot_pixels_only: bool = False, settings=None) -> Path:
    """The file :func:`cached_render` keeps the render of these inputs in (there once rendered).

    Lets a caller tell which renders are cached before it starts them (to announce only the others).
    """
    from . import __version__
    from .render import RenderSettings, select_variant

    used = select_variant(variant)[1]
    settings = RenderSettings() if settings is None else settings
    f = np.ascontiguousarray(forces, dtype=np.float64)
    name = json_fingerprint({"sensor": sensor.to_dict(), "camera": camera.to_dict(), "spp": spp,
                             "seed": seed, "settings": asdict(settings), "variant": used,
                             "version": __version__, "forces": hashlib.sha256(f.tobytes()).hexdigest(),
                             "spot_pixels_only": bool(spot_pixels_only)}, 24)
    return cache_dir() / "renders" / f"{name}.npy"


def precompute_cache_enabled() -> bool:
    """False when ``$OPTITACT_PRECOMPUTE_CACHE`` is ``0``, ``off``, ``false`` or ``no`` (any case)."""
    return os.environ.get("OPTITACT_PRECOMPUTE_CACHE", "1").strip().lower() not in ("0", "off", "false", "no")


def cached_arrays(kind: str, key: dict, build: Callable[[], dict], check: Callable[[dict], None], *,
                  cache: bool = True) -> dict:
    """Named arrays from ``cache_dir() / kind``, or ``build()`` them and store them there.

    Parameters
    ----------
    kind : str
        Subfolder of the cache (e.g. ``"precompute"``).
    key : dict
        JSON-able description of everything the arrays depend on; the
        package version, NumPy's version and :data:`PRECOMPUTE_FORMAT` are
        added to it. The file is ``<fingerprint>.npz``.
    build : callable
        Returns the arrays (a dict of name to ndarray, no object arrays).
    check : callable
        Called with the loaded arrays; raises (any exception) when they are
        not what ``build`` makes, so that a damaged file is rebuilt.
    cache : bool
        False (or ``$OPTITACT_PRECOMPUTE_CACHE=0``): build, read and write nothing.

    Returns
    -------
    dict of ndarray

    Notes
    -----
    The file is an uncompressed ``.npz`` written atomically
    (:func:`optitact.io.atomic_write`): a reader sees a complete file or none.
    A file that cannot be read, whose stored fingerprint is not its key's,
    whose ZIP checksums fail or that ``check`` refuses is never trusted: the
    arrays are rebuilt and the file replaced. A cache folder that cannot be
    written only costs the rebuild next time. The folder keeps the
    :data:`CACHE_KEEP` most recently used files.
    """
    from . import __version__

    if not (cache and precompute_cache_enabled()):
        return build()
    full = dict(key, package_version=__version__, numpy_version=np.__version__, format=PRECOMPUTE_FORMAT)
    name = json_fingerprint(full, 32)
    try:
        path = cache_dir() / kind / f"{name}.npz"
    except OSError:
        return build()
    try:
        with path.open("rb") as fh, np.load(fh, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}  # reads every member whole: the ZIP CRCs are checked
        if str(arrays.pop("fingerprint")) != name:
            raise ValueError(f"{path} holds another key")
        check(arrays)
        try:
            os.utime(path)  # recently used: kept longest
        except OSError:
            pass
        return arrays
    except Exception:  # missing, truncated, corrupt, foreign: rebuilt, never trusted
        pass
    arrays = build()

    def write(tmp: Path) -> None:
        with tmp.open("wb") as fh:
            np.savez(fh, fingerprint=np.array(name), **arrays)

    try:
        atomic_write(path, write)
        _prune(path.parent, CACHE_KEEP)
    except OSError:
        pass
    return arrays


def _prune(folder: Path, keep: int) -> None:
    """Remove the least recently used ``.npz`` files of ``folder`` beyond the ``keep`` newest."""
    files = []
    for entry in os.scandir(folder):
        if entry.name.endswith(".npz") and entry.is_file(follow_symlinks=False):
            try:
                files.append((entry.stat().st_mtime, entry.path))
            except FileNotFoundError:
                pass
    for _, old in sorted(files)[:max(len(files) - keep, 0)]:
        try:
            os.unlink(old)
        except FileNotFoundError:
            pass
