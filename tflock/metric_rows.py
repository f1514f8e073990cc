"""A run's metrics table, kept in bounded memory whatever the run's length.

A run takes one row of metrics every ``log.metrics_every`` steps, for as many steps as it runs (1e6 rows and more
for the papers' steady-state measurements), and :meth:`tflock.simulation.Simulation.metrics` must still give the
whole table. :class:`MetricRows` keeps the rows as float64 in two places:

* a **block** in memory: a fixed NumPy array of about :data:`BLOCK_BYTES` (at least one row), filled row by row;
* a **spill file**: when the block is full, its rows are appended, row-major and raw, to an anonymous temporary
  file (``tempfile.TemporaryFile``: unlinked at creation, so the operating system removes it when the run ends,
  however it ends; it lives in the temporary directory, ``TMPDIR``). The file grows by ``8 * columns`` bytes a row
  (136 bytes for Vicsek's 17 columns: 136 MB for 1e6 rows).

The memory a table holds is then one block, at any length. Reading the table back (:meth:`columns`) first spills
the block, then maps the file (``numpy.memmap``): ``copy=True`` gives each column as a NumPy array of its own (what
the API hands out, O(rows) memory then, on demand); ``copy=False`` gives strided views into the mapping, which a
checkpoint writes in chunks (``numpy.save`` streams non-contiguous arrays through a small buffer) without
allocating the table; the mapped pages are file pages, which the kernel can drop at any time. :meth:`last` reads
the last row alone (a run's summary). Values round-trip exactly (raw float64), so a checkpoint's table and a
resumed run's table are the uninterrupted run's, bit for bit.

This is not the run's metrics table *file* (``<recording>.metrics.csv``, written by the recorder row by row as the
run goes, for people and other programs); a run without a recording has no such file but still a table here.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from typing import IO

import numpy as np

#: bytes of the in-memory block of rows (at least one row): 256 KiB is 1927 rows of Vicsek's 17 columns
BLOCK_BYTES = 256 * 1024


class MetricRows:
    """The rows of a metrics table with the columns `names` (all float64), in bounded memory (see the module)."""

    def __init__(self, names: Sequence[str], block_bytes: int | None = None) -> None:
        """`block_bytes`: the size of the in-memory block (default :data:`BLOCK_BYTES`)."""
        block_bytes = BLOCK_BYTES if block_bytes is None else block_bytes
        self.names = tuple(names)
        self._index = {name: k for k, name in enumerate(self.names)}
        width = max(1, len(self.names))
        self._block = np.empty((max(1, block_bytes // (8 * width)), width), dtype=np.float64)
        self._filled = 0  # rows of the block in use
        self._spilled = 0  # rows in the spill file
        self._file: IO[bytes] | None = None  # created at the first spill

    def __len__(self) -> int:
        return self._spilled + self._filled

    def append(self, values: Mapping[str, float]) -> None:
        """Add a row: each column's value from `values` (a column missing there is nan; other keys are ignored)."""
        if self._filled == len(self._block):
            self._spill()
        row = self._block[self._filled]
        row.fill(np.nan)
        for name, value in values.items():
            k = self._index.get(name)
            if k is not None:
                row[k] = value
        self._filled += 1

    def extend(self, columns: Mapping[str, np.ndarray]) -> None:
        """Add the rows of a table given as columns (a checkpoint's), a block at a time."""
        rows = len(next(iter(columns.values()))) if columns else 0
        for begin in range(0, rows, len(self._block)):
            end = min(rows, begin + len(self._block))
            if self._filled:
                self._spill()
            part = self._block[: end - begin]
            part.fill(np.nan)
            for name, column in columns.items():
                k = self._index.get(name)
                if k is not None:
                    part[:, k] = column[begin:end]
            self._filled = end - begin

    def last(self) -> dict[str, float] | None:
        """The last row (None for an empty table), read without the rest."""
        if self._filled:
            row = self._block[self._filled - 1]
        elif self._spilled:
            assert self._file is not None
            width = self._block.shape[1]
            self._file.seek((self._spilled - 1) * width * 8)
            row = np.frombuffer(self._file.read(width * 8), dtype=np.float64)
        else:
            return None
        return {name: float(row[k]) for k, name in enumerate(self.names)}

    def columns(self, copy: bool = True) -> dict[str, np.ndarray]:
        """The whole table as columns: arrays of their own (`copy`), or read-only strided views into the mapped
        spill file, valid until the next row is added."""
        if not len(self):
            return {name: np.empty(0, dtype=np.float64) for name in self.names}
        self._spill()
        assert self._file is not None
        table = np.memmap(self._file, dtype=np.float64, mode="r", shape=(self._spilled, self._block.shape[1]))
        return {name: np.array(table[:, k]) if copy else table[:, k] for k, name in enumerate(self.names)}

    def _spill(self) -> None:
        """Append the block's rows to the spill file and empty the block."""
        if not self._filled:
            return
        if self._file is None:
            self._file = tempfile.TemporaryFile(prefix="tflock-metrics-")
        self._file.seek(self._spilled * self._block.shape[1] * 8)
        self._file.write(self._block[: self._filled].tobytes())
        self._file.flush()
        self._spilled += self._filled
        self._filled = 0
