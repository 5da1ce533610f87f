"""Output files written beside their name as ``.NAME.PID.partial`` and renamed only when complete.

:class:`~optitact.tables.ReadingsWriter` writes its CSV (:class:`PartialCSV`)
and Parquet (:class:`PartialParquet`, the ``columnar`` extra) tables through
them, so a killed run never leaves half a table under the real name.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._optional import require
from .errors import InputError

__all__ = ["PartialCSV", "PartialParquet"]


class PartialCSV:
    """A CSV file written beside ``path`` as ``.NAME.PID.partial``, renamed when complete."""

    def __init__(self, path: Path, header: Sequence[str], tmp: Path | None = None) -> None:
        self.path = path
        self.tmp = tmp if tmp is not None else path.with_name(f".{path.name}.{os.getpid()}.partial")
        self.fh = self.tmp.open("w", newline="", encoding="utf-8")
        self.fh.write(",".join(header) + "\r\n")

    def write(self, text: str) -> None:
        self.fh.write(text)

    def flush(self) -> None:
        self.fh.flush()

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
                  "saturated": "bool_", "clamped": "bool_", "n_contact": "int64", "n_clamped": "int64"}


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
        self.tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
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
            self._writer.write_table(self._pa.Table.from_batches(self._batches, self.schema),
                                     row_group_size=self._rows)
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
