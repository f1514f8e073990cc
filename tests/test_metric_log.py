"""The recorder's metric rows (tflock.metric_log) against metric-by-metric bookkeeping: the columns handed to Rerun,
the metrics that kept one value, and the thinned series the legends are placed on."""

import math

import numpy as np
import pytest

from tflock.metric_log import TRACE_POINTS, MetricRows

NAMES = ("order", "speed", "clusters", "lambda2")


def _rows(seed: int, count: int) -> list[tuple[int, dict[str, float]]]:
    """Rows at steps 0, 1, ...: some complete and in order, some with metrics left out or reordered, with nans, infs
    and float32 values; 'clusters' keeps one value after step 0, 'lambda2' is nan throughout."""
    rng = np.random.default_rng(seed)
    rows = []
    for step in range(count):
        values = {"order": float(rng.random()), "speed": np.float32(rng.normal()), "clusters": 3.0 if step else 1.0,
                  "lambda2": math.nan}
        if step % 7 == 3:
            values["speed"] = math.inf
        if rng.random() < 0.3:
            values.pop(str(rng.choice(NAMES)))
        if rng.random() < 0.2:
            values = dict(reversed(values.items()))
        rows.append((step, values))
    return rows


@pytest.mark.parametrize("seed", [0, 1])
def test_columns_and_constants_match_metric_by_metric_bookkeeping(seed: int) -> None:
    rows = MetricRows(NAMES)
    expected: dict[str, tuple[list[int], list[float]]] = {}
    first: dict[str, float] = {}
    changed: set[str] = set()
    taken: dict[str, tuple[list[int], list[float]]] = {}
    for k, (step, values) in enumerate(_rows(seed, 300)):
        row, present = rows.row(values)
        rows.add(step, row, present)
        for name, value in values.items():
            value = float(value)
            expected.setdefault(name, ([], []))[0].append(step)
            expected[name][1].append(value)
            if name not in changed and step > 0:
                kept = first.setdefault(name, value)
                if kept != value and not (math.isnan(kept) and math.isnan(value)):
                    changed.add(name)
        assert rows.constant() == tuple(n for n in NAMES if n in first and n not in changed)
        if k % 37 == 36 or k == 299:
            for name, steps, column in rows.take_pending():
                taken.setdefault(name, ([], []))[0].extend(steps.tolist())
                taken[name][1].extend(column.tolist())
            assert rows.pending() == 0
    assert set(taken) == set(expected)
    for name, (steps, values) in expected.items():
        assert taken[name][0] == steps
        np.testing.assert_array_equal(taken[name][1], values)  # nan where nan was logged
    assert rows.constant() == ("clusters", "lambda2")
    assert rows.rows == 300


def test_complete_rows_in_order_are_read_as_one_vector() -> None:
    rows = MetricRows(NAMES)
    row, present = rows.row({"order": 0.5, "speed": np.float32(0.1), "clusters": 2, "lambda2": math.nan})
    assert present is None
    np.testing.assert_array_equal(row, [0.5, float(np.float32(0.1)), 2.0, math.nan])
    row, present = rows.row({"speed": 1.0, "order": 0.5})
    assert present.tolist() == [True, True, False, False]
    np.testing.assert_array_equal(row, [0.5, 1.0, math.nan, math.nan])
    with pytest.raises(ValueError, match="unknown metric.s. nope; declared: order, speed, clusters, lambda2"):
        rows.row({"nope": 1.0})


def test_series_are_thinned_evenly_over_the_run() -> None:
    rows = MetricRows(NAMES)
    count = 5 * TRACE_POINTS + 3
    for step in range(count):
        values = {"order": step / count, "speed": -float(step)}
        if step % 3:
            values["clusters"] = 1.0
        rows.add(step, *rows.row(values))
    steps, values = rows.series("order")
    assert TRACE_POINTS // 2 <= len(steps) <= TRACE_POINTS
    gaps = np.diff(steps)
    assert gaps.min() == gaps.max()  # every stride-th row
    assert steps[0] == 0 and steps[-1] >= count - gaps[0]  # the whole run
    np.testing.assert_array_equal(values, steps / count)
    clusters_steps, _ = rows.series("clusters")
    assert len(clusters_steps) > TRACE_POINTS // 4 and all(clusters_steps.astype(int) % 3)  # only where logged
    assert len(rows.series("lambda2")[0]) == 0


def test_extent_is_exact_over_every_row() -> None:
    """Each metric's smallest and largest finite value over every row logged, rows thinned out of the trace
    included; left-out and non-finite values do not count; None before any finite value."""
    rows = MetricRows(["a", "b", "c"])
    assert rows.extent("a") is None
    for step in range(3 * TRACE_POINTS):
        a = 5.0 if step == 3 * TRACE_POINTS - 1 else float(step % 3)  # the last row's a: thinned out of the trace
        row, present = rows.row({"a": a, "b": math.inf if step == 7 else -1.0})
        rows.add(step, row, present)
    assert rows.series("a")[1].max() == 2.0
    assert rows.extent("a") == (0.0, 5.0)
    assert rows.extent("b") == (-1.0, -1.0)
    assert rows.extent("c") is None
