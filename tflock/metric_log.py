"""The recorder's metric rows: each row as one NumPy vector, the rows not yet handed to Rerun, a thinned copy of them
for placing the plots' legends, each metric's smallest and largest value (the plots' fixed ranges), and which
metrics have kept one value.

A run logs one row of every metric at each metrics step (1000s of rows of 10-40 metrics); handling the row as one
vector, not metric by metric in Python, keeps the recorder's share of a small swarm's observation to tens of
microseconds. A metric left out of a row is missing there (not logged, an empty CSV cell), not NaN.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

#: rows kept of the run to place the plots' legends (every other row is dropped when more come)
TRACE_POINTS = 2048


class MetricRows:
    """The rows of the metrics `names` (in that order), as they are logged."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.index = {name: j for j, name in enumerate(self.names)}
        width = len(self.names)
        self.rows = 0
        self._steps: list[int] = []  # rows not yet taken by `take_pending`
        self._values: list[np.ndarray] = []
        self._present: list[np.ndarray | None] = []  # None: every metric present
        self._stride, self._seen = 1, 0  # the trace: every stride-th row
        self._trace_steps: list[int] = []
        self._trace_values: list[np.ndarray] = []
        self._trace_present: list[np.ndarray | None] = []
        self._first = np.full(width, np.nan)  # each metric's first value after step 0
        self._has_first = np.zeros(width, dtype=bool)
        self._changed = np.zeros(width, dtype=bool)
        self._low = np.full(width, np.inf)  # each metric's smallest and largest finite value so far
        self._high = np.full(width, -np.inf)

    def row(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray | None]:
        """`values` as a vector in the order of `names` (NaN where left out) and which are present (None: all).
        A name not among `names` raises ValueError."""
        if len(values) == len(self.names) and tuple(values) == self.names:  # a model's row: every metric, in order
            return np.fromiter(values.values(), np.float64, len(self.names)), None
        unknown = set(values) - self.index.keys()
        if unknown:
            raise ValueError(f"unknown metric(s) {', '.join(sorted(unknown))}; declared: {', '.join(self.names)}")
        row = np.full(len(self.names), np.nan)
        present = np.zeros(len(self.names), dtype=bool)
        for name, value in values.items():
            j = self.index[name]
            row[j] = float(value)
            present[j] = True
        return row, present

    def add(self, step: int, row: np.ndarray, present: np.ndarray | None) -> None:
        """Keep a row (from :meth:`row`) logged at `step`."""
        self.rows += 1
        self._steps.append(step)
        self._values.append(row)
        self._present.append(present)
        if self._seen % self._stride == 0:
            self._trace_steps.append(step)
            self._trace_values.append(row)
            self._trace_present.append(present)
            if len(self._trace_steps) > TRACE_POINTS:
                for kept in (self._trace_steps, self._trace_values, self._trace_present):
                    del kept[1::2]
                self._stride *= 2
        self._seen += 1
        finite = np.isfinite(row)  # (a left-out metric is NaN)
        np.minimum(self._low, row, out=self._low, where=finite)
        np.maximum(self._high, row, out=self._high, where=finite)
        if step > 0:  # step 0 is the state before any step was made
            every = True if present is None else present
            new = every & ~self._has_first
            self._first[new] = row[new]
            self._has_first |= new
            same = (row == self._first) | (np.isnan(row) & np.isnan(self._first))
            self._changed |= every & ~same

    def pending(self) -> int:
        """Rows not yet taken."""
        return len(self._steps)

    def take_pending(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The rows kept since the last call, as one (name, steps, values) column per metric present in any."""
        if not self._steps:
            return []
        steps = np.asarray(self._steps, dtype=np.int64)
        values = np.stack(self._values)
        present = None
        if any(p is not None for p in self._present):
            present = np.stack([np.ones(len(self.names), dtype=bool) if p is None else p for p in self._present])
        self._steps, self._values, self._present = [], [], []
        columns = []
        for j, name in enumerate(self.names):
            if present is None:
                columns.append((name, steps, values[:, j]))
            elif present[:, j].any():
                columns.append((name, steps[present[:, j]], values[present[:, j], j]))
        return columns

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """A thinned copy of one metric's (steps, values) over the run: at most :data:`TRACE_POINTS` rows, evenly
        spaced (every stride-th row), those where the metric is present."""
        if not self._trace_steps:
            return np.zeros(0), np.zeros(0)
        j = self.index[name]
        present = np.array([p is None or p[j] for p in self._trace_present], dtype=bool)
        steps = np.asarray(self._trace_steps, dtype=np.float64)[present]
        values = np.array([v[j] for v in self._trace_values], dtype=np.float64)[present]
        return steps, values

    def extent(self, name: str) -> tuple[float, float] | None:
        """The smallest and largest finite value of one metric over every row so far (None: none yet)."""
        j = self.index[name]
        return (float(self._low[j]), float(self._high[j])) if self._low[j] <= self._high[j] else None

    def constant(self) -> tuple[str, ...]:
        """The metrics logged with one value at every step after step 0 so far (none before a row after step 0)."""
        return tuple(name for j, name in enumerate(self.names) if self._has_first[j] and not self._changed[j])
