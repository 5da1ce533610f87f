"""A user cache folder for expensive, reproducible intermediates (renders: :mod:`optitact.render.cache`).

The folder is ``$OPTITACT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/optitact``
(``~/.cache/optitact``): never next to the user's data. :func:`cached_arrays`
keeps named arrays there (the pipeline's precompute, ``precompute/``), keyed
by a fingerprint of what they are computed from; ``OPTITACT_PRECOMPUTE_CACHE=0``
turns that cache off.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from optitact.io.files import atomic_write, json_fingerprint

__all__ = ["CACHE_KEEP", "PRECOMPUTE_FORMAT", "cache_dir", "cached_arrays", "precompute_cache_enabled"]

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
    (:func:`optitact.io.files.atomic_write`): a reader sees a complete file or none.
    A file that cannot be read, whose stored fingerprint is not its key's,
    whose ZIP checksums fail or that ``check`` refuses is never trusted: the
    arrays are rebuilt and the file replaced. A cache folder that cannot be
    written only costs the rebuild next time. The folder keeps the
    :data:`CACHE_KEEP` most recently used files.
    """
    from optitact import __version__

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
