"""Atomic file writes, and the JSON, PNG and NPY writers built on them.

:func:`atomic_write` fills a temporary file beside the target and renames
it, so a reader sees the old file or the complete new one; the writers of
this module (:func:`write_json`, :func:`write_png`, :func:`write_npy`,
:func:`atomic_write_text`, :func:`atomic_write_png_figure`) all go through
it. :func:`json_fingerprint` keys caches and calibration files by their
settings.

The CSV tables (forces in, readings out) live in :mod:`optitact.io.tables`.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np


__all__ = ["write_png", "write_json", "read_json_object", "atomic_write", "atomic_write_text",
           "atomic_write_png_figure", "json_fingerprint", "write_npy"]


def atomic_write(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Write a file atomically: ``write(tmp)`` fills a temporary file beside ``path``, then it is renamed.

    A reader sees the old file or the complete new one, never half of it; if
    ``write`` raises, ``path`` is untouched and the temporary file is removed.
    The temporary file is ``.<name>.<pid>-<random>.tmp<suffix>`` (hidden,
    never read, keeping ``path``'s suffix so writers that choose the format by
    extension work); one left by a process that was killed is removed by the
    next write of the same ``path`` (only those whose process is gone). The
    parent folder is created if needed.
    """
    import re
    import secrets

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Temporaries of this path left by killed writers: this version's names and those of before
    # (``.<stem>.<pid>.tmp<suffix>``); a living writer's (its pid exists) is left alone.
    stale = re.compile(rf"^\.(?:{re.escape(path.name)}\.(\d+)-[0-9a-f]+|{re.escape(path.stem)}\.(\d+))"
                       rf"\.tmp{re.escape(path.suffix)}$")
    for entry in os.scandir(path.parent):
        m = stale.match(entry.name)
        if m is None or not entry.is_file(follow_symlinks=False):
            continue
        pid = int(m.group(1) or m.group(2))
        try:
            if pid == os.getpid():
                continue
            os.kill(pid, 0)
            continue  # alive: it may be writing now
        except (ProcessLookupError, OverflowError):
            pass  # gone (or never a pid): stale
        except OSError:
            continue  # alive under another user, or unknowable
        try:
            os.unlink(entry.path)
        except FileNotFoundError:
            pass
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_write`)."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def atomic_write_png_figure(fig, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Save a matplotlib figure as PNG at ``path`` atomically (:func:`atomic_write`)."""
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))


def write_npy(path: str | os.PathLike, array) -> Path:
    """Save an array as ``.npy`` at exactly ``path``, atomically (:func:`atomic_write`)."""

    def write(tmp: Path) -> None:
        with tmp.open("wb") as fh:
            np.save(fh, np.asarray(array))

    return atomic_write(path, write)


def json_fingerprint(obj, n: int = 16) -> str:
    """The first ``n`` hex digits of the SHA-256 of ``obj`` as JSON with sorted keys.

    Equal settings give equal fingerprints on every machine and run (keys
    sorted, floats written by ``repr``, ``json.dumps``' default separators:
    the calibration files' fingerprints and the cache keys written before
    this helper existed keep their values).

    Examples
    --------
    >>> json_fingerprint({"b": 1, "a": [1.0, 2]}) == json_fingerprint({"a": [1.0, 2], "b": 1})
    True
    """
    key = json.dumps(obj, sort_keys=True)
    return hashlib.sha256(key.encode()).hexdigest()[:n]



def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8/uint16 greyscale or (H, W, 3) BGR image as PNG (OpenCV, atomically)."""
    import cv2

    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"image must be uint8 or uint16, got {img.dtype}")

    def write(tmp: Path) -> None:
        ok, data = cv2.imencode(".png", img)
        if not ok:
            raise OSError(f"could not encode a PNG for {path}")
        tmp.write_bytes(data.tobytes())

    atomic_write(path, write)


def read_json_object(path: str | os.PathLike, keys: Sequence[str], *, what: str, writer: str) -> dict:
    """The JSON object in ``path``, holding ``keys``; InputError naming the file otherwise.

    ``what`` names the kind of file (``"setup"``), ``writer`` what writes one
    (``"optitact register"``), for the messages.

    Raises
    ------
    InputError
        A missing or unreadable file, one that is not UTF-8 JSON (nested too
        deeply included), or not an object holding ``keys``.
    """
    from optitact.errors import InputError

    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what} file (write one with {writer})") from None
    except RecursionError:  # Python's parser recurses once per nested array or object
        raise InputError(f"{path}: not a {what} JSON file (arrays or objects nested too deeply to read; "
                         f"{writer} writes a few levels)") from None
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise InputError(f"{path}: not a {what} JSON file ({exc})") from None
    if not isinstance(doc, dict) or any(k not in doc for k in keys):
        got = sorted(doc) if isinstance(doc, dict) else type(doc).__name__
        want = " and ".join(repr(k) for k in keys)
        raise InputError(f"{path}: expected a JSON object with {want} (as {writer} writes), got {got}")
    return doc


def write_json(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy arrays become lists)."""

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        raise TypeError(f"cannot write {type(o).__name__} as JSON")

    atomic_write_text(path, json.dumps(obj, indent=2, default=default) + "\n")
