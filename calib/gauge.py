"""The force gauge's CSV and the frames it goes with: measured presses.

:func:`read_presses` reads the gauge's CSV into element-local forces per frame
and element; :func:`measure_presses` reads the frames with a pipeline and
pairs them with it (:class:`Presses`); :func:`check_presses` checks forces
and a pressed mask against readings. Fits and reports on presses are in
:mod:`optitact.calib.press_fit` and :mod:`optitact.calib.held_out`.

The gauge CSV
-------------
One row per frame and pressed element, columns found by name (any order, any
case, ``,`` ``;`` or tab as :func:`optitact.io.tables.sniff_delimiter` tells them)::

    frame,element,fx,fy,fz[,frame_of_reference]

``frame`` is the frame's source as ``optitact process`` names it in its
``source`` column (``press_001.png``, or ``clip.avi#12`` for frame 12 of a
video or ``.npy`` stack) or a 0-based index into all the frames in the order
they are read (baseline frames included). ``element`` is the element index.
``fx, fy, fz`` are element-local (``z`` the outward normal, ``fz > 0``
pressing) unless ``frame_of_reference`` reads ``global`` (the sensor frame:
converted with :func:`optitact.optics.force_frames.local_from_global`). The elements of a
listed frame that have no row are unloaded, and so is every element of a
frame that is not listed: those no-load samples are used where the pipeline
sees contact anyway (a zero-force sample for the fit, and in the report's
``unloaded`` errors); a no-load frame also serves as the baseline
(``baseline_frames``). A *press* is one row: one frame of one element under a
known force; the usual protocol presses one element at a time, normal then
inclined, and frames pressing several elements at once (mixed loads) work
the same way.

Units. A force column's unit is written in brackets after its name, ``Fz
(mN)`` or ``Fz [mN]``, one of :data:`GAUGE_UNITS` in any case (``N``, ``mN``,
``kN``, ``gf``, ``kgf``, ``lbf``, ``ozf``), and converted to N; a column
without one is in N. Any other unit is refused by name (``g``, ``kg``,
``lb`` and ``oz`` too: masses, where a gauge's gram-force is ``gf``), and so
is a unit glued to the name (``fz_mN``: write ``Fz (mN)``).

Forces a press cannot have are refused, naming the line, frame and element:
a component beyond :data:`MAX_GAUGE_FORCE_N` (100 N on one element: a unit
left out of the header is the usual cause), a negative local ``Fz`` (a pull,
no contact), a shear with ``Fz = 0`` (nothing holds it), and a file whose
every ``Fz`` is 0 (nothing to fit). Two columns of one name (``fz`` and
``Fz (N)``) are refused as ambiguous.

Encoding. UTF-8 (with or without a byte-order mark, as Excel's "CSV UTF-8"
writes it) or UTF-16 with a byte-order mark (Excel's "Unicode text"); a file
that is not valid UTF-8 and holds no NUL character is read as Windows-1252
(Excel's "CSV" on Western Windows; Latin-1 where that fails), whose digits,
signs and ASCII names read the same. Anything else (UTF-16 without a
byte-order mark, a binary file) is refused, and so is a line longer than
:data:`MAX_LINE_CHARS` characters.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from optitact._validate import check_type
from optitact.errors import InputError, ShapeError
from optitact.io.tables import column_key, csv_numbers, text_rows
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor
from optitact.io.tables import FORCE_UNITS, MASS_UNITS, force_unit

__all__ = ["GAUGE_UNITS", "MAX_GAUGE_FORCE_N", "MAX_LINE_CHARS", "Presses", "check_presses", "frame_of",
           "measure_presses", "read_presses"]

_REFERENCES = ("local", "global")
_COLUMNS = ("frame", "element", "fx", "fy", "fz")
_FORCES = ("fx", "fy", "fz")

#: The units a force column may name in brackets (any case), in N per unit (``optitact.io.tables.FORCE_UNITS``).
GAUGE_UNITS = FORCE_UNITS
#: The largest force component (N) a gauge may give for one element (larger: a unit left out, a typo).
MAX_GAUGE_FORCE_N = 100.0
#: The longest line (characters) a gauge CSV may have (Python's csv module refuses longer fields).
MAX_LINE_CHARS = 131072


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
def frame_of(cell: str, sources: Sequence[str], by_name: dict, path, lineno: int, col: int) -> int | None:
    """The frame a CSV's ``frame`` cell names, or None where it names none.

    A source name (``by_name``: name -> frame indices) or a 0-based index into ``sources``. A name of
    several frames (files of one name in different folders) is refused, naming the line and column.
    """
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
    return None


def _frame_index(cell: str, sources: Sequence[str], by_name: dict, path, lineno: int, col: int) -> int:
    """:func:`frame_of`, with an error naming the frames where it names none."""
    t = frame_of(cell, sources, by_name, path, lineno, col)
    if t is not None:
        return t
    shown = ", ".join(repr(s) for s in sources[:3]) + (", ..." if len(sources) > 3 else "")
    raise InputError(f"{path}, line {lineno}, column {col}: frame {cell!r} is not one of the {len(sources)} "
                     f"frames: name it as the 'source' column of optitact process does ({shown}) or by its "
                     f"0-based index 0..{len(sources) - 1}")


def _unit_factor(cell: str, path, lineno: int, col: int) -> float:
    """N per unit of a force column's header cell (``Fz (mN)`` -> 1e-3; no unit: N), or an error naming it."""
    try:
        return force_unit(cell)
    except InputError as exc:
        raise InputError(f"{path}, line {lineno}, column {col} ({cell!r}): {exc}") from None


