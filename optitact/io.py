"""Reading and writing forces and frames.

Forces CSV format: one row per element, in element order, with columns
``fx, fy, fz`` (element-local, N) or ``element, fx, fy, fz``. A header row
naming the columns is optional; blank lines and lines starting with ``#`` are
ignored.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from .errors import InputError, ShapeError

__all__ = ["read_forces_csv", "write_forces_csv", "write_png", "write_json", "ReadingsWriter", "atomic_write",
           "atomic_write_text", "atomic_write_png_figure", "json_fingerprint", "write_npy"]

_HEADERS = (["fx", "fy", "fz"], ["element", "fx", "fy", "fz"])


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


def csv_rows(path: Path) -> list[tuple[int, list[str]]]:
    """Non-blank, non-comment rows of a CSV file as ``(line number, stripped cells)``."""
    rows: list[tuple[int, list[str]]] = []
    with Path(path).open(newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row]
            if not any(cells) or cells[0].startswith("#"):
                continue
            rows.append((lineno, cells))
    return rows


def csv_numbers(cells: Sequence[str], path, lineno: int, first_column: int = 1) -> list[float]:
    """Parse CSV cells as finite numbers; InputError naming line and column otherwise."""
    out = []
    for j, cell in enumerate(cells, start=first_column):
        try:
            v = float(cell)
        except ValueError:
            raise InputError(f"{path}, line {lineno}, column {j}: {cell!r} is not a number") from None
        if not math.isfinite(v):
            raise InputError(f"{path}, line {lineno}, column {j}: {cell!r} is not finite")
        out.append(v)
    return out


def read_forces_csv(path: str | os.PathLike, n_elements: int) -> np.ndarray:
    """Read element-local forces (N) from a CSV file.

    Parameters
    ----------
    path : path-like
        The CSV file (see the module docstring for the format).
    n_elements : int
        Expected number of rows (elements).

    Returns
    -------
    (n_elements, 3) float64 ndarray

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    InputError
        A cell that is not a finite number (the message gives line and column),
        element indices out of order.
    ShapeError
        Wrong number of rows or columns.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"forces file not found: {path}")
    rows = csv_rows(path)
    if rows and [c.lower() for c in rows[0][1]] in _HEADERS:
        rows = rows[1:]
    if not rows:
        raise ShapeError(f"{path}: expected {n_elements} rows of fx, fy, fz (N), got none")
    width = len(rows[0][1])
    if width not in (3, 4):
        raise ShapeError(
            f"{path}, line {rows[0][0]}: expected 3 columns (fx, fy, fz) or 4 "
            f"(element, fx, fy, fz), got {width}"
        )
    values = np.empty((len(rows), width))
    for i, (lineno, cells) in enumerate(rows):
        if len(cells) != width:
            raise ShapeError(f"{path}, line {lineno}: expected {width} columns, got {len(cells)}")
        values[i] = csv_numbers(cells, path, lineno)
    if len(rows) != n_elements:
        raise ShapeError(f"{path}: expected {n_elements} rows (one per element), got {len(rows)}")
    if width == 4:
        if not np.array_equal(values[:, 0], np.arange(n_elements)):
            raise InputError(f"{path}: the element column must read 0, 1, ..., {n_elements - 1}")
        values = values[:, 1:]
    return values


def write_forces_csv(path: str | os.PathLike, forces: np.ndarray) -> None:
    """Write element-local forces (N, 3) as ``element, fx, fy, fz`` CSV with a header (atomically)."""
    f = np.asarray(forces, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ShapeError(f"forces must have shape (N, 3), got {f.shape}")

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(_HEADERS[1])
            for i, row in enumerate(f):
                w.writerow([i, *(repr(float(v)) for v in row)])

    atomic_write(path, write)


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


def write_json(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy arrays become lists)."""

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        raise TypeError(f"cannot write {type(o).__name__} as JSON")

    atomic_write_text(path, json.dumps(obj, indent=2, default=default) + "\n")


class ReadingsWriter:
    """Append readings (and estimated forces) to a CSV file, one row per frame and element.

    Columns: ``frame, source, element, G, ux, uy, contact, saturated`` (G in
    grey level x mm^2, u in mm, flags as 0/1; numbers written with the
    shortest digits that read back to the same float64), and with ``forces=True`` also
    ``fx, fy, fz`` (element-local, N) and ``clamped`` (the calibration
    clamped the reading to its fitted range). Use as a context manager.

    Rows go to a temporary file beside ``path``, renamed to ``path`` on
    :meth:`close`: a reader never sees half a table. Leaving the ``with``
    block by an exception discards the rows and leaves ``path`` untouched.
    """

    COLUMNS = ("frame", "source", "element", "G", "ux", "uy", "contact", "saturated")
    FORCE_COLUMNS = ("fx", "fy", "fz", "clamped")

    def __init__(self, path: str | os.PathLike, *, forces: bool = False) -> None:
        self.path = Path(path)
        self.with_forces = forces
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.stem}.{os.getpid()}.tmp{self.path.suffix}")
        self._fh = self._tmp.open("w", newline="")
        self._csv = csv.writer(self._fh)
        self._csv.writerow(self.COLUMNS + (self.FORCE_COLUMNS if forces else ()))
        self.frames = 0

    def write(self, readings, sources: Sequence[str], forces=None, clamped=None) -> None:
        """Write readings of ``len(sources)`` frames (a stack, or one frame), with forces if kept."""
        r = readings if readings.is_stack else readings._lifted()
        if len(r) != len(sources):
            raise ShapeError(f"got readings of {len(r)} frames for {len(sources)} sources")
        if self.with_forces:
            if forces is None or clamped is None:
                raise ValueError("this writer has force columns: pass forces and clamped")
            forces = np.asarray(forces).reshape(len(r), r.n_elements, 3)
            clamped = np.asarray(clamped).reshape(len(r), r.n_elements)
        # repr of a Python float is the shortest string that reads back to the same float64, so
        # sums over the file (10^6 rows and more) equal sums over the readings bit for bit
        g, u = r.G.tolist(), r.u.tolist()
        contact, saturated = r.contact.tolist(), r.saturated.tolist()
        if self.with_forces:
            forces, clamped = forces.astype(np.float64).tolist(), clamped.tolist()
        for k, src in enumerate(sources):
            for i in range(r.n_elements):
                row = [self.frames, src, i, repr(g[k][i]), repr(u[k][i][0]), repr(u[k][i][1]),
                       int(contact[k][i]), int(saturated[k][i])]
                if self.with_forces:
                    row += [repr(v) for v in forces[k][i]] + [int(clamped[k][i])]
                self._csv.writerow(row)
            self.frames += 1

    def close(self) -> None:
        """Close the file and move it to ``path`` (again: nothing)."""
        if self._fh.closed:
            return
        self._fh.close()
        os.replace(self._tmp, self.path)

    def discard(self) -> None:
        """Close and delete the rows written so far; ``path`` is left as it was."""
        self._fh.close()
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> ReadingsWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.discard()
