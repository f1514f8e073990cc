"""The bounded metrics table (tflock.metric_rows): rows spilled to a temporary file read back exactly, and a
Simulation's table is the same whether it spills or not."""

import numpy as np

from tflock import metric_rows
from tflock.metric_rows import MetricRows


def test_rows_round_trip_through_the_spill_file():
    names = ["step", "a", "b"]
    table = MetricRows(names, block_bytes=3 * 8 * 4)  # 4 rows a block: 10 rows spill twice
    rng = np.random.default_rng(0)
    expected = rng.standard_normal((10, 3))
    for row in expected:
        table.append(dict(zip(names, row, strict=True)))
    assert table._spilled == 8 and table._filled == 2
    assert len(table) == 10
    assert table.last() == dict(zip(names, expected[-1].tolist(), strict=True))
    columns = table.columns()
    for k, name in enumerate(names):
        assert np.array_equal(columns[name], expected[:, k]), name
        assert columns[name].dtype == np.float64
    views = table.columns(copy=False)
    assert all(np.array_equal(views[n], columns[n]) for n in names)
    table.append({"step": 10.0, "a": 1.5, "unknown": 3.0})  # missing: nan, unknown: ignored
    last = table.last()
    assert last["step"] == 10.0 and last["a"] == 1.5 and np.isnan(last["b"])
    assert len(table.columns()["step"]) == 11


def test_extend_and_empty_table():
    empty = MetricRows(["step", "x"], block_bytes=16)
    assert empty.last() is None and [len(c) for c in empty.columns().values()] == [0, 0]
    columns = {"step": np.arange(7.0), "x": np.linspace(0, 1, 7)}
    table = MetricRows(["step", "x"], block_bytes=16 * 3)
    table.append({"step": -1.0, "x": 2.0})
    table.extend(columns)
    out = table.columns()
    assert np.array_equal(out["step"], np.r_[-1.0, columns["step"]])
    assert np.array_equal(out["x"], np.r_[2.0, columns["x"]])
    assert table.last() == {"step": 6.0, "x": 1.0}


def test_simulation_table_is_the_same_when_spilled(make_sim, monkeypatch):
    kept = make_sim(params={"n": 50, "box": 5.0}, steps=30, seed=2)
    kept.run()
    monkeypatch.setattr(metric_rows, "BLOCK_BYTES", 8)  # one row a block: every row goes through the file
    spilled = make_sim(params={"n": 50, "box": 5.0}, steps=30, seed=2)
    spilled.run()
    assert spilled._table._spilled == 30
    a, b = kept.metrics(), spilled.metrics()
    assert list(a) == list(b) and len(a["step"]) == 31
    for name in a:
        assert np.array_equal(a[name], b[name], equal_nan=True), name
    assert spilled.last_metrics() == {name: float(b[name][-1]) for name in b}