def _glued_unit(key: str) -> str | None:
    """``'fz_mn'`` -> ``'fz'`` (a force column with its unit glued to the name), else None."""
    m = re.fullmatch(r"(f[xyz])[\s_/-]+(\w+)", key)
    known = {u.lower() for u in GAUGE_UNITS} | set(MASS_UNITS)
    return m.group(1) if m is not None and m.group(2) in known else None


def _impossible(fx: float, fy: float, fz: float) -> str | None:
    """Why element-local forces (N) cannot be a press, or None: a pull, or a shear with no normal force."""
    if fz < 0:
        return f"Fz = {fz:.6g} N is a pull (no contact), not a press: Fz > 0 presses"
    if fz == 0 and (fx != 0 or fy != 0):
        return (f"a shear of ({fx:.6g}, {fy:.6g}) N with Fz = 0: nothing holds a shear without a normal force "
                f"(a press needs Fz > 0)")
    return None


def _too_large(values) -> str | None:
    """Why force components (N) are beyond :data:`MAX_GAUGE_FORCE_N`, or None."""
    big = [f"{name} = {v:.6g} N" for name, v in zip(("Fx", "Fy", "Fz"), values, strict=True)
           if abs(v) > MAX_GAUGE_FORCE_N]
    if not big:
        return None
    return (f"{', '.join(big)} is beyond the {MAX_GAUGE_FORCE_N:g} N a gauge can put on one element of "
            f"a tactile sensor; if the gauge reads another unit, name it in the header (e.g. 'Fz (mN)')")


