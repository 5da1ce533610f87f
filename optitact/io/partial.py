"""Output files written whole or named partial: ``.NAME.PID.partial`` files renamed when complete, and a lock.

:class:`~optitact.io.tables.ReadingsWriter` writes its CSV (:class:`PartialCSV`)
and Parquet (:class:`PartialParquet`, the ``columnar`` extra) tables through
them, so a killed run never leaves half a table under the real name. A CSV
is appended to in whole blocks of rows: a write that fails part-way (a full
disk) is cut back, so the file always ends on the last whole frame.
:class:`OutputLock` keeps two runs from writing one output at once, and
:func:`remove_stray_partials` removes what killed runs of an output left.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path

import numpy as np

from optitact._optional import require
from optitact.errors import InputError

__all__ = ["OutputLock", "PartialCSV", "PartialParquet", "keep_earlier_partial", "pid_alive",
           "remove_stray_partials"]


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (True where that cannot be told, e.g. on Windows)."""
    if pid == os.getpid():
        return True
    if sys.platform == "win32" or pid <= 0:  # os.kill(pid, 0) would end the process on Windows
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process (EPERM), or no way to tell
        return True
    return True


def _tmp_name(path: Path, pid: int) -> str:
    return f".{path.name}.{pid}.partial"


def remove_stray_partials(path: Path) -> list[Path]:
    """Remove the ``.NAME.PID.partial`` files beside ``path`` of runs that were killed (``PID`` not alive).

    Returns the files removed. Those of live processes (and of this one) are kept.
    """
    prefix, suffix = f".{path.name}.", ".partial"
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        pid = entry.name[len(prefix):-len(suffix)]
        if (entry.name.startswith(prefix) and entry.name.endswith(suffix) and pid.isdigit()
                and not pid_alive(int(pid))):
            with suppress(OSError):  # gone already, or not ours to remove: nothing is lost by keeping it
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


def keep_earlier_partial(path: Path) -> Path | None:
    """Move aside the rows an earlier run left in a visible partial file, before a new run writes it.

    A stream killed, or stopped by a full disk, leaves its rows in ``NAME.partial.csv``; the next
    run of the same output would start that file afresh. The earlier rows are kept as
    ``NAME.partial.earlier-YYYYmmddTHHMMSS.csv`` (the file's modification time; a counter where
    that name is taken), with an :class:`~optitact.errors.OptitactWarning` naming it. Call it with
    the output's lock held. Returns the new name, or None when there was nothing to keep.
    """
    import warnings

    from optitact.errors import OptitactWarning

    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    if st.st_size == 0:
        return None
    stamp = time.strftime("%Y%m%dT%H%M%S", time.localtime(st.st_mtime))
    for k in range(1000):
        kept = path.with_name(f"{path.stem}.earlier-{stamp}{'' if k == 0 else f'-{k}'}{path.suffix}")
        if not kept.exists():
            break
    os.replace(path, kept)
    warnings.warn(f"{path} held the rows of an earlier run that did not finish: kept as {kept.name}",
                  OptitactWarning, stacklevel=3)
    return kept


def _read_pid(fd: int) -> int | None:
    """The pid a lock file holds (None if it holds none yet)."""
    for _ in range(20):  # the holder writes its pid just after taking the lock
        with suppress(OSError):
            os.lseek(fd, 0, os.SEEK_SET)
            text = os.read(fd, 32).decode("ascii", "replace").strip()
            if text.isdigit():
                return int(text)
        time.sleep(0.01)
    return None


