"""Flight recorder: the last seconds of the loop in a preallocated ring, dumped to CSV in chunks.

`FlightRecorder.record_row` is the hot-path call: one row of floats packed
straight into a preallocated float64 ring with ``struct.pack_into`` (the
fastest allocation-free write measured, see `rakectl.bench.wakeup`). On a fault,
an e-stop or a request the daemon takes a `FlightRecorder.snapshot` (a copy in
time order) and hands it to a `DumpWriter`, whose `DumpWriter.work` writes as
many rows as fit in the tick's slack and returns; the CSV appears under its
final name, atomically renamed from ``<name>.partial``, once every row is out.
"""

from __future__ import annotations

import enum
import os
import struct
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from rakectl.errors import ConfigError, RakeError


class DumpError(RakeError, OSError):
    """Writing a flight-recorder dump failed; the message names the file."""


class DumpReason(enum.Enum):
    """Why a dump was taken (the daemon puts it in the file name)."""

    FAULT = "fault"
    ESTOP = "estop"
    REQUEST = "request"


class FlightRecorder:
    """A ring of the last ``capacity_ticks`` rows of ``columns`` (float64; codes for states)."""

    def __init__(self, columns: tuple[str, ...], capacity_ticks: int) -> None:
        _check_columns(columns)
        if capacity_ticks < 1:
            raise ConfigError(f"FlightRecorder: capacity_ticks must be >= 1, got {capacity_ticks}")
        self.columns = columns
        self.capacity_ticks = capacity_ticks
        self._data = np.zeros((capacity_ticks, len(columns)), dtype=np.float64)
        self._bytes = self._data.data.cast("B")  # the ring's memory, written in place
        self._pack_into = struct.Struct(f"={len(columns)}d").pack_into
        self._row_bytes = 8 * len(columns)
        self._end_bytes = self._row_bytes * capacity_ticks
        self._offset_bytes = 0
        self.rows_recorded = 0

    def record_row(self, values: Sequence[float]) -> None:
        """Write one row (exactly one value per column) over the oldest one."""
        self._pack_into(self._bytes, self._offset_bytes, *values)
        offset_bytes = self._offset_bytes + self._row_bytes
        self._offset_bytes = 0 if offset_bytes == self._end_bytes else offset_bytes
        self.rows_recorded += 1

    def snapshot(self) -> np.ndarray:
        """A copy of the stored rows, oldest first."""
        if self.rows_recorded <= self.capacity_ticks:
            return self._data[: self.rows_recorded].copy()
        split = self._offset_bytes // self._row_bytes
        return np.concatenate((self._data[split:], self._data[:split]))

    def start_dump(self, path: Path, *, durable: bool = False) -> DumpWriter:
        """Snapshot now and return the writer that puts it in ``path`` chunk by chunk."""
        return DumpWriter(self.snapshot(), self.columns, path, durable=durable)


def _check_columns(columns: tuple[str, ...]) -> None:
    if not columns or len(set(columns)) != len(columns):
        raise ConfigError(f"FlightRecorder: columns must be non-empty and unique, got {columns}")
    bad = [name for name in columns if not name or any(c in name for c in ',"\r\n')]
    if bad:
        raise ConfigError(f"FlightRecorder: column names need no CSV quoting, got {bad}")


class DumpWriter:
    """Writes a snapshot to CSV (header = columns) a few rows per `work` call.

    Rows are written ``rows_per_check`` at a time; a call stops when another
    batch, as long as the last one, would end past its budget. Every call
    makes progress (a batch, or the final flush, close and
    rename, which happen in a call of their own unless time is left). Floats
    are written with ``repr``: reading the file back gives the snapshot bit
    for bit. With ``durable`` the file and its directory are
    fsynced before and after the rename; that last call may then take
    milliseconds, so the daemon should only ask for it when stopped.
    """

    def __init__(
        self,
        rows: np.ndarray,
        columns: tuple[str, ...],
        path: Path,
        *,
        durable: bool = False,
        clock_s: Callable[[], float] = time.perf_counter,
        rows_per_check: int = 8,
    ) -> None:
        if rows.ndim != 2 or rows.shape[1] != len(columns):
            raise ConfigError(
                f"DumpWriter: rows of shape {rows.shape} do not fit {len(columns)} columns"
            )
        self.path = path
        self.partial_path = path.with_name(path.name + ".partial")
        self._rows = rows
        self._columns = columns
        self._durable = durable
        self._clock_s = clock_s
        self._batch = max(1, rows_per_check)
        self._row_format = ",".join(["%r"] * len(columns)) + "\n"
        self._file: TextIO | None = None
        self.rows_written = 0
        self.done = False

    def open_now(self) -> None:
        """Create the partial file at once, so that a path it cannot be written to is an
        error of the request (DumpError naming the file), not of the loop later."""
        try:
            self._open()
        except OSError as exc:
            raise DumpError(f"flight-recorder dump {self.path}: cannot create "
                            f"{self.partial_path.name}: {exc.strerror or exc}") from exc

    def work(self, budget_s: float) -> bool:
        """Write for about ``budget_s`` (at least one batch); True once the file is final."""
        if self.done:
            return True
        deadline_s = self._clock_s() + budget_s
        try:
            if self.rows_written < len(self._rows):
                self._write_until(deadline_s)
                if self.rows_written < len(self._rows) or self._clock_s() >= deadline_s:
                    return False
            self._finish()  # a call with no rows left to write always finishes
        except OSError as exc:
            self.abort()
            raise DumpError(f"flight-recorder dump {self.partial_path}: {exc}") from exc
        return self.done

    def _write_until(self, deadline_s: float) -> None:
        """Write batches while the last batch's duration still fits before the deadline."""
        file = self._file if self._file is not None else self._open()
        total, row_format = len(self._rows), self._row_format
        before_s = self._clock_s()
        while self.rows_written < total:
            end = min(total, self.rows_written + self._batch)
            batch = self._rows[self.rows_written : end].tolist()
            file.write("".join(row_format % tuple(row) for row in batch))
            self.rows_written = end
            now_s = self._clock_s()
            if 2.0 * now_s - before_s >= deadline_s:  # another batch would end past it
                return
            before_s = now_s

    def _open(self) -> TextIO:
        # "x": a file already there (another's, or the daemon's own) is never truncated
        self._file = open(self.partial_path, "x", encoding="ascii", newline="")  # noqa: SIM115
        self._file.write(",".join(self._columns) + "\n")
        return self._file

    def _finish(self) -> None:
        file = self._file if self._file is not None else self._open()
        file.flush()
        if self._durable:
            os.fsync(file.fileno())
        file.close()
        self._file = None
        # a file that appeared at the final name while the dump was written is kept (the
        # service's system-call filter refuses link(), which would close the gap between
        # this check and the rename)
        if os.path.lexists(self.path):  # a dangling link too
            self.partial_path.unlink(missing_ok=True)
            raise DumpError(f"flight-recorder dump {self.path}: a file appeared there while "
                            "the dump was written; it is kept, the dump dropped")
        os.replace(self.partial_path, self.path)
        if self._durable:
            _fsync_directory(self.path.parent)
        self.done = True

    def abort(self) -> None:
        """Stop: close and delete the partial file (the final name never appears)."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self.partial_path.unlink(missing_ok=True)


def _fsync_directory(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
