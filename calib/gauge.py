"""The force gauge's CSV and the frames it goes with: measured presses.

:func:`read_presses` reads the gauge's CSV into element-local forces per frame
and element; :func:`measure_presses` reads the frames with a pipeline and
pairs them with it (:class:`Presses`); :func:`check_presses` checks forces
and a pressed mask against readings. Fits and reports on presses are in
:mod:`optitact.calib.press_fit` and :mod:`optitact.calib.held_out`.

The gauge CSV
-------------
One row per frame and pressed element, columns found by name (any order, any
case, units in brackets such as ``Fz (N)``, a byte-order mark, ``,`` ``;`` or
tab as :func:`optitact.io.csv_rows` reads them)::

    frame,element,fx,fy,fz[,frame_of_reference]

``frame`` is the frame's source as ``optitact process`` names it in its
``source`` column (``press_001.png``, or ``clip.avi#12`` for frame 12 of a
video or ``.npy`` stack) or a 0-based index into all the frames in the order
they are read (baseline frames included). ``element`` is the element index.
``fx, fy, fz`` are in N, element-local (``z`` the outward normal, ``fz > 0``
pressing) unless ``frame_of_reference`` reads ``global`` (the sensor frame:
converted with :func:`optitact.forces.local_from_global`). The elements of a
listed frame that have no row are unloaded, and so is every element of a
frame that is not listed: those no-load samples are used where the pipeline
sees contact anyway (a zero-force sample for the fit, and in the report's
``unloaded`` errors); a no-load frame also serves as the baseline
(``baseline_frames``). A *press* is one row: one frame of one element under a
known force; the usual protocol presses one element at a time, normal then
inclined, and frames pressing several elements at once (mixed loads) work
the same way.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from optitact._validate import check_type
from optitact.errors import InputError, ShapeError
from optitact.io import column_key, csv_numbers, csv_rows
from optitact.readings import Readings
from optitact.sensor import DomeSensor

__all__ = ["Presses", "check_presses", "measure_presses", "read_presses"]

_REFERENCES = ("local", "global")
_COLUMNS = ("frame", "element", "fx", "fy", "fz")


@dataclass(frozen=True, eq=False)
class Presses:
    """Frames read by the pipeline, with the gauge's forces (what :func:`measure_presses` returns).

    Attributes
    ----------
    sources : list of str
        Each frame's source (as ``optitact process`` names it).
    readings : Readings
        ``(T, E)`` readings of the frames.
    forces : (T, E, 3) ndarray
        Element-local forces (N); 0 for elements without a row.
    pressed : (T, E) bool ndarray
        The gauge CSV has a row for this frame and element.
    """

    sources: list
    readings: Readings
    forces: np.ndarray
    pressed: np.ndarray


# ---------------------------------------------------------------------------- the gauge CSV
def _frame_index(cell: str, sources: Sequence[str], by_name: dict, path, lineno: int, col: int) -> int:
    """The frame a ``frame`` cell names: a source name or a 0-based index."""
    if cell in by_name:
        hits = by_name[cell]
        if len(hits) > 1:
            raise InputError(f"{path}, line {lineno}, column {col}: frame {cell!r} names {len(hits)} frames "
                             f"(frames {', '.join(map(str, hits[:5]))}: files of the same name in different "
                             f"folders); name the frame by its 0-based index instead")
        return hits[0]
    try:
        k = float(cell)
    except ValueError:
        k = math.nan
    if k.is_integer() and 0 <= k < len(sources):
        return int(k)
    shown = ", ".join(repr(s) for s in sources[:3]) + (", ..." if len(sources) > 3 else "")
    raise InputError(f"{path}, line {lineno}, column {col}: frame {cell!r} is not one of the {len(sources)} "
                     f"frames: name it as the 'source' column of optitact process does ({shown}) or by its "
                     f"0-based index 0..{len(sources) - 1}")


def read_presses(path: str | os.PathLike, sources: Sequence[str], sensor: DomeSensor) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    r"""Read a force gauge's CSV: element-local forces per frame and element.

    Parameters
    ----------
    path : path-like
        The CSV (see the module docstring for its columns).
    sources : sequence of str
        The frames' sources in order (:attr:`optitact.batch.ProcessedFrames.sources`).
    sensor : DomeSensor

    Returns
    -------
    forces : (T, E, 3) float64 ndarray
        Element-local forces (N); 0 where there is no row.
    pressed : (T, E) bool ndarray
        Where there is a row.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ShapeError
        No header naming ``frame, element, fx, fy, fz``, a row of the wrong width, no rows.
    InputError
        A frame or element that does not exist, a force that is not a finite
        number (NaN), a frame listed twice for one element, an unknown
        ``frame_of_reference`` (each message gives the line).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from optitact import DomeSensor
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "gauge.csv"
    >>> _ = p.write_text("Frame;Element;Fx (N);Fy (N);Fz (N)\npress_1.png;3;0.1;0;0.5\n1;0;0;0;0.2\n")
    >>> f, pressed = read_presses(p, ["noload.png", "press_1.png"], DomeSensor.default())
    >>> f.shape, f[1, 3].tolist(), f[1, 0].tolist(), int(pressed.sum())
    ((2, 41, 3), [0.1, 0.0, 0.5], [0.0, 0.0, 0.2], 2)
    """
    from optitact.forces import local_from_global

    check_type(sensor, DomeSensor, "sensor")
    sources = [str(s) for s in sources]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"force gauge file not found: {path}")
    rows = csv_rows(path)
    if not rows:
        raise ShapeError(f"{path}: empty; expected a header {', '.join(_COLUMNS)} and one row per frame and "
                         f"pressed element")
    header_line, first = rows[0]
    header = [column_key(c) for c in first]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise ShapeError(f"{path}, line {header_line}: no column {', '.join(missing)} in the header {first}; "
                         f"expected the columns {', '.join(_COLUMNS)} (any order, units like 'Fz (N)'), "
                         f"optionally frame_of_reference (local or global)")
    col = {k: header.index(k) for k in (*_COLUMNS, "frame_of_reference") if k in header}
    n_t, n_el = len(sources), sensor.n_elements
    by_name: dict[str, list[int]] = {}
    for i, s in enumerate(sources):
        by_name.setdefault(s, []).append(i)
    forces = np.zeros((n_t, n_el, 3))
    pressed = np.zeros((n_t, n_el), bool)
    is_global = np.zeros((n_t, n_el), bool)
    line_of: dict[tuple[int, int], int] = {}
    if len(rows) < 2:
        raise ShapeError(f"{path}: a header and no presses; expected one row per frame and pressed element")
    for lineno, cells in rows[1:]:
        if len(cells) != len(header):
            raise ShapeError(f"{path}, line {lineno}: expected {len(header)} columns, got {len(cells)}")
        t = _frame_index(cells[col["frame"]], sources, by_name, path, lineno, col["frame"] + 1)
        cell = cells[col["element"]]
        try:
            e = float(cell)
        except ValueError:
            e = math.nan
        if not (e.is_integer() and 0 <= e < n_el):
            raise InputError(f"{path}, line {lineno}, column {col['element'] + 1}: element {cell!r} does not "
                             f"exist (the sensor's elements are 0..{n_el - 1})")
        e = int(e)
        if (t, e) in line_of:
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r} is listed twice for element {e} "
                             f"(also on line {line_of[t, e]}); one row per frame and element")
        line_of[t, e] = lineno
        forces[t, e] = [csv_numbers([cells[col[k]]], path, lineno, first_column=col[k] + 1)[0]
                        for k in ("fx", "fy", "fz")]
        pressed[t, e] = True
        if "frame_of_reference" in col:
            ref = cells[col["frame_of_reference"]].strip().lower() or "local"
            if ref not in _REFERENCES:
                raise InputError(f"{path}, line {lineno}, column {col['frame_of_reference'] + 1}: "
                                 f"frame_of_reference must be local or global, got "
                                 f"{cells[col['frame_of_reference']]!r}")
            is_global[t, e] = ref == "global"
    for t in np.flatnonzero(is_global.any(axis=1)):
        local = local_from_global(sensor, forces[t])
        forces[t, is_global[t]] = local[is_global[t]]
    return forces, pressed


# ---------------------------------------------------------------------------- frames -> presses
def measure_presses(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *, pipeline,
                    baseline=None, baseline_frames: int = 1, progress: bool = False) -> Presses:
    """Read frames with ``pipeline`` and the gauge CSV ``forces`` that goes with them.

    Parameters
    ----------
    frames : sequence of path-like
        Image files, folders, ``.npy`` stacks or videos
        (:func:`optitact.frames.expand_sources`), read in order.
    forces : path-like
        The gauge CSV (see the module docstring).
    pipeline : Pipeline
    baseline : array_like, optional
        No-load frame(s); else the mean of the first ``baseline_frames``
        frames (which must not be listed in the CSV), as in
        :func:`optitact.batch.process_files`.
    baseline_frames : int
    progress : bool

    Raises
    ------
    InputError
        The CSV names a baseline frame as pressed; see also :func:`read_presses`
        and :func:`~optitact.batch.process_files`.
    """
    from optitact.batch import process_files

    done = process_files(frames, pipeline=pipeline, baseline=baseline, baseline_frames=baseline_frames,
                         progress=progress)
    f, pressed = read_presses(forces, done.sources, pipeline.sensor)
    n_base = 0 if baseline is not None or pipeline.baseline is not None else int(baseline_frames)
    hit = np.flatnonzero(pressed[:n_base].any(axis=1))
    if hit.size:
        raise InputError(f"{forces}: frame {done.sources[hit[0]]!r} is the no-load baseline (the first "
                         f"{n_base} frame(s), baseline_frames / --baseline-frames) but the gauge lists it "
                         f"pressed; record no-load frames first, or give the baseline as a file "
                         f"(--baseline)")
    return Presses(sources=list(done.sources), readings=done.readings, forces=f, pressed=pressed)


def check_presses(readings: Readings, forces, pressed) -> tuple[np.ndarray, np.ndarray]:
    """Forces ``(T, E, 3)`` and the pressed mask ``(T, E)`` checked against stack readings."""
    if not isinstance(readings, Readings) or not readings.is_stack:
        raise TypeError("readings must be stack Readings (T, E) from Pipeline.process(stack)")
    f = np.asarray(forces, dtype=np.float64)
    shape = readings.G.shape
    if f.shape != (*shape, 3):
        raise ShapeError(f"forces must have shape {(*shape, 3)} to match the readings, got {f.shape}")
    if not np.isfinite(f).all():
        raise InputError("forces must be finite (a NaN or infinite gauge reading)")
    pressed = np.any(f != 0, axis=-1) if pressed is None else np.asarray(pressed, dtype=bool)
    if pressed.shape != shape:
        raise ShapeError(f"pressed must have shape {shape}, got {pressed.shape}")
    return f, pressed