class OutputLock:
    """An exclusive lock on an output's name while a run writes it: the file ``.NAME.lock`` beside it.

    The lock file holds the pid of the run that holds it. The lock is the
    operating system's (``flock``; on Windows a locked byte), released when
    the process ends however it ends, so the file a killed run leaves is taken
    over by the next run. :meth:`release` removes it.

    Parameters
    ----------
    path : Path
        The output file (it need not exist).

    Raises
    ------
    InputError
        Another process holds the lock: the message names its pid.
    OSError
        The lock file cannot be made (a read-only folder): the message names it.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        #: The lock file.
        self.file = self.path.with_name(f".{self.path.name}.lock")
        self._fd: int | None = None
        for _ in range(100):  # a holder may remove the file between our open and our lock: open it again
            try:
                fd = os.open(self.file, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise _named(exc, f"cannot lock {self.path} for writing ({self.file})") from None
            try:
                if not _lock(fd):
                    pid = _read_pid(fd)
                    raise InputError(
                        f"{self.path} is being written by another run (pid {pid if pid else 'unknown'}; "
                        f"its lock is {self.file}): wait for it to end, or write to another file")
                try:
                    same = os.path.samestat(os.fstat(fd), os.stat(self.file))
                except FileNotFoundError:
                    same = False
                if same:
                    os.ftruncate(fd, 0)
                    os.lseek(fd, 0, os.SEEK_SET)
                    os.write(fd, f"{os.getpid()}\n".encode("ascii"))
                    self._fd, fd = fd, None
                    return
            finally:
                if fd is not None:
                    os.close(fd)
        raise InputError(f"{self.path}: could not lock it for writing ({self.file} keeps changing)")

    def release(self) -> None:
        """Remove the lock file and let go of the lock (again: nothing)."""
        if self._fd is None:
            return
        with suppress(OSError):  # the lock is released with the descriptor either way
            if os.path.samestat(os.fstat(self._fd), os.stat(self.file)):
                os.unlink(self.file)
        os.close(self._fd)
        self._fd = None


def _lock(fd: int) -> bool:
    """Take the lock of the open file ``fd`` without waiting; False when another process holds it."""
    try:
        import fcntl
    except ImportError:  # Windows: lock a byte far past the pid, so that the pid stays readable
        import msvcrt

        os.lseek(fd, 1 << 20, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as exc:  # a file system without locks (ENOLCK, EOPNOTSUPP): write as before, and say so
        import warnings

        from optitact.errors import OptitactWarning

        warnings.warn(f"cannot lock the output against other runs here ({exc.strerror}): do not start two "
                      f"runs writing the same file", OptitactWarning, stacklevel=4)
    return True


def _named(exc: OSError, what: str) -> OSError:
    """``exc`` as an OSError whose message starts with ``what`` (the file), with the same errno."""
    named = OSError(f"{what}: {exc.strerror or exc}")
    named.errno = exc.errno
    return named


class PartialCSV:
    """A CSV file written beside ``path`` as ``.NAME.PID.partial`` (or ``tmp``), renamed when complete.

    Each :meth:`write` appends its text whole or not at all: a write that
    fails part-way (a full disk, a file-size limit) is cut back to where it
    began, and the OSError names the file.
    """

    def __init__(self, path: Path, header: Sequence[str], tmp: Path | None = None) -> None:
        self.path = path
        self.tmp = tmp if tmp is not None else path.with_name(_tmp_name(path, os.getpid()))
        #: The name messages give: the visible file rows go to, else the table being written.
        self.shown = self.path if tmp is None else tmp
        #: Bytes written whole so far.
        self.size = 0
        #: Where the rows of an earlier run that did not finish were kept (None: there were none).
        self.kept = keep_earlier_partial(tmp) if tmp is not None else None
        try:
            self.fh = self.tmp.open("wb", buffering=0)
        except OSError as exc:
            raise _named(exc, f"writing {self.shown}") from None
        try:
            self.write(",".join(header) + "\r\n")
        except OSError:
            self.fh.close()
            self.tmp.unlink(missing_ok=True)
            raise

    def write(self, text: str) -> None:
        """Append ``text`` whole; on a failure cut the file back to where it was and raise naming it."""
        data = memoryview(text.encode("utf-8"))
        done = 0
        try:
            while done < len(data):
                done += self.fh.write(data[done:])
        except OSError as exc:
            self.truncate(self.size)
            raise _named(exc, f"writing {self.shown}") from None
        self.size += len(data)

    def truncate(self, size: int) -> None:
        """Cut the file back to ``size`` bytes (the end of an earlier :meth:`write`)."""
        with suppress(OSError):  # shrinking a file needs no space; if it fails, the error raised says why
            self.fh.truncate(size)
            self.fh.seek(size)
            self.size = size

    def flush(self) -> None:
        """Nothing to do: every write goes straight to the operating system."""

    def finish(self, to: Path | None) -> None:
        """Close, then rename to ``to`` (None: delete)."""
        if not self.fh.closed:
            self.fh.close()
        if to is None:
            self.tmp.unlink(missing_ok=True)
        elif self.tmp.exists():
            os.replace(self.tmp, to)


#: Arrow types of the columns of the Parquet tables (the rest are float64).
_PARQUET_TYPES = {"frame": "int64", "source": "string", "element": "int64", "contact": "bool_",
                  "saturated": "bool_", "clamped": "bool_", "n_contact": "int64", "n_clamped": "int64",
                  "wall_time": "string", "drift_flag": "bool_"}


class PartialParquet:
    """A Parquet file written beside ``path`` as ``.NAME.PID.partial`` in row groups, renamed when complete.

    Rows are gathered until ``row_group`` of them make a row group; closing
    writes the last one and the footer (a Parquet file is readable only then:
    the hidden file of a killed run is never one).
    """

    def __init__(self, path: Path, header: Sequence[str], *, row_group: int) -> None:
        pa = require("pyarrow", purpose="Parquet tables (.parquet)")
        pq = require("pyarrow.parquet", purpose="Parquet tables (.parquet)")
        self.path, self.row_group = path, row_group
        self.tmp = path.with_name(_tmp_name(path, os.getpid()))
        self._pa = pa
        self.schema = pa.schema([(name, getattr(pa, _PARQUET_TYPES.get(name, "float64"))()) for name in header])
        self._writer = pq.ParquetWriter(self.tmp, self.schema)
        self._batches: list = []
        self._rows = 0

    def write(self, columns: dict) -> None:
        """Add rows: ``columns`` maps every column name to its values (a source column: ``(names, repeat)``)."""
        batch = self._pa.RecordBatch.from_arrays([self._column(columns[f.name], f.type) for f in self.schema],
                                                 schema=self.schema)
        self._batches.append(batch)
        self._rows += batch.num_rows
        if self._rows >= self.row_group:
            self.flush()

    def _column(self, values, kind):
        """An Arrow array from buffers (``pyarrow.array`` would import pandas: half a second)."""
        pa = self._pa
        if kind == pa.string():
            names, repeat = values
            enc = [str(name).encode("utf-8") for name in names]
            lengths = np.repeat(np.array([len(e) for e in enc], np.int64), repeat)
            offsets = np.zeros(len(lengths) + 1, np.int64)
            np.cumsum(lengths, out=offsets[1:])
            if offsets[-1] >= 2**31:
                raise InputError("source names too long for one Parquet batch")
            data = b"".join(e * repeat for e in enc)
            return pa.Array.from_buffers(kind, len(lengths), [None, pa.py_buffer(offsets.astype(np.int32)),
                                                               pa.py_buffer(data)])
        if kind == pa.bool_():
            flags = np.asarray(values, bool).reshape(-1)
            bits = np.packbits(flags, bitorder="little")
            return pa.Array.from_buffers(kind, len(flags), [None, pa.py_buffer(bits)])
        arr = np.ascontiguousarray(values, dtype=kind.to_pandas_dtype()).reshape(-1)
        return pa.Array.from_buffers(kind, len(arr), [None, pa.py_buffer(arr)])

    def flush(self) -> None:
        """Write the gathered rows as a row group."""
        if self._rows:
            try:
                self._writer.write_table(self._pa.Table.from_batches(self._batches, self.schema),
                                         row_group_size=self._rows)
            except OSError as exc:
                raise _named(exc, f"writing {self.path}") from None
            self._batches, self._rows = [], 0

    def finish(self, to: Path | None) -> None:
        """Close (footer written), then rename to ``to`` (None: delete)."""
        if self._writer is not None:
            try:
                if to is not None:
                    self.flush()
            finally:
                self._writer.close()
                self._writer = None
        if to is None:
            self.tmp.unlink(missing_ok=True)
        elif self.tmp.exists():
            os.replace(self.tmp, to)
