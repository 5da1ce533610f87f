"""CSV tables: per-element tables read by header name, forces tables, and the readings table written.

Reading: :func:`csv_rows` (delimiter sniffed, comments and blank lines
dropped), :func:`read_element_table` (per-element columns found by header
name) and :func:`read_forces_csv`. Writing: :func:`write_forces_csv` and
:class:`ReadingsWriter` (one row per frame and element, and a per-frame
table beside it, complete or kept as :func:`partial_path`). Everything here
is importable from :mod:`optitact.io.files` too.

Forces CSV format: columns ``fx, fy, fz`` (element-local, N) and optionally
``element``. With a header row the columns are found by name, in any order,
whatever their case and a unit in parentheses or brackets (``Fx (N)``); other
columns are ignored. With an ``element`` column any subset of the elements may
be listed, each at most once (the others are unloaded); without one, one row
per element in element order. Without a header the columns are
``fx, fy, fz`` or ``element, fx, fy, fz``. The delimiter is ``,``, ``;`` or tab
(sniffed), a UTF-8 byte-order mark (Excel) is fine, and blank lines and lines
starting with ``#`` are ignored.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from optitact.io.partial import OutputLock, PartialCSV, PartialParquet, remove_stray_partials
from optitact.errors import InputError, ShapeError

__all__ = ["FORCE_UNITS", "MASS_UNITS", "decode_text", "force_unit", "text_rows", "read_forces_csv",
           "write_forces_csv",
           "ReadingsWriter", "read_element_table", "csv_rows",
           "csv_numbers", "column_key", "sniff_delimiter", "partial_path", "per_frame_path",
           "PARQUET_ROW_GROUP", "table_files", "refuse_overwriting_inputs"]

#: Force units a column may name in brackets after its name (``Fz (mN)``; any case), in N per unit.
FORCE_UNITS = {"N": 1.0, "mN": 1e-3, "kN": 1e3, "gf": 9.80665e-3, "kgf": 9.80665, "lbf": 4.4482216152605,
               "ozf": 4.4482216152605 / 16}
#: Mass units a force gauge's display may show, and the force unit meant (refused: say the force).
MASS_UNITS = {"g": "gf", "kg": "kgf", "lb": "lbf", "lbs": "lbf", "oz": "ozf"}
_UNIT = re.compile(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")


def force_unit(cell: str) -> float:
    """N per unit of a force column's header cell: ``"Fz (mN)"`` -> 0.001; no unit: 1.

    Raises
    ------
    InputError
        A unit other than those of :data:`FORCE_UNITS` (any case), named, with the accepted ones
        (a mass such as ``g`` or ``lb`` says which force unit to write; ``MN`` is meganewton).

    Examples
    --------
    >>> force_unit("Fz (mN)"), force_unit("fx [N]"), force_unit("FY"), round(force_unit("Fz (kgf)"), 5)
    (0.001, 1.0, 1.0, 9.80665)
    """
    m = _UNIT.search(cell)
    if m is None:
        return 1.0
    unit = m.group(1)
    accepted = ", ".join(FORCE_UNITS)
    if unit == "MN":
        raise InputError(f"unit 'MN' is meganewton; write mN for millinewton (accepted: {accepted})")
    known = {u.lower(): u for u in FORCE_UNITS} | {"newton": "N", "newtons": "N"}
    if unit.lower() in known:
        return FORCE_UNITS[known[unit.lower()]]
    hint = ""
    if unit.lower() in MASS_UNITS:
        force = MASS_UNITS[unit.lower()]
        hint = f"; {unit!r} is a mass: if the gauge reads {force} (its force), write {force}"
    raise InputError(f"unknown force unit {unit!r}; the accepted units are {accepted} (any case, in brackets "
                     f"after the name: 'Fz (mN)'){hint}")


_HEADERS = (["fx", "fy", "fz"], ["element", "fx", "fy", "fz"])


#: Delimiters a CSV file may use (sniffed): comma, semicolon (Excel in many locales), tab.
CSV_DELIMITERS = ",;\t"


def column_key(name: str) -> str:
    """A CSV header cell as a column name: case-folded, units in ``(...)``/``[...]`` and a BOM dropped.

    Examples
    --------
    >>> column_key("\ufeffFx (N)"), column_key(" fz_global [N] "), column_key("Element")
    ('fx', 'fz_global', 'element')
    """
    key = name.replace("\ufeff", "").strip()
    key = re.sub(r"\s*[\(\[][^\)\]]*[\)\]]\s*$", "", key)
    return key.strip().lower()


def _delimiter_name(d: str) -> str:
    return {",": "',' (comma)", ";": "';' (semicolon)", "\t": "tab"}.get(d, repr(d))


def sniff_delimiter(lines: Sequence[str], path) -> str:
    """The delimiter of CSV ``lines`` among :data:`CSV_DELIMITERS` (``csv.Sniffer``).

    Lines holding none of them (a one-column file) read as comma-separated;
    an InputError naming the candidates and the first line when the sniffer
    cannot tell.
    """
    sample = "\n".join(lines[:50])
    if not any(d in sample for d in CSV_DELIMITERS):
        return ","
    try:
        return csv.Sniffer().sniff(sample, delimiters=CSV_DELIMITERS).delimiter
    except csv.Error:
        raise InputError(
            f"{path}: cannot tell the delimiter of this CSV file (tried ',' (comma), ';' (semicolon) "
            f"and tab; the columns must be separated by one of them on every line); its first line "
            f"reads {lines[0][:80]!r}") from None


def csv_rows(path: str | os.PathLike, delimiter: str | None = None) -> list[tuple[int, list[str]]]:
    """Non-blank, non-comment rows of a CSV file as ``(line number, stripped cells)``.

    The file is UTF-8, with or without a byte-order mark (Excel writes one);
    ``delimiter`` None sniffs it among :data:`CSV_DELIMITERS`
    (:func:`sniff_delimiter`). Lines whose first cell starts with ``#`` are
    comments.
    """
    return _csv_rows(path, delimiter)[0]


def _csv_rows(path, delimiter: str | None = None) -> tuple[list[tuple[int, list[str]]], str]:
    """:func:`csv_rows` and the delimiter used."""
    with Path(path).open(newline="", encoding="utf-8-sig") as fh:
        text = fh.read()
    lines = text.splitlines()
    if delimiter is None:
        content = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
        delimiter = sniff_delimiter(content, path) if content else ","
    rows: list[tuple[int, list[str]]] = []
    for lineno, row in enumerate(csv.reader(lines, delimiter=delimiter), start=1):
        cells = [c.strip() for c in row]
        if not any(cells) or cells[0].startswith("#"):
            continue
        rows.append((lineno, cells))
    return rows, delimiter


def decode_text(path: str | os.PathLike, what: str = "CSV") -> str:
    """The text of a CSV file as spreadsheets write it: UTF-8, UTF-16 with a BOM, else Windows-1252.

    UTF-8 with or without a byte-order mark; Windows-1252 is Excel's "CSV" on Western Windows
    (Latin-1 where that fails).

    Refused (:class:`~optitact.errors.InputError`, naming ``what``): UTF-16 without a byte-order
    mark, a binary file (NUL characters).
    """
    import codecs

    path = Path(path)
    data = path.read_bytes()
    encoding = "utf-16" if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) else "utf-8-sig"
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError as exc:
        if encoding == "utf-16" or b"\x00" in data:
            raise InputError(f"{path}: not a text file in UTF-8 or UTF-16 ({encoding} fails at byte "
                             f"{exc.start}); save the {what} as UTF-8 (Excel: 'CSV UTF-8')") from None
        try:  # Excel's "CSV" on Western Windows; its digits, signs and ASCII names read the same
            text = data.decode("cp1252")
        except UnicodeDecodeError:
            text = data.decode("latin-1")
    if "\x00" in text:
        raise InputError(f"{path}: holds NUL characters: UTF-16 without a byte-order mark, or not a text file; "
                         f"save the {what} as UTF-8 (Excel: 'CSV UTF-8') or UTF-16 with a byte-order mark")
    return text


def text_rows(path: str | os.PathLike, *, what: str, max_chars: int, columns: Sequence[str] = (),
              holds: str = "") -> list[tuple[int, list[str]]]:
    """Non-blank, non-comment rows of a spreadsheet's CSV (:func:`decode_text`) as ``(line, stripped cells)``.

    The delimiter is what :func:`sniff_delimiter` tells; where rows of unequal width leave it unsure,
    the one delimiter whose split of the header holds every name in ``columns``. A line longer than
    ``max_chars`` is refused (``holds``: what a line should hold, for the message).
    """
    path = Path(path)
    lines = decode_text(path, what).splitlines()
    for lineno, line in enumerate(lines, start=1):
        if len(line) > max_chars:
            raise InputError(f"{path}, line {lineno}: {len(line)} characters long, more than the "
                             f"{max_chars} a {what} line may have{f' ({holds})' if holds else ''}; is this "
                             f"the {what}?")
    content = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    try:
        delimiter = sniff_delimiter(content, path) if content else ","
    except InputError:  # csv.Sniffer gives up on rows of unequal width: let the header tell, when it can
        fits = [d for d in ",;\t" if columns and set(columns) <= {
            column_key(c) for c in next(csv.reader([content[0]], delimiter=d))}]
        if len(fits) != 1:
            raise
        delimiter = fits[0]
    reader = csv.reader(lines, delimiter=delimiter)
    rows: list[tuple[int, list[str]]] = []
    try:
        for row in reader:
            cells = [c.strip() for c in row]
            if any(cells) and not cells[0].startswith("#"):
                rows.append((reader.line_num, cells))
    except csv.Error as exc:
        raise InputError(f"{path}, line {reader.line_num + 1}: not a CSV row ({exc})") from None
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


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


_FLAG_CELLS = {"0": False, "1": True, "false": False, "true": True}


def read_element_table(path: str | os.PathLike, n_elements: int, numbers: Sequence[str], *,
                       optional: Sequence[str] = (), flags: Sequence[str] = (),
                       headerless: bool = True, what: str = "forces",
                       empty: bool = False, force_units: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Per-element columns of a CSV file, found by their header names.

    Parameters
    ----------
    path : path-like
        The CSV file: UTF-8 (a byte-order mark is fine), delimited by ``,``,
        ``;`` or tab (sniffed), blank and ``#`` lines ignored.
    n_elements : int
        Elements of the sensor.
    numbers : sequence of str
        Required number columns (e.g. ``fx, fy, fz``).
    optional : sequence of str
        Number columns read when present.
    flags : sequence of str
        0/1 (or true/false) columns read when present.
    headerless : bool
        Allow a file without a header: its columns are then ``numbers`` or
        ``element`` and ``numbers``, in that order.
    what : str
        What the file holds, for messages.
    empty : bool
        Accept a header with an ``element`` column and no row: no element
        listed, all columns 0 (a forces table of no load).
    force_units : sequence of str
        Columns of forces: a unit their header names (``Fz (mN)``, see
        :func:`force_unit`) is converted to N, and an unknown unit refused.

    Returns
    -------
    dict of str to (n_elements,) ndarray
        Every present column (float64, flags bool), in element order; with an
        ``element`` column, elements without a row are 0 (flags False).

    Notes
    -----
    Header cells match column names whatever their case, surrounding blanks
    and a trailing unit in parentheses or brackets (``Fx (N)`` is ``fx``; the
    unit of a ``force_units`` column converts its values to N), in any
    order; other columns are ignored. Without an ``element`` column there
    is one row per element, in element order; with one, any subset of the
    elements in any order (each at most once).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ShapeError
        A missing column, a row of the wrong width, the wrong number of rows.
    InputError
        An unknown delimiter, a cell that is not a finite number or flag (the
        message gives line and column), an element index that does not
        exist or appears twice.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    rows, delim = _csv_rows(path)
    wanted = list(numbers)
    if not rows:
        raise ShapeError(f"{path}: expected {n_elements} rows of {', '.join(wanted)}, got none")
    first = rows[0][1]
    known = {"element", *wanted, *optional, *flags}
    # a header names a known column or holds no number; anything else is a row of data
    data_first = not any(column_key(c) in known for c in first) and any(_is_number(c) for c in first)
    if headerless and data_first:
        if len(first) not in (len(wanted), len(wanted) + 1):
            raise ShapeError(f"{path}, line {rows[0][0]}: expected {len(wanted)} columns "
                             f"({', '.join(wanted)}) or {len(wanted) + 1} (element, {', '.join(wanted)}), "
                             f"got {len(first)}")
        header = wanted if len(first) == len(wanted) else ["element", *wanted]
    else:
        if data_first:
            raise ShapeError(f"{path}, line {rows[0][0]}: no header row; expected one naming the columns "
                             f"{', '.join(wanted)} (any order), optionally element")
        header = [column_key(c) for c in first]
        header_line, rows = rows[0][0], rows[1:]
        twice = sorted({k for k in header if k and header.count(k) > 1})
        if twice:
            raise ShapeError(f"{path}, line {header_line}: the column {twice[0]!r} appears twice in "
                             f"the header")
        missing = [k for k in wanted if k not in header]
        if missing:
            raise ShapeError(
                f"{path}: no column {', '.join(missing)} in the header {first} (read with delimiter "
                f"{_delimiter_name(delim)}); expected the columns {', '.join(wanted)} (any order, case "
                f"and units like 'Fx (N)'), optionally element")
    width = len(header)
    cols = {k: header.index(k) for k in (*wanted, *optional, *flags) if k in header}
    scale = {}
    if not (headerless and data_first):
        for k in force_units:
            if k in cols:
                try:
                    scale[k] = force_unit(first[cols[k]])
                except InputError as exc:
                    raise InputError(f"{path}, line {header_line}, column {cols[k] + 1} "
                                     f"({first[cols[k]]!r}): {exc}") from None
    number_names = [k for k in (*wanted, *optional) if k in cols]
    flag_names = [k for k in flags if k in cols]
    has_element = "element" in header
    if not rows and not (empty and has_element):
        raise ShapeError(f"{path}: expected {n_elements} rows of {', '.join(wanted)}, got none")
    if not has_element and len(rows) != n_elements:
        raise ShapeError(f"{path}: expected {n_elements} rows (one per element), got {len(rows)}")
    out = {k: np.zeros(n_elements) for k in number_names}
    out.update({k: np.zeros(n_elements, bool) for k in flag_names})
    row_of: dict[int, int] = {}
    for i, (lineno, cells) in enumerate(rows):
        if len(cells) != width:
            raise ShapeError(f"{path}, line {lineno}: expected {width} columns, got {len(cells)}")
        if has_element:
            j = header.index("element")
            cell = cells[j]
            try:
                e = float(cell)
            except ValueError:
                e = math.nan
            if not (e.is_integer() and 0 <= e < n_elements):
                raise InputError(f"{path}, line {lineno}, column {j + 1}: element {cell!r} does not exist "
                                 f"(the element column must read 0, 1, ..., {n_elements - 1}, each at "
                                 f"most once)")
            e = int(e)
            if e in row_of:
                raise InputError(f"{path}, line {lineno}: element {e} appears twice (also on line "
                                 f"{row_of[e]}); the element column must read 0, 1, ..., "
                                 f"{n_elements - 1}, each at most once")
            row_of[e] = lineno
        else:
            e = i
        for k in number_names:
            value = csv_numbers([cells[cols[k]]], path, lineno, first_column=cols[k] + 1)[0]
            out[k][e] = value * scale[k] if k in scale else value
        for k in flag_names:
            flag = _FLAG_CELLS.get(cells[cols[k]].lower())
            if flag is None:
                raise InputError(f"{path}, line {lineno}, column {cols[k] + 1} ({k}): expected 0 or 1, "
                                 f"got {cells[cols[k]]!r}")
            out[k][e] = flag
    return out


def read_forces_csv(path: str | os.PathLike, n_elements: int) -> np.ndarray:
    r"""Read element-local forces (N) from a CSV file.

    Parameters
    ----------
    path : path-like
        The CSV file (see the module docstring for the format).
    n_elements : int
        Number of elements of the sensor.

    Returns
    -------
    (n_elements, 3) float64 ndarray
        Elements without a row are 0: a header ``element,fx,fy,fz`` alone is no load.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    InputError
        A cell that is not a finite number (the message gives line and column),
        an element index that does not exist or appears twice, a delimiter
        that cannot be told.
    ShapeError
        Wrong number of rows or columns, a missing column.

    Examples
    --------
    Excel's way (byte-order mark, ``;``, units), one loaded element listed:

    >>> import pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "f.csv"
    >>> _ = p.write_text("\ufeffElement;Fz (N);Fy (N);Fx (N)\n3;0.5;0;0.1\n", encoding="utf-8")
    >>> f = read_forces_csv(p, 41)
    >>> f.shape, f[3].tolist(), float(abs(f).sum() - 0.6) < 1e-12
    ((41, 3), [0.1, 0.0, 0.5], True)
    """
    cols = read_element_table(path, n_elements, _HEADERS[0], empty=True, force_units=_HEADERS[0])
    return np.stack([cols[k] for k in _HEADERS[0]], axis=1)


def write_forces_csv(path: str | os.PathLike, forces: np.ndarray) -> None:
    """Write element-local forces (N, 3) as ``element, fx, fy, fz`` CSV with a header (atomically)."""
    f = np.asarray(forces, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ShapeError(f"forces must have shape (N, 3), got {f.shape}")
    from optitact.io.files import atomic_write  # here, not at the top: optitact.io imports this module

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(_HEADERS[1])
            for i, row in enumerate(f):
                w.writerow([i, *(repr(float(v)) for v in row)])

    atomic_write(path, write)


def _csv_cell(text: str) -> str:
    """``text`` as one CSV cell (quoted as :mod:`csv` does when it holds a delimiter, quote or newline)."""
    if any(ch in text for ch in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def add_to_message(exc: BaseException, text: str) -> None:
    """Append ``text`` to the message of ``exc`` (the one the command line prints), in place."""
    if isinstance(exc, OSError) and exc.strerror:
        exc.strerror += text
    elif len(exc.args) == 1 and isinstance(exc.args[0], str):
        exc.args = (exc.args[0] + text,)
    else:
        exc.add_note(text.strip())


def partial_path(path: str | os.PathLike) -> Path:
    """Where :class:`ReadingsWriter` keeps the rows of a run that failed: ``out.csv`` -> ``out.partial.csv``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def per_frame_path(path: str | os.PathLike) -> Path:
    """The per-frame table beside a forces table: ``out.csv`` -> ``out.per_frame.csv``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.per_frame{path.suffix}")


def table_files(path: str | os.PathLike, *, forces: bool = True) -> dict[str, Path]:
    """The files a :class:`ReadingsWriter` of ``path`` may leave, by role (``forces``: the per-frame ones too).

    Examples
    --------
    >>> [f"{k}: {v}" for k, v in table_files("out.csv").items()]  # doctest: +NORMALIZE_WHITESPACE
    ['table: out.csv', 'partial table: out.partial.csv', 'per-frame table: out.per_frame.csv',
     'partial per-frame table: out.per_frame.partial.csv']
    """
    path = Path(path)
    files = {"table": path, "partial table": partial_path(path)}
    if forces:
        frame = per_frame_path(path)
        files |= {"per-frame table": frame, "partial per-frame table": partial_path(frame)}
    return files


def refuse_overwriting_inputs(outputs: dict[str, Path], inputs) -> None:
    """Refuse to write over an input: InputError when a file of ``outputs`` is one of ``inputs``.

    Parameters
    ----------
    outputs : dict of str to Path
        The files a run may write, keyed by how the message names them (``"--out"``).
    inputs : iterable of path-like
        The files it reads. The same file by another name (a link, ``./``) counts.

    Raises
    ------
    InputError
        Naming the output, the input and what to do.
    """
    written = {}
    for what, path in outputs.items():
        try:
            st = os.stat(path)
        except OSError:  # not there yet: not an input either
            continue
        written[(st.st_dev, st.st_ino)] = (what, path)
    if not written:
        return
    for source in inputs:
        try:
            st = os.stat(source)
        except OSError:
            continue
        hit = written.get((st.st_dev, st.st_ino))
        if hit is not None:
            what, path = hit
            same = "" if os.path.abspath(path) == os.path.abspath(source) else f" (as {source})"
            raise InputError(f"{what} {path} is an input file{same}: writing it would destroy the input; "
                             f"choose another output name")


#: Rows gathered before :class:`ReadingsWriter` writes a Parquet row group.
PARQUET_ROW_GROUP = 65536


def _csv_block(heads: Sequence[str], columns: Sequence[list], n_el: int,
               tails: Sequence[str] | None = None) -> str:
    """CSV rows: ``heads[k]``, cells of ``columns``' rows ``k n_el .. (k+1) n_el - 1`` (numbers), ``tails[k]``.

    One ``repr`` of the whole block: Python writes each float with the
    shortest digits that read back to the same float64, as ``repr(x)`` does,
    without a format call per cell.
    """
    if not n_el or not columns:
        return ""
    rows = list(zip(*columns, strict=True))
    out = []
    for k, head in enumerate(heads):
        tail = tails[k] if tails is not None else ""
        body = repr(rows[k * n_el:(k + 1) * n_el])[2:-2].replace(", ", ",")
        out.append(head + body.replace("),(", tail + "\r\n" + head) + tail + "\r\n")
    return "".join(out)


def _iso_utc(wall: float) -> str:
    """Seconds since the epoch as an ISO 8601 time in UTC, to the microsecond (empty for NaN)."""
    from datetime import datetime, timezone

    if not math.isfinite(wall):
        return ""
    return datetime.fromtimestamp(wall, tz=timezone.utc).isoformat(timespec="microseconds")


class ReadingsWriter:
    """Append readings (and estimated forces) to a CSV or Parquet file, one row per frame and element.

    Columns: ``frame, source, element, G, ux, uy, contact, saturated`` (G in
    grey level x mm^2, u in mm, flags as 0/1; numbers written with the
    shortest digits that read back to the same float64). With ``forces=True``
    also ``fx, fy, fz`` (element-local, N), ``fx_global, fy_global,
    fz_global`` (the force on the element in the sensor frame, N; as
    :meth:`optitact.forces.ForceField.as_dict`) and ``clamped`` (the
    reading was outside the calibration's fitted range: see
    :meth:`optitact.calib.fit.Calibration.forces`), and with
    ``stderr=True`` after those ``fx_se, fy_se, fz_se`` (standard errors of
    the element-local forces, N: :meth:`optitact.calib.fit.Calibration.stderr`);
    and a second table,
    :func:`per_frame_path` (``out.per_frame.csv``), with one row per frame:
    :data:`FRAME_COLUMNS`, i.e. ``frame, source``, the elements in contact and
    clamped, ``total_normal`` (sum of Fz over contact elements, N), the
    resultant force ``resultant_x, resultant_y, resultant_z`` (global, N) and
    the centre of pressure ``centre_of_pressure_x, _y, _z`` (mm, on the outer
    surface; empty when no element carries a normal force), as
    :class:`~optitact.forces.ForceField` computes them. Both tables read with
    ``pandas.read_csv`` as they are. Use as a context manager.

    A ``path`` ending in ``.parquet`` writes Parquet instead (the
    ``columnar`` extra, pyarrow): the same columns and values (flags as
    booleans, the centre of pressure NaN where the CSV leaves it empty),
    written in row groups of :data:`PARQUET_ROW_GROUP` rows as frames come;
    ``pandas.read_parquet`` reads it. For long recordings: about a fifth of
    the CSV's size, and no number formatting.

    With ``times=True`` (a live stream) both tables end with two columns:
    ``time_s``, the seconds from the start of the stream to the capture of
    the frame (a monotonic clock), and ``wall_time``, the same moment on the
    wall clock as an ISO 8601 time in UTC (``2025-01-31T09:15:02.123456+00:00``);
    :meth:`write` needs them then.

    Rows go to a hidden temporary file beside ``path`` (``.NAME.PID.partial``),
    renamed to ``path`` on :meth:`close`: a reader never sees half a table,
    and an existing ``path`` stays as it was until the new table is complete.
    Leaving the ``with`` block by an exception keeps the rows written so far
    as :func:`partial_path` (``out.partial.csv``; nothing when no frame was
    written) and adds where they are to the exception's message; a killed
    process leaves its hidden temporary file and ``path`` untouched. The
    rows of each :meth:`write` go to a CSV file whole: a write that fails
    part-way (a full disk) is cut back, so a partial table ends on the last
    whole frame, and the error names the file. A clean :meth:`close` also
    removes the hidden files that killed runs left for the same ``path``
    (those whose process id no longer runs).

    While a writer is open it holds a lock on ``path`` (the file
    ``.NAME.lock`` beside it, holding the process id; released by
    :meth:`close`, :meth:`discard` or :meth:`keep_partial`, or when the
    process ends however it ends): a second writer of the same ``path``, in
    this process or another, is refused.

    With ``visible=True`` (a live stream, which has no end to wait for) the
    rows go to :func:`partial_path` from the start instead, so that readers
    see them as they come (call :meth:`flush` after each frame); ``close``
    renames them just the same. CSV only.

    Raises
    ------
    MissingExtraError
        A ``.parquet`` path without pyarrow installed.
    InputError
        ``visible=True`` with a ``.parquet`` path; another writer (the
        message names its process id) is writing ``path``.
    OSError
        A file cannot be written (the message names it).
    """

    COLUMNS = ("frame", "source", "element", "G", "ux", "uy", "contact", "saturated")
    FORCE_COLUMNS = ("fx", "fy", "fz", "fx_global", "fy_global", "fz_global", "clamped")
    SE_COLUMNS = ("fx_se", "fy_se", "fz_se")
    FRAME_COLUMNS = ("frame", "source", "n_contact", "n_clamped", "total_normal", "resultant_x",
                     "resultant_y", "resultant_z", "centre_of_pressure_x", "centre_of_pressure_y",
                     "centre_of_pressure_z")

    #: The columns that end both tables with ``times=True``.
    TIME_COLUMNS = ("time_s", "wall_time")

    #: The columns after those with ``drift=True``: the drift tracker's state at the frame
    #: (:class:`optitact.pipeline.drift.DriftState`: light gain, black-level offset in grey levels,
    #: camera shift in pixels, and whether the change exceeds what tracking follows, 0/1).
    DRIFT_COLUMNS = ("drift_gain", "drift_offset", "drift_shift_x", "drift_shift_y", "drift_flag")

    def __init__(self, path: str | os.PathLike, *, forces: bool = False, sensor=None,
                 visible: bool = False, stderr: bool = False, times: bool = False, drift: bool = False) -> None:
        self.path = Path(path)
        #: The tables end with :data:`TIME_COLUMNS`.
        self.with_times = bool(times)
        #: The tables end with :data:`DRIFT_COLUMNS` (after the time columns).
        self.with_drift = bool(drift)
        self.with_forces = forces
        if stderr and not forces:
            raise InputError("stderr=True needs forces=True: the standard errors are of the forces")
        #: The table has the standard-error columns :data:`SE_COLUMNS` (after the force columns).
        self.with_stderr = bool(stderr)
        if forces:
            from optitact.optics.sensor import DomeSensor

            if not isinstance(sensor, DomeSensor):
                raise TypeError(f"a ReadingsWriter with forces needs the sensor (a DomeSensor) for the "
                                f"global forces, got {type(sensor).__name__}")
        self.sensor = sensor
        #: ``"csv"`` or ``"parquet"`` (a path ending in ``.parquet``).
        self.format = "parquet" if self.path.suffix.lower() == ".parquet" else "csv"
        if self.format == "parquet" and visible:
            raise InputError(f"{self.path}: a Parquet table is readable only once complete; write a live "
                             f"stream as CSV")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        times_cols = ((self.TIME_COLUMNS if self.with_times else ())
                      + (self.DRIFT_COLUMNS if self.with_drift else ()))

        def partial(target: Path, header: Sequence[str]):
            if self.format == "parquet":
                return PartialParquet(target, header + times_cols, row_group=PARQUET_ROW_GROUP)
            return PartialCSV(target, header + times_cols, partial_path(target) if visible else None)

        self._lock = OutputLock(self.path)
        self._files = []
        try:
            self._files.append(partial(self.path, self.COLUMNS + (self.FORCE_COLUMNS if forces else ())
                                       + (self.SE_COLUMNS if self.with_stderr else ())))
            if forces:
                self._files.append(partial(per_frame_path(self.path), self.FRAME_COLUMNS))
        except BaseException:
            for f in self._files:
                f.finish(None)
            self._lock.release()
            raise
        if self.format == "csv":
            self._fh = self._files[0].fh
        self.frames = 0

    def flush(self) -> None:
        """Hand the rows written so far to the operating system (they survive a crash of this process)."""
        for f in self._files:
            f.flush()

    @property
    def paths(self) -> list[Path]:
        """The files this writer makes: ``path`` (and :func:`per_frame_path` with forces)."""
        return [f.path for f in self._files]

    def write(self, readings, sources: Sequence[str], forces=None, clamped=None, stderr=None, *,
              time_s: Sequence[float] | None = None, wall_time: Sequence[float] | None = None,
              drift: Sequence | None = None) -> None:
        """Write readings of ``len(sources)`` frames (a stack, or one frame), with forces if kept.

        ``stderr`` (``(T, E, 3)`` or ``(E, 3)`` N) is needed by a writer made with ``stderr=True``;
        ``time_s`` (seconds from the start of the stream) and ``wall_time`` (seconds since the epoch,
        written as ISO 8601 in UTC), one of each per frame, by a writer made with ``times=True``;
        ``drift``, one ``(gain, offset, shift_x, shift_y, flag)`` per frame, by one made with
        ``drift=True``.
        The frames' rows go to each CSV table in one write: if it fails, none of them is written.
        """
        r = readings.as_stack()
        n, n_el = len(r), r.n_elements
        if n != len(sources):
            raise ShapeError(f"got readings of {n} frames for {len(sources)} sources")
        times = None
        if self.with_times:
            if time_s is None or wall_time is None:
                raise ValueError("this writer has time columns: pass time_s and wall_time")
            times = (np.asarray(time_s, np.float64).reshape(-1), np.asarray(wall_time, np.float64).reshape(-1))
            if times[0].size != n or times[1].size != n:
                raise ShapeError(f"time_s and wall_time need one value per frame ({n}), got "
                                 f"{times[0].size} and {times[1].size}")
        states = None
        if self.with_drift:
            if drift is None or len(drift) != n:
                raise ValueError(f"this writer has drift columns: pass drift, one state per frame ({n})")
            states = [(float(g), float(o), float(x), float(y), bool(f)) for g, o, x, y, f in drift]
        cols = {"G": r.G, "ux": r.u[..., 0], "uy": r.u[..., 1], "contact": r.contact, "saturated": r.saturated}
        per_frame = None
        if self.with_forces:
            if forces is None or clamped is None:
                raise ValueError("this writer has force columns: pass forces and clamped")
            from optitact.optics.force_frames import frame_totals

            f = np.asarray(forces, dtype=np.float64).reshape(n, n_el, 3)
            cl = np.asarray(clamped, dtype=bool).reshape(n, n_el)
            tot = frame_totals(self.sensor, f, r.contact)
            gl = tot["global"]
            cols |= {"fx": f[..., 0], "fy": f[..., 1], "fz": f[..., 2], "fx_global": gl[..., 0],
                     "fy_global": gl[..., 1], "fz_global": gl[..., 2], "clamped": cl}
            if self.with_stderr:
                if stderr is None:
                    raise ValueError("this writer has standard-error columns: pass stderr")
                se = np.asarray(stderr, dtype=np.float64)
                if se.size != n * n_el * 3:
                    raise ShapeError(f"stderr must have shape {(n, n_el, 3)}, got {se.shape}")
                se = se.reshape(n, n_el, 3)
                cols |= {k: se[..., i] for i, k in enumerate(self.SE_COLUMNS)}
            res, cop = tot["resultant"], tot["centre_of_pressure"]
            per_frame = {"n_contact": np.asarray(tot["n_contact"], np.int64), "n_clamped": cl.sum(axis=1),
                         "total_normal": np.asarray(tot["total_normal"], np.float64),
                         **{f"resultant_{a}": res[:, i] for i, a in enumerate("xyz")},
                         **{f"centre_of_pressure_{a}": cop[:, i] for i, a in enumerate("xyz")}}
        frame_ids = np.arange(self.frames, self.frames + n)
        if self.format == "parquet":
            extra: dict = {}
            if times is not None:
                walls = [_iso_utc(w) for w in times[1].tolist()]
                cols |= {"time_s": np.repeat(times[0], n_el), "wall_time": (walls, n_el)}
                extra |= {"time_s": times[0], "wall_time": (walls, 1)}
            if states is not None:
                arr = np.array([st[:4] for st in states], np.float64).reshape(n, 4)
                flags = np.array([st[4] for st in states], bool)
                for i, k in enumerate(self.DRIFT_COLUMNS[:4]):
                    cols[k], extra[k] = np.repeat(arr[:, i], n_el), arr[:, i]
                cols["drift_flag"], extra["drift_flag"] = np.repeat(flags, n_el), flags
            names = self._files[0].schema.names
            table = {"frame": np.repeat(frame_ids, n_el), "element": np.tile(np.arange(n_el), n),
                     "source": (sources, n_el)}
            self._files[0].write(table | {k: cols[k] for k in names[3:]})
            if per_frame is not None:
                self._files[1].write({"frame": frame_ids, "source": (sources, 1)} | per_frame | extra)
            self.frames += n
            return
        heads = [f"{self.frames + k},{_csv_cell(src)}," for k, src in enumerate(sources)]
        tails = None if times is None else [f",{t!r},{_iso_utc(w)}"
                                            for t, w in zip(times[0].tolist(), times[1].tolist(), strict=True)]
        if states is not None:
            more = [f",{g!r},{o!r},{x!r},{y!r},{int(f)}" for g, o, x, y, f in states]
            tails = more if tails is None else [a + b for a, b in zip(tails, more, strict=True)]
        names = self.COLUMNS[3:] + (self.FORCE_COLUMNS if self.with_forces else ()) \
            + (self.SE_COLUMNS if self.with_stderr else ())
        columns = [list(range(n_el)) * n]
        for name in names:
            v = cols[name]
            columns.append((v.view(np.uint8) if v.dtype == bool else v).reshape(-1).tolist())
        block = [_csv_block(heads, columns, n_el, tails)]
        if per_frame is not None:
            lines = []
            res, cop = per_frame, tot["centre_of_pressure"].tolist()
            for k, head in enumerate(heads):
                where = ",".join("" if math.isnan(v) else repr(v) for v in cop[k])
                lines.append(f"{head}{int(res['n_contact'][k])},{int(res['n_clamped'][k])},"
                             f"{float(res['total_normal'][k])!r},{float(res['resultant_x'][k])!r},"
                             f"{float(res['resultant_y'][k])!r},{float(res['resultant_z'][k])!r},{where}"
                             f"{tails[k] if tails else ''}\r\n")
            block.append("".join(lines))
        sizes = [f.size for f in self._files]
        for i, text in enumerate(block):
            try:
                self._files[i].write(text)
            except OSError:  # the tables end on the same whole frame: cut back the ones already written
                for f, size in zip(self._files[:i], sizes, strict=False):
                    f.truncate(size)
                raise
        self.frames += n

    def close(self) -> None:
        """Close the files and move them to their paths (again: nothing); remove what killed runs left.

        The hidden ``.NAME.PID.partial`` files of earlier runs of the same tables whose process no
        longer runs are removed; the lock is released.
        """
        try:
            for f in reversed(self._files):  # the main table last: when it is there, both are
                f.finish(f.path)
            for f in self._files:
                remove_stray_partials(f.path)
        finally:
            self._lock.release()

    def discard(self) -> None:
        """Close and delete the rows written so far; ``path`` is left as it was."""
        try:
            for f in self._files:
                f.finish(None)
        finally:
            self._lock.release()

    def keep_partial(self) -> list[Path]:
        """Close and keep the rows written so far as :func:`partial_path` files (none without rows)."""
        if not self.frames:
            self.discard()
            return []
        kept = [partial_path(f.path) for f in self._files]
        try:
            for f, to in zip(self._files, kept, strict=True):
                f.finish(to)
        finally:
            self._lock.release()
        return kept

    def __enter__(self) -> ReadingsWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
            return
        kept = self.keep_partial()
        if kept and exc is not None:
            frames = f"{self.frames} frame{'s were' if self.frames != 1 else ' was'}"
            add_to_message(exc, f" [{frames} written before this error: their rows are "
                                f"in {', '.join(map(str, kept))}, a partial table; "
                                f"{self.path} was not written]")