def read_presses(path: str | os.PathLike, sources: Sequence[str], sensor: DomeSensor) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    r"""Read a force gauge's CSV: element-local forces per frame and element.

    Parameters
    ----------
    path : path-like
        The CSV (see the module docstring for its columns, units and encodings).
    sources : sequence of str
        The frames' sources in order (:attr:`optitact.pipeline.batch.ProcessedFrames.sources`).
    sensor : DomeSensor

    Returns
    -------
    forces : (T, E, 3) float64 ndarray
        Element-local forces (N, converted from the header's units); 0 where there is no row.
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
        number, a frame listed twice for one element, an unknown
        ``frame_of_reference`` (each message gives the line); an unknown
        unit, two columns of one name; a force a press cannot have (beyond
        :data:`MAX_GAUGE_FORCE_N`, a negative local Fz, a shear without Fz;
        the message names the line, frame and element), Fz = 0 on every row;
        a file that is not UTF-8 or UTF-16 text, a line longer than
        :data:`MAX_LINE_CHARS`.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from optitact.optics.sensor import DomeSensor
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "gauge.csv"
    >>> _ = p.write_text("Frame;Element;Fx (mN);Fy (mN);Fz (mN)\npress_1.png;3;100;0;500\n1;0;0;0;200\n")
    >>> f, pressed = read_presses(p, ["noload.png", "press_1.png"], DomeSensor.default())
    >>> f.shape, f[1, 3].tolist(), f[1, 0].tolist(), int(pressed.sum())
    ((2, 41, 3), [0.1, 0.0, 0.5], [0.0, 0.0, 0.2], 2)
    """
    from optitact.optics.force_frames import local_from_global

    check_type(sensor, DomeSensor, "sensor")
    sources = [str(s) for s in sources]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"force gauge file not found: {path}")
    rows = text_rows(path, what="gauge CSV", max_chars=MAX_LINE_CHARS, columns=_COLUMNS,
                     holds="a frame, an element and three forces")
    if not rows:
        raise ShapeError(f"{path}: empty; expected a header {', '.join(_COLUMNS)} and one row per frame and "
                         f"pressed element")
    header_line, first = rows[0]
    header = [column_key(c) for c in first]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        glued = [(c, _glued_unit(k)) for c, k in zip(first, header, strict=True) if _glued_unit(k) in missing]
        hint = "".join(f"; write {c!r} as '{name.capitalize()} (unit)', the unit in brackets"
                       for c, name in glued[:1])
        raise ShapeError(f"{path}, line {header_line}: no column {', '.join(missing)} in the header {first}; "
                         f"expected the columns {', '.join(_COLUMNS)} (any order, units like 'Fz (N)'), "
                         f"optionally frame_of_reference (local or global){hint}")
    col = {}
    for k in (*_COLUMNS, "frame_of_reference"):
        at = [j for j, h in enumerate(header) if h == k]
        if len(at) > 1:
            raise InputError(f"{path}, line {header_line}: columns {at[0] + 1} ({first[at[0]]!r}) and "
                             f"{at[1] + 1} ({first[at[1]]!r}) both name {k}: which to use is ambiguous; "
                             f"keep one")
        if at:
            col[k] = at[0]
    unit = {k: _unit_factor(first[col[k]], path, header_line, col[k] + 1) for k in _FORCES}
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
        value = [csv_numbers([cells[col[k]]], path, lineno, first_column=col[k] + 1)[0] * unit[k]
                 for k in _FORCES]
        why = _too_large(value)
        if why is not None:
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r}, element {e}: {why}")
        forces[t, e] = value
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
    for (t, e), lineno in line_of.items():
        why = _impossible(*forces[t, e])
        if why is not None:
            seen = " (in the element's frame, converted from global)" if is_global[t, e] else ""
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r}, element {e}: {why}{seen}")
    if not np.any(forces[pressed][:, 2] > 0):
        raise InputError(f"{path}: Fz is 0 on every row: no press to fit or test from; give each press's "
                         f"normal force (in N, or name the unit in the header: 'Fz (mN)')")
    return forces, pressed


# ---------------------------------------------------------------------------- frames -> presses
def measure_presses(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *, pipeline,
                    baseline=None, baseline_frames: int = 1, progress: bool = False) -> Presses:
    """Read frames with ``pipeline`` and the gauge CSV ``forces`` that goes with them.

    Parameters
    ----------
    frames : sequence of path-like
        Image files, folders, ``.npy`` stacks or videos
        (:func:`optitact.io.frames.expand_sources`), read in order.
    forces : path-like
        The gauge CSV (see the module docstring).
    pipeline : Pipeline
    baseline : array_like, optional
        No-load frame(s); else the mean of the first ``baseline_frames``
        frames (which must not be listed in the CSV), as in
        :func:`optitact.pipeline.batch.process_files`.
    baseline_frames : int
    progress : bool

    Raises
    ------
    InputError
        The CSV names a baseline frame as pressed; see also :func:`read_presses`
        and :func:`~optitact.pipeline.batch.process_files`.
    """
    from optitact.pipeline.batch import process_files

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
    """Forces ``(T, E, 3)`` and the pressed mask ``(T, E)`` checked against stack readings.

    Raises
    ------
    TypeError
        ``readings`` are not stack Readings.
    ShapeError
        ``forces`` or ``pressed`` do not match the readings.
    InputError
        A force that is not finite or beyond :data:`MAX_GAUGE_FORCE_N`, or a
        pressed sample a press cannot be (a negative Fz, a shear with Fz = 0);
        the message names the frame (its index) and the element.
    """
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
    big = np.argwhere(np.any(np.abs(f) > MAX_GAUGE_FORCE_N, axis=-1))
    if big.size:
        t, e = big[0]
        raise InputError(f"forces[{t}, {e}] (frame {t}, element {e}): {_too_large(f[t, e])}")
    bad = np.argwhere(pressed & ((f[..., 2] < 0) | ((f[..., 2] == 0) & np.any(f[..., :2] != 0, axis=-1))))
    if bad.size:
        t, e = bad[0]
        raise InputError(f"forces[{t}, {e}] (frame {t}, element {e}): {_impossible(*f[t, e])}")
    return f, pressed
