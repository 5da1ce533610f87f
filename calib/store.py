"""The housekeeping of a calibration set's Zarr store: its lock, and a store killed half-made.

:func:`store_lock` holds an exclusive OS lock (``flock``) on the store while
:func:`~optitact.calib.sets.generate` writes it, so that a second writer is refused
at once (:class:`StoreLockedError`, naming the holder). :func:`open_store`
opens a whole store, rebuilds one killed before its attributes were written
and refuses a folder holding anything a store never has (a user's files are
never deleted); :func:`remove_partials` removes Zarr's temporary
``*.partial`` files left by a kill.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import socket
import sys
import time
from pathlib import Path

from optitact.errors import InputError

__all__ = ["LOCK_NAME", "StoreLockedError", "open_store", "remove_partials", "store_lock"]

#: The lock file inside a store (:func:`~optitact.calib.sets.generate` holds an OS lock on it while it writes).
LOCK_NAME = ".optitact-lock"
#: The names a store's own files and folders have (a folder holding anything else is not deleted).
_ARRAYS = ("forces", "seeds", "G", "u", "contact", "saturated", "frames", "baseline", "baseline_radiance",
           "baseline_done", "done")
#: Zarr's temporary files (``<name>.<uuid4 hex>.partial``, renamed over ``<name>`` when whole).
_PARTIAL = re.compile(r"^(zarr|\d+)\.[0-9a-f]{32}\.partial$")
_CHUNK = re.compile(r"^\d+$")


class StoreLockedError(InputError):
    """Another process is writing the calibration set (it holds the store's lock)."""


@contextlib.contextmanager
def store_lock(path: Path):
    """Hold an exclusive OS lock (``flock``) on ``path/LOCK_NAME`` while the block runs.

    The lock file records who holds it (pid, host, command, since when); the
    lock is released when the block ends or the process dies, whatever the
    cause. Raises :class:`StoreLockedError` at once (no waiting) if another
    process holds it.
    """
    try:
        import fcntl
    except ImportError:  # not a POSIX system: no OS lock to take
        yield
        return
    path.mkdir(parents=True, exist_ok=True)
    lock = path / LOCK_NAME
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise StoreLockedError(f"{path} is being written by another process ({_holder(lock)}); "
                                   f"wait for it to finish, or stop it and run this command again") from None
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": " ".join(sys.argv),
                  "since": time.strftime("%Y-%m-%d %H:%M:%S %z")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def _holder(lock: Path) -> str:
    """Who holds ``lock``, as its holder wrote it."""
    try:
        h = json.loads(lock.read_text(encoding="utf-8"))
        return (f"pid {h['pid']} on {h['host']}, running {h['command']!r} since {h['since']}; "
                f"lock file {lock}")
    except (OSError, ValueError, KeyError, TypeError):
        return f"no details written yet; lock file {lock}"


def _foreign(path: Path) -> list[Path]:
    """Entries under ``path`` whose names a calibration store never uses (a user's files)."""
    out = []
    for entry in path.iterdir():
        name = entry.name
        if name in (LOCK_NAME, "zarr.json") or _PARTIAL.match(name):
            if entry.is_dir():
                out.append(entry)
            continue
        if name not in _ARRAYS or not entry.is_dir():
            out.append(entry)
            continue
        for root, dirs, files in os.walk(entry):
            rel = Path(root).relative_to(entry)
            for d in dirs:
                if not (rel == Path(".") and d == "c" or rel.parts[:1] == ("c",) and _CHUNK.match(d)):
                    out.append(Path(root) / d)
            for f in files:
                if not (f == "zarr.json" and rel == Path(".") or _PARTIAL.match(f)
                        or rel.parts[:1] == ("c",) and _CHUNK.match(f)):
                    out.append(Path(root) / f)
            dirs[:] = [d for d in dirs if Path(root) / d not in out]
    return out


def open_store(path: Path, zarr, *, schema: str):
    """The store's group (read-write) if ``path`` holds a whole calibration set; None if it must be created.

    ``zarr`` is the imported module and ``schema`` the set's schema name (a
    store whose attributes name it is whole). A folder that is empty, or holds only a store's own files but no
    finished store (killed while it was being created or removed: its
    attributes, written last, are missing or unreadable), is emptied and
    None returned. A folder with anything else in it is never touched: an
    InputError names what does not belong.
    """
    if not path.exists():
        return None
    group = None
    try:
        group = zarr.open_group(str(path), mode="r+")
        whole = dict(group.attrs).get("schema") == schema
    except Exception:  # zarr raises several kinds for a missing or unreadable zarr.json
        whole = False
    if whole:
        return group
    foreign = _foreign(path)
    if foreign:
        shown = ", ".join(str(p.relative_to(path)) for p in foreign[:3])
        raise InputError(f"{path} exists and is not a calibration set (it holds {shown}"
                         f"{' ...' if len(foreign) > 3 else ''}, which a calibration set never has); "
                         f"nothing was changed: use another --out")
    if group is not None and dict(group.attrs).get("schema"):
        raise InputError(f"{path} is a Zarr store of another kind (schema "
                         f"{dict(group.attrs).get('schema')!r}); use another --out")
    if any(p.is_file() and not _PARTIAL.match(p.name) for p in (path / "done" / "c").rglob("*")):
        raise InputError(f"{path} has finished frames but no readable settings; it was not changed: "
                         f"move it away or use another --out")
    for entry in path.iterdir():  # a half-made store: start again (the lock file stays)
        if entry.name == LOCK_NAME:
            continue
        if entry.is_dir():
            shutil.rmtree(entry)
        else:
            entry.unlink()
    return None


def remove_partials(path: Path) -> None:
    """Remove Zarr's temporary ``*.partial`` files left by a process killed mid-write (we hold the lock)."""
    for p in path.rglob("*.partial"):
        if _PARTIAL.match(p.name) and p.is_file():
            p.unlink()
