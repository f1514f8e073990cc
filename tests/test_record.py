"""Tests for tflock.record: write synthetic recordings, verify them and read them back."""

from __future__ import annotations

import contextlib
import csv
import math
import os
import re
import signal
import socket
import subprocess
import sys
import textwrap
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from tflock.record import (
    FLUSH_NUM_BYTES,
    Frame,
    Recorder,
    WorldSpec,
    batcher_config,
    heading_colors,
    read_recording,
    verify_recording,
)

CONFIG = 'model = "vicsek"\n\n[params]\nn = 40\nnoise = 0.3\nboundary = "periodic"\n'
METRICS = {"order": "polarisation phi", "speed": "mean speed |v|"}
STEPS = 20
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def strict_mode():
    """Make Rerun raise on malformed data instead of warning."""
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def synthetic_frame(rng: np.random.Generator, dim: int, m: int = 40, n_edges: int | None = 30,
                    leader: bool = False) -> Frame:
    pos = rng.random((m, dim), dtype=np.float32) * 10.0
    d = rng.normal(size=(m, dim)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    edges = None
    if n_edges is not None:
        ij = rng.integers(0, m, size=(n_edges, 2))
        edges = pos[ij]  # (E, 2, dim)
    return Frame(positions=pos, directions=d, arrow_length=0.5, edges=edges,
                 leader=pos[0] if leader else None, leader_direction=d[0] if leader else None)


def write_run(path: Path, dim: int, boundary: str, edges: bool, leader: bool) -> dict[str, float]:
    rng = np.random.default_rng(dim)
    last: dict[str, float] = {}
    with Recorder(model="vicsek", config_toml=CONFIG, world=WorldSpec(dim, boundary, 10.0, dt=0.1),
                  metrics=METRICS, path=path, metrics_table=path.with_suffix(".csv")) as rec:
        for step in range(STEPS):
            rec.log_frame(step, synthetic_frame(rng, dim, n_edges=30 if edges else None, leader=leader))
            last = {"order": float(rng.random()), "speed": 1.0 + step}
            rec.log_metrics(step, last)
    return last


@pytest.mark.parametrize(
    ("dim", "boundary", "edges", "leader"),
    [(2, "periodic", True, False), (2, "open", False, True), (3, "reflecting", True, True), (3, "open", False, False)],
)
def test_write_verify_read(tmp_path: Path, dim: int, boundary: str, edges: bool, leader: bool) -> None:
    path = tmp_path / "sub" / "run.rrd"  # the parent directory is created
    last = write_run(path, dim, boundary, edges, leader)

    assert verify_recording(path)
    summary = read_recording(path)
    assert summary.model == "vicsek"
    assert summary.config_toml == CONFIG
    assert summary.frames == STEPS
    assert summary.steps == list(range(STEPS))
    assert summary.last_step == STEPS - 1
    assert summary.metric_rows == STEPS
    assert summary.final_metrics == pytest.approx(last)
    assert summary.metric_descriptions == METRICS
    ents = set(summary.entities)
    assert {"/world/agents", "/world/agents/headings", "/metrics/order", "/metrics/speed", "/config"} <= ents
    assert ("/world/edges" in ents) == edges
    assert ("/world/leader" in ents) == leader
    assert ("/world/bounds" in ents) == (boundary != "open")

    with open(path.with_suffix(".csv"), newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["step", "time", "order", "speed"]
    assert len(rows) == STEPS + 1
    assert [int(r[0]) for r in rows[1:]] == list(range(STEPS))
    assert [float(r[1]) for r in rows[1:]] == [step * 0.1 for step in range(STEPS)]  # step * dt
    assert float(rows[-1][2]) == last["order"]


def test_zero_edges_explicit_colors_and_subset_metrics(tmp_path: Path) -> None:
    path = tmp_path / "zero.rrd"
    rng = np.random.default_rng(1)
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS,
                  path=path, metrics_table=tmp_path / "m.csv") as rec:
        frame = synthetic_frame(rng, 2, m=5, n_edges=0)
        frame.colors = np.full((5, 3), 200, np.uint8)
        rec.log_frame(0, frame)
        rec.log_frame(1, synthetic_frame(rng, 2, m=0, n_edges=0))  # empty frame
        rec.log_metrics(0, {"order": 0.5})  # 'speed' left out: empty cell
        with pytest.raises(ValueError, match="unknown metric"):
            rec.log_metrics(1, {"nope": 1.0})
        with pytest.raises(ValueError, match="positions"):
            rec.log_frame(2, Frame(np.zeros((3, 3), np.float32), np.zeros((3, 3), np.float32), 1.0))
    rec.close()  # idempotent
    assert verify_recording(path)
    summary = read_recording(path)
    assert summary.frames == 2 and "/world/edges" in summary.entities
    assert summary.final_metrics == {"order": 0.5}
    assert (tmp_path / "m.csv").read_text().splitlines() == ["step,time,order,speed", "0,0.0,0.5,"]


def test_metric_rows_sent_as_columns_keep_their_steps_and_times(tmp_path: Path) -> None:
    """Metric rows gathered and handed to Rerun as columns (several batches, a series with gaps) read back with the
    step, the time (step * dt) and the value of each row, including the rows still gathered when the run closes."""
    from tflock.record import METRIC_BATCH_ROWS

    path, dt = tmp_path / "columns.rrd", 0.25
    steps = np.arange(2 * METRIC_BATCH_ROWS + 37)
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0, dt=dt), metrics=METRICS,
                  path=path) as rec:
        for step in steps:
            rec.log_metrics(int(step), {"order": step / 1000.0, **({"speed": -float(step)} if step % 3 else {})})
    batches = _chunks(path)
    for name, kept, value in (("order", steps, steps / 1000.0), ("speed", steps[steps % 3 != 0], -steps)):
        rows = sorted((s, t, v) for b in batches[f"/metrics/{name}"] if "Scalars:scalars" in b.schema.names
                      for s, t, v in zip(b.column("step").to_pylist(), b.column("time").to_pylist(),
                                         b.column("Scalars:scalars").to_pylist(), strict=True))
        assert [r[0] for r in rows] == kept.tolist()
        assert [r[1].total_seconds() for r in rows] == pytest.approx((kept * dt).tolist())
        assert [r[2][0] for r in rows] == pytest.approx(np.asarray(value)[kept].tolist())


def test_metrics_table_only_and_validation(tmp_path: Path) -> None:
    table = tmp_path / "only.csv"
    with Recorder(model="m", config_toml="", world=WorldSpec(3, "open", 2.0), metrics=METRICS,
                  metrics_table=table) as rec:
        assert not rec.enabled
        rec.log_frame(0, synthetic_frame(np.random.default_rng(3), 3))
        rec.log_metrics(0, {"order": 0.25, "speed": 2.0})
    assert table.read_text().splitlines() == ["step,time,order,speed", "0,0.0,0.25,2.0"]
    assert list(tmp_path.iterdir()) == [table]
    with pytest.raises(ValueError, match="metric name"):
        Recorder(model="m", config_toml="", world=WorldSpec(2, "open", 1.0), metrics={"a/b": "x"})
    with pytest.raises(ValueError, match="boundary"):
        WorldSpec(2, "torus", 1.0)
    with pytest.raises(ValueError, match="dim"):
        WorldSpec(4, "open", 1.0)


def test_batcher_sends_big_rows_alone_unless_the_environment_says(monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows of a frame go on as soon as FLUSH_NUM_BYTES are pending; a user's RERUN_FLUSH_NUM_BYTES wins, and
    Rerun's other variables still apply."""
    monkeypatch.delenv("RERUN_FLUSH_NUM_BYTES", raising=False)
    monkeypatch.setenv("RERUN_FLUSH_TICK_SECS", "0.5")
    config = batcher_config()
    assert config is not None
    assert config.flush_num_bytes == FLUSH_NUM_BYTES < rr.ChunkBatcherConfig.DEFAULT().flush_num_bytes
    assert config.flush_tick.total_seconds() == 0.5
    monkeypatch.setenv("RERUN_FLUSH_NUM_BYTES", "4096")
    assert batcher_config() is None


def test_heading_colors() -> None:
    angles = np.array([0.0, 2 * math.pi / 3, 4 * math.pi / 3, -2 * math.pi / 3, math.pi])
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    rgb = heading_colors(d)
    assert rgb.dtype == np.uint8 and rgb.shape == (5, 3)
    assert rgb.tolist() == [[255, 0, 0], [0, 255, 0], [0, 0, 255], [0, 0, 255], [0, 255, 255]]


def test_slow_agents_arrows_are_drawn_long_enough_to_show_their_heading() -> None:
    """An arrow is the velocity relative to the reference speed, `length` per unit, but at least MIN_ARROW of a
    full-speed arrow, along the agent's heading: a Tanner swarm slowed to a tenth of its initial speed drew 2 px stubs.
    An agent at rest draws no arrow; faster agents keep their proportional length."""
    from tflock.frame import MIN_ARROW, drawn_arrows

    d = np.array([[0.1, 0.0], [0.0, -0.05], [0.6, 0.8], [0.0, 0.0], [1.5, 0.0], [0.2, 0.2]], np.float32)
    vectors = drawn_arrows(d, 3.0)
    assert vectors.dtype == np.float32
    np.testing.assert_allclose(vectors[[0, 1, 3, 4]], [[3.0 * MIN_ARROW, 0], [0, -3.0 * MIN_ARROW], [0, 0], [4.5, 0]],
                               rtol=1e-6)
    np.testing.assert_allclose(vectors[2], [1.8, 2.4], rtol=1e-6)  # full speed: unchanged
    np.testing.assert_allclose(np.linalg.norm(vectors[5]), 3.0 * MIN_ARROW, rtol=1e-6)  # heading kept: 45 degrees
    assert vectors[5, 0] == pytest.approx(vectors[5, 1])
    assert d[0, 0] == np.float32(0.1)  # the frame's directions are not changed


def test_open_space_view_keeps_every_drawn_agent_and_arrow_inside_a_margin() -> None:
    """The viewer frames an open-space 2D view on each entity's region of interest, mean +- 2 standard deviations
    per axis (Rerun's RobustBounds): the agents' own cut an outlying agent in half. world/extent's two points must
    have as region the box of every agent and arrow tip, padded by VIEW_MARGIN of the extent (and no wider: a
    region twice too wide left the swarm small in the middle of the view)."""
    from tflock.record import VIEW_MARGIN, view_corners

    rng = np.random.default_rng(3)
    pos = rng.normal(size=(40, 2)).astype(np.float32)
    pos[0] = (9.0, -7.0)  # an outlier the agents' own region of interest leaves out
    vectors = rng.normal(scale=0.1, size=(40, 2)).astype(np.float32)
    corners = view_corners(pos, vectors)
    assert corners.shape == (2, 2) and corners.dtype == np.float32
    mean, sigma = corners.mean(axis=0), corners.std(axis=0)
    low, high = mean - 2 * sigma, mean + 2 * sigma
    points = np.concatenate([pos, pos + vectors])
    extent = points.max(axis=0) - points.min(axis=0)
    pad = VIEW_MARGIN * extent.max()
    np.testing.assert_allclose(low, points.min(axis=0) - pad, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(high, points.max(axis=0) + pad, rtol=1e-5, atol=1e-5)
    agents_mean, agents_sigma = pos.mean(axis=0), pos.std(axis=0)
    assert pos[0, 0] > agents_mean[0] + 2 * agents_sigma[0]  # the agents' region alone would cut it


@pytest.mark.parametrize("bad", ["file", "proc"])
def test_unwritable_path_raises_before_logging(tmp_path: Path, bad: str) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    path = blocker / "run.rrd" if bad == "file" else Path("/proc/tflock-test.rrd")
    with pytest.raises(OSError, match="cannot write the recording"):
        Recorder(model="m", config_toml="", world=WorldSpec(2, "open", 1.0), metrics={}, path=path)


def test_not_a_recording(tmp_path: Path) -> None:
    junk = tmp_path / "junk.rrd"
    junk.write_text("hello")
    with pytest.raises(ValueError, match="cannot read"):
        read_recording(junk)
    assert not verify_recording(junk)
    with pytest.raises(ValueError):
        read_recording(tmp_path / "missing.rrd")
    other = tmp_path / "other.rrd"  # a valid .rrd that tflock did not write
    with rr.RecordingStream("other") as stream:
        stream.save(other)
        stream.log("points", rr.Points2D([[0.0, 0.0]]))
    with pytest.raises(ValueError, match="not a tflock recording"):
        read_recording(other)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display check is Linux-only")
def test_spawn_without_display(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="--spawn needs a display.*`tflock view --live --web`.*--connect"):
        Recorder(model="m", config_toml="", world=WorldSpec(2, "open", 1.0), metrics={}, spawn=True,
                 path=tmp_path / "x.rrd")


#: fake viewers for --spawn (`python -c CODE --port PORT ...`): one that cannot open its window, one that listens and
#: then exits as the viewer does where the graphics driver cannot draw, and one that listens until stopped
FAKE_VIEWERS = {
    "no-window": "import sys; print('\\x1b[31mERROR\\x1b[0m eframe: no window'); "
                 "print('Error: app creation error: no adapter.'); sys.exit(1)",
    "listens-then-exits": "import socket, sys, time; s = socket.socket(); "
                          "s.bind(('127.0.0.1', int(sys.argv[sys.argv.index('--port') + 1]))); s.listen(); "
                          "time.sleep(0.2); print('Error: app creation error: R32Float'); sys.exit(1)",
    "works": "import socket, sys, time; s = socket.socket(); "
             "s.bind(('127.0.0.1', int(sys.argv[sys.argv.index('--port') + 1]))); s.listen(); time.sleep(5)",
}


@pytest.mark.parametrize("viewer", ["no-window", "listens-then-exits"])
def test_spawn_where_the_viewer_cannot_start_is_one_line_and_writes_nothing(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, viewer: str) -> None:
    """A viewer that exits as it starts (a graphics driver it cannot draw with: over ssh -X, or a software
    rasteriser) is reported with its own reason, before any file is made: Rerun's spawn went on, streamed the run to
    nobody and said so only at its end, in its own log lines."""
    import tflock.record as record

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(record, "rerun_executable", lambda: [sys.executable, "-c", FAKE_VIEWERS[viewer]])
    port = _free_port()
    monkeypatch.setattr(record, "SPAWN_PORT", port)
    message = "no adapter" if viewer == "no-window" else "R32Float"
    with pytest.raises(RuntimeError, match=rf"^--spawn: the viewer exited at start: app creation error: {message}; "
                                           r"watch the run in a browser instead: start `tflock view --live --web`"):
        Recorder(model="m", config_toml="", world=WorldSpec(2, "open", 1.0), metrics={}, spawn=True,
                 path=tmp_path / "x.rrd", metrics_table=tmp_path / "x.metrics.csv")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("live", [False, True], ids=["recording", "live"])
def test_a_native_viewer_that_fails_is_reported(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, live: bool) -> None:
    """`tflock view FILE` (or --live) whose viewer exits with an error says so, and names the web viewer, instead
    of returning as if the user had closed it."""
    import tflock.record as record
    from tflock.record import open_viewer

    path = tmp_path / "view.rrd"
    write_run(path, 2, "periodic", edges=False, leader=False)
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(record, "rerun_executable", lambda: [sys.executable, "-c", FAKE_VIEWERS["no-window"]])
    web = "`tflock view --live --web`" if live else "`tflock view --web`"
    with pytest.raises(RuntimeError, match=f"^the viewer exited with code 1 .*{web} serves the web viewer"):
        open_viewer(None if live else path)


def test_spawn_uses_a_viewer_that_listens_and_stays(monkeypatch: pytest.MonkeyPatch) -> None:
    """A viewer that listens and keeps running is the one the run streams to; one already listening is used as it
    is, and none is started beside it."""
    import tflock.record as record
    from tflock.record import _listening, spawn_viewer

    monkeypatch.setattr(record, "rerun_executable", lambda: [sys.executable, "-c", FAKE_VIEWERS["works"]])
    port = _free_port()
    started = time.monotonic()
    log = spawn_viewer(port)
    assert time.monotonic() - started >= record.SPAWN_GRACE_S and _listening(port)
    assert log is not None and log.is_file()  # the new viewer's log
    log.unlink()
    monkeypatch.setattr(record, "rerun_executable", lambda: pytest.fail("a second viewer was started"))
    assert spawn_viewer(port) is None  # already there (the fake viewer exits by itself after 5 s)


#: what a frame draws (the legend's entities, logged once, aside)
FRAME_ENTITIES = ("/world/agents", "/world/edges", "/profiles", "/world/leader", "/world/virtual_agent")
#: the components of a frame that change from step to step (the rest are styles, logged when they change)
PER_STEP = ("positions", "colors", "origins", "vectors", "strips", "values")


def _frame_rows(path: Path) -> dict[tuple[str, int, str], object]:
    """Every (entity, step, component) value of a recording's frames, whatever chunks hold them."""
    from rerun.chunk import RrdReader

    rows = {}
    for chunk in RrdReader(path).stream():
        if not chunk.entity_path.startswith(FRAME_ENTITIES) or not chunk.num_rows:
            continue
        batch = chunk.to_record_batch()
        if "step" not in batch.schema.names:
            continue
        steps = batch.column("step").to_pylist()
        for name in batch.schema.names:
            if ":" in name:
                for step, value in zip(steps, batch.column(name).to_pylist(), strict=True):
                    if value is not None:
                        rows[(chunk.entity_path, step, name)] = value
    return rows


@pytest.mark.parametrize("dim", [2, 3])
def test_gathered_frames_hold_what_frames_logged_one_by_one_hold(tmp_path: Path, monkeypatch, dim: int) -> None:
    """Small frames go to Rerun as columns of many steps (tflock.frame_columns): the recording has the same
    positions, colours, arrows, edges (cleared where a frame draws none) and bar charts at every step as one log
    call per frame writes, and the styles (radii, draw order, edge colour) from the first frame on."""
    import tflock.frame_columns as frame_columns
    import tflock.record as record

    def write(path: Path, gather: int) -> None:
        monkeypatch.setattr(record, "GATHER_AGENTS", gather)
        monkeypatch.setattr(frame_columns, "GATHER_FRAMES", 7)  # sent in several batches
        rng = np.random.default_rng(3)
        with Recorder(model="vicsek", config_toml=CONFIG, world=WorldSpec(dim, "periodic", 10.0, dt=0.5),
                      metrics=METRICS, profiles={"band_profile": "slabs"}, path=path) as rec:
            for step in range(STEPS):
                frame = synthetic_frame(rng, dim, n_edges=None if step in (4, 5, 12) else 3 + step % 4)
                frame.profiles = {"band_profile": rng.random(6)}
                rec.log_frame(step, frame)

    write(tmp_path / "one-by-one.rrd", 0)
    write(tmp_path / "gathered.rrd", 1000)
    one, gathered = _frame_rows(tmp_path / "one-by-one.rrd"), _frame_rows(tmp_path / "gathered.rrd")
    styles = ("radii", "draw_order")
    for (entity, step, name), value in one.items():
        if name.endswith(styles) or (entity == "/world/edges" and name.endswith("colors")):
            assert gathered[(entity, 0, name)] == value  # logged once, at the first frame
        else:
            assert gathered[(entity, step, name)] == value, (entity, step, name)
    points = {(e, s) for e, s, n in gathered if n.endswith("positions") and e == "/world/agents"}
    assert len(points) == STEPS
    assert gathered[("/world/edges", 4, f"LineStrips{dim}D:strips")] == []  # no edges: the last ones cleared
    summary = read_recording(tmp_path / "gathered.rrd")
    assert summary.steps == list(range(STEPS))


@pytest.mark.parametrize("model, params", [
    ("vicsek", {"n": 60, "box": 5.0}),
    ("vicsek", {"n": 60, "box": 5.0, "async_bound": 3, "leader": {"enabled": True}}),
    ("potential", {"n": 40}),
    ("formation", {}),
    ("adaptive", {"n": 60, "dim": 3, "box": 4.0}),
])
def test_every_model_records_the_same_frames_gathered(tmp_path: Path, monkeypatch, cpu_engine, model: str,
                                                      params: dict) -> None:
    """The models' own frames (arrays a step may write in place, host views) recorded through the gathered
    columns hold, at every step, what logging each frame at once holds: no frame's arrays change after it is
    handed over. The leader and the virtual agent (its point, heading and circle) too, their styles (colours,
    radii, labels, draw order) logged once, at the first frame."""
    import tflock
    import tflock.record as record

    def run(path: Path, gather: int) -> None:
        monkeypatch.setattr(record, "GATHER_AGENTS", gather)
        sim = tflock.Simulation(model=model, params=params, steps=12, log={"every": 1}, record=path,
                                engine={"precision": cpu_engine.precision})
        sim.run()
        sim.close()

    run(tmp_path / "one-by-one.rrd", 0)
    run(tmp_path / "gathered.rrd", 10**6)
    one, gathered = _frame_rows(tmp_path / "one-by-one.rrd"), _frame_rows(tmp_path / "gathered.rrd")
    shapes = ("/world/leader", "/world/virtual_agent")

    def style(entity: str, name: str) -> bool:
        if entity.startswith(shapes):
            return not name.endswith(PER_STEP) or name.endswith("colors")
        return name.endswith(("radii", "draw_order")) or (entity == "/world/edges" and name.endswith("colors"))

    per_step = {k: v for k, v in one.items() if not style(k[0], k[2])}
    assert per_step and all(gathered.get(k) == v for k, v in per_step.items())
    styles = {(e, n): v for (e, t, n), v in one.items() if style(e, n)}
    assert all(gathered[(e, 0, n)] == v for (e, n), v in styles.items())  # the same at every step: logged once
    expected = set()
    if "leader" in params:
        expected = {"/world/leader", "/world/leader/heading"}
    elif model == "formation":
        expected = {"/world/virtual_agent", "/world/virtual_agent/heading", "/world/virtual_agent/range"}
    assert {e for e, t, n in one if e.startswith(shapes)} == expected
    positions = [one[("/world/agents", t, n)] for (e, t, n) in sorted(one) if e == "/world/agents"
                 and n.endswith("positions")]
    assert len(positions) == 13 and positions[0] != positions[-1]


CHILD = textwrap.dedent(
    """
    import signal, sys
    import numpy as np
    from tflock.record import Frame, Recorder, WorldSpec
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rng = np.random.default_rng(0)
    rec = Recorder(model="vicsek", config_toml="a = 1\\n", world=WorldSpec(2, "periodic", 10.0),
                   metrics={"order": "phi"}, path=sys.argv[1])
    try:
        step = 0
        while True:
            pos = rng.random((200, 2), dtype=np.float32) * 10
            rec.log_frame(step, Frame(pos, np.ones((200, 2), np.float32), 0.5, edges=pos[:100].reshape(50, 2, 2)))
            rec.log_metrics(step, {"order": 0.5})
            step += 1
            if step == 5:
                print("ready", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        rec.close()
        print(step, flush=True)
    """
)


def test_interrupted_run_is_complete(tmp_path: Path) -> None:
    """SIGTERM (mapped to KeyboardInterrupt) and SIGINT both leave a finalised file (two children in parallel)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    runs = {}
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            path = tmp_path / f"interrupted-{sig.name}.rrd"
            runs[sig] = (path, subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE,
                                                text=True, env=env))
        for sig, (_, child) in runs.items():
            assert child.stdout is not None
            assert child.stdout.readline().strip() == "ready"
            time.sleep(0.2)
            child.send_signal(sig)
        logged = {}
        for sig, (_, child) in runs.items():
            assert child.wait(timeout=15) == 0
            logged[sig] = int(child.stdout.read().split()[-1])  # steps begun; the last may be half logged
    finally:
        for _, child in runs.values():
            if child.poll() is None:
                child.kill()
    for sig, (path, _) in runs.items():
        assert verify_recording(path), path
        summary = read_recording(path)
        assert summary.frames >= 5
        assert summary.steps[:logged[sig]] == list(range(logged[sig]))  # every frame drawn, gathered ones too
        assert summary.frames in (logged[sig], logged[sig] + 1)
        assert summary.metric_rows >= 5


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listens on port {port}")


@contextlib.contextmanager
def _receiver(saved: Path) -> Iterator[str]:
    """A Rerun viewer process that saves what it receives in `saved`, while the block runs: the URL to stream to."""
    from tflock.record import rerun_executable

    port = _free_port()
    receiver = subprocess.Popen([*rerun_executable(), "--port", str(port), "--save", str(saved)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for_port(port)
        yield f"rerun+http://127.0.0.1:{port}/proxy"
    finally:
        receiver.send_signal(signal.SIGINT)
        try:
            receiver.wait(timeout=5)
        except subprocess.TimeoutExpired:
            receiver.kill()


def test_tee_file_and_grpc(tmp_path: Path) -> None:
    """`connect` streams to a running receiver while the file sink still gets everything."""
    received = tmp_path / "received.rrd"
    with _receiver(received) as url:
        path = tmp_path / "tee.rrd"
        rng = np.random.default_rng(2)
        with Recorder(model="vicsek", config_toml=CONFIG, world=WorldSpec(2, "periodic", 10.0), metrics=METRICS,
                      path=path, connect=url) as rec:
            for step in range(5):
                rec.log_frame(step, synthetic_frame(rng, 2))
                rec.log_metrics(step, {"order": 0.1, "speed": 1.0})
        assert read_recording(path).frames == 5
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                if read_recording(received).frames == 5:
                    break
            except ValueError:
                pass
            time.sleep(0.2)
        assert read_recording(received).frames == 5


def _outward_address() -> str | None:
    """The IPv4 address this machine would reach other machines from (no packet is sent), or None where it has
    only the loopback."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        try:
            udp.connect(("10.255.255.255", 1))
        except OSError:
            return None
        address = udp.getsockname()[0]
    return None if address.startswith("127.") else address


def test_open_viewer_web(tmp_path: Path) -> None:
    """`open_viewer(web=True)` serves the web viewer until interrupted, on 127.0.0.1 only (Rerun's default binds
    every interface); the one address it prints is not buried under Rerun's info log (colour codes, an address of
    its own)."""
    path = tmp_path / "view.rrd"
    write_run(path, 2, "periodic", edges=True, leader=False)
    web, grpc = _free_port(), _free_port()
    code = (
        "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "from tflock.record import open_viewer\n"
        f"open_viewer(sys.argv[1], web=True, port={web}, grpc_port={grpc})\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    env.pop("RUST_LOG", None)
    child = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True, env=env,
                             stderr=subprocess.PIPE, start_new_session=True)  # (its viewer too: killed as a group)
    try:
        assert child.stdout is not None
        line = child.stdout.readline()
        assert f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy" in line
        _wait_for_port(web)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=5) as resp:
            assert resp.status == 200
        outward = _outward_address()  # this machine's address towards other machines: both ports closed there
        if outward is not None:
            for port in (web, grpc):
                with socket.socket() as probe:
                    assert probe.connect_ex((outward, port)) != 0, (outward, port)
        child.send_signal(signal.SIGINT)
        _, log = child.communicate(timeout=10)
        assert child.returncode == 0
        assert "INFO" not in log and "Hosting a web-viewer" not in log, log[:500]
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)  # a failed test leaves no rerun server behind
            child.wait()


def test_view_live_shows_the_runs_streamed_to_it(tmp_path: Path) -> None:
    """`tflock view --live --web` serves an empty web viewer and prints the URL a run streams to; a run that streams
    there (`tflock sim --connect URL`) reaches it: a second client of the viewer's server receives the run's frames."""
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "from tflock.cli import app\napp()\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    child = subprocess.Popen([sys.executable, "-c", code, "view", "--live", "--web"], stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True, env=env, start_new_session=True)
    saver = None
    try:
        assert child.stdout is not None
        assert "Web viewer: http://127.0.0.1:" in child.stdout.readline()
        line = child.stdout.readline()
        assert line.startswith("Stream a run to it: tflock sim --connect rerun+http://127.0.0.1:"), line
        url = line.split()[-1]
        _wait_for_port(int(url.rsplit(":", 1)[1].split("/")[0]))
        rng = np.random.default_rng(3)
        with Recorder(model="vicsek", config_toml=CONFIG, world=WorldSpec(2, "periodic", 10.0), metrics=METRICS,
                      connect=url) as rec:
            for step in range(3):
                rec.log_frame(step, synthetic_frame(rng, 2))
                rec.log_metrics(step, {"order": 0.1, "speed": 1.0})
        from tflock.record import rerun_executable

        got = tmp_path / "got.rrd"
        saver = subprocess.Popen([*rerun_executable(), "--connect", url, "--save", str(got)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 20
        frames = 0
        while time.monotonic() < deadline and frames < 3:
            with contextlib.suppress(ValueError, OSError):
                frames = read_recording(got).frames
            time.sleep(0.2)
        assert frames == 3
        assert child.poll() is None  # serving until stopped
        child.send_signal(signal.SIGINT)
        assert child.wait(timeout=10) == 0
    finally:
        if saver is not None:
            saver.kill()
            saver.wait()
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
        child.wait()


def test_markers_are_drawn_on_their_own_entities(tmp_path: Path) -> None:
    from tflock.record import Marker

    path = tmp_path / "markers.rrd"
    rr.set_strict_mode(True)
    rec = Recorder(model="m", config_toml="a = 1\n", world=WorldSpec(2, "open", 10.0), metrics={}, path=path)
    for step in range(3):
        rec.log_frame(step, Frame(positions=np.zeros((4, 2), np.float32), directions=np.ones((4, 2), np.float32),
                                  arrow_length=1.0, markers=[Marker("virtual_agent", np.array([step, 0.0]),
                                                                    direction=np.array([-1.0, 0.0]),
                                                                    circle=25.0)]))
    rec.close()
    summary = read_recording(path)
    for entity in ("/world/virtual_agent", "/world/virtual_agent/heading", "/world/virtual_agent/range"):
        assert entity in summary.entities


def _chunks(path: Path) -> dict[str, list]:
    """Record batches of each entity of a recording (blueprint excluded)."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        if chunk.num_rows and not chunk.entity_path.startswith("/__"):
            out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def _last(batches: list, column: str) -> object:
    """The value of `column` in the row with the highest step (static rows count as step -1)."""
    best, value = None, None
    for batch in batches:
        if column not in batch.schema.names:
            continue
        steps = batch.column("step").to_pylist() if "step" in batch.schema.names else [-1] * batch.num_rows
        for s, v in zip(steps, batch.column(column).to_pylist(), strict=True):
            if v is not None and (best is None or s >= best):
                best, value = s, v
    return value


def test_simulation_recording_content(make_sim, tmp_path: Path) -> None:
    """What a person sees, read back from a run's file: drawn agents with their ids, edges among drawn agents only,
    the field of all agents (its pixels' total is N and it equals the NumPy reference of the final state), the
    y-flip, the legend, the layout's grouped plots and the trails."""
    from tflock.field import reference_field
    from tflock.record import point_radius

    path = tmp_path / "run.rrd"
    n, box = 3000, 30.0
    sim = make_sim(model="vicsek", params={"n": n, "box": box, "radius": 1.5}, steps=6, record=path,
                   log={"max_agents": 600, "max_edges": 150, "field": 16, "trail": 4})
    sim.run()
    selected, state, cells = sim._selected, sim.state(), sim.model.grid.geometry
    sim.close()
    assert verify_recording(path)
    summary = read_recording(path)
    assert summary.frames == 7
    batches = _chunks(path)
    pos = np.array(_last(batches["/world/agents"], "Points2D:positions"))
    np.testing.assert_allclose(pos, state["x"][selected], atol=1e-4)
    assert _last(batches["/world/agents"], "Points2D:labels") == [f"agent {i}" for i in selected]
    assert _last(batches["/world/agents"], "Points2D:radii") == pytest.approx([-point_radius(600)])  # UI points
    # edges: between drawn agents only (the far end up to the periodic box), at most the cap
    strips = _last(batches["/world/edges"], "LineStrips2D:strips")
    assert 0 < len(strips) <= 150
    for start, end in (np.array(s) for s in strips):
        assert np.min(np.linalg.norm(pos - start, axis=1)) < 1e-4
        gap = pos - end
        gap -= box * np.round(gap / box)
        assert np.min(np.linalg.norm(gap, axis=1)) < 1e-4
        assert np.linalg.norm(end - start) <= 1.5 + 1e-4
    # the field: every agent in it, the reference's classes from the final state
    field = batches["/world/field"]
    assert _last(field, "agents") == [n]
    (image,) = _last(field, "SegmentationImage:buffer")  # one image a row
    (fmt,) = _last(field, "SegmentationImage:format")
    classes = np.asarray(image, dtype=np.uint8).reshape(fmt["height"], fmt["width"])
    # pixels of whole cells of the model's grid: 20 cells of 1.5 a side, 2 x 2 a pixel for at most 16 pixels
    assert cells.cells_per_side == 20
    expected, counts = reference_field(state["x"], state["theta"], np.zeros(2), cells.cell_size, 20, k=2)
    assert counts.sum() == n
    np.testing.assert_array_equal(classes, expected[0])
    assert _last(field, "Transform3D:scale") == [pytest.approx([3.0, 3.0, 1.0])]
    assert len(_last(field, "AnnotationContext:context")[0]) == 241  # a colour and label per class
    # y up, the legend, trails, the about document
    assert _last(batches["/world"], "Transform3D:scale") == [[1.0, -1.0, 1.0]]
    assert "/legend/wheel" in batches and "/legend/field" in batches
    trails = _last(batches["/world/agents/trails"], "LineStrips2D:strips")
    assert len(trails) == 600 and all(len(t) == 4 for t in trails)
    (about,) = _last(batches["/about"], "TextDocument:text")
    assert "- **neighbors**, 2 series:\n  - mean (`mean_neighbors`): " in about and "field" in about
    assert "|" not in about.replace("\\|", "")  # no table: the viewer cuts a table's cells at the view's edge


def test_metric_groups_and_constant_series(tmp_path: Path) -> None:
    from tflock.record import metric_groups

    names = ["speed_mean", "speed_spread", "valency_min", "valency_max", "valency_0", "valency_1", "mean_neighbors",
             "max_neighbors", "kinetic_energy", "potential_energy", "connected", "mean_heading"]
    groups = metric_groups(names)
    assert groups == {
        "speed_mean": [("speed_mean", "speed_mean")],
        "speed_spread": [("speed_spread", "speed_spread")],
        "valency": [("valency_min", "min"), ("valency_max", "max"), ("valency_0", "agent 0"),
                    ("valency_1", "agent 1")],
        "neighbors": [("mean_neighbors", "mean"), ("max_neighbors", "max")],
        "energy": [("kinetic_energy", "kinetic"), ("potential_energy", "potential")],
        "connected": [("connected", "connected")],
        "mean_heading": [("mean_heading", "mean_heading")],
    }
    # indices that are no agent ids are named by what they are: gnf_std_<m> is a box of side L/m
    assert metric_groups(["gnf_exponent", "gnf_std_4", "gnf_std_8", "gnf_std_16"]) == {
        "gnf_exponent": [("gnf_exponent", "gnf_exponent")],
        "gnf_std": [("gnf_std_4", "box L/4"), ("gnf_std_8", "box L/8"), ("gnf_std_16", "box L/16")],
    }
    path = tmp_path / "constant.rrd"
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS, path=path) as rec:
        for step in range(3):
            rec.log_metrics(step, {"order": 0.5, "speed": float(step)})
        assert rec.constant_metrics() == ("order",)
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    layouts = [" ".join(str(c.to_record_batch().to_pylist()) for c in reader.stream(store=store))
               for store in reader.blueprints()]
    # the layout is sent again at the end, with the constant series apart
    assert len(layouts) == 2 and sorted("constant: order" in text for text in layouts) == [False, True]


#: (model, params, reference speed's parameter) of the read-back test of every model's content; small N, few steps
MODEL_CASES = [
    ("adaptive", {"n": 1500, "dim": 3, "box": 8.0, "radius": 1.0}, "speed"),
    ("potential", {"n": 1500, "box": 40.0, "dt": 0.05, "topology": "fixed", "graph": "ring"}, "speed"),
    ("formation", {"n": 300, "init_length": 60.0, "init_width": 40.0}, "out_speed"),
]


@pytest.mark.parametrize(("model", "params", "speed_name"), MODEL_CASES, ids=[c[0] for c in MODEL_CASES])
def test_every_models_recording_content(make_sim, tmp_path: Path, model: str, params: dict, speed_name: str) -> None:
    """Read back from each model's file what a person sees: the drawn agents with their ids and UI-point sizes,
    arrows of the move just made relative to the reference speed (the one convention), edges joining drawn agents
    only (potential's fixed graph: edges of that graph), and the field of all agents: one image in 2D, three
    projections in 3D, each of all N agents."""
    from tflock.frame import MIN_ARROW, arrow_length
    from tflock.record import point_radius

    path = tmp_path / f"{model}.rrd"
    steps, drawn_count = 4, 200
    sim = make_sim(model=model, params=params, steps=steps, record=path,
                   log={"max_agents": drawn_count, "max_edges": 400, "field": 32})
    sim.step(steps - 1)
    before = sim.model.state()["x"].astype(np.float64)
    sim.step(1)
    selected, state, world, p = sim._selected, sim.model.state(), sim.model.world(), sim.model.params
    sim.close()
    assert verify_recording(path)
    assert read_recording(path).steps == list(range(steps + 1))
    dim, n = world.dim, p.n
    kind = "Points2D" if dim == 2 else "Points3D"
    batches = _chunks(path)
    agents = batches["/world/agents"]
    pos = np.array(_last(agents, f"{kind}:positions"))
    expected_pos = state["x"][selected].astype(np.float64)
    if world.centred_on:  # formation: the torus drawn centred on the virtual agent
        expected_pos = np.mod(expected_pos - (sim.model.va_position() - world.box / 2), world.box)
        va = np.array(_last(batches["/world/virtual_agent"], "Points2D:positions"))
        np.testing.assert_allclose(va, [[world.box / 2] * 2])
    np.testing.assert_allclose(pos, expected_pos, atol=1e-4)
    assert len(selected) == drawn_count and np.ptp(selected) > n // 2  # a sample spread over all ids
    assert _last(agents, f"{kind}:labels") == [f"agent {i}" for i in selected]
    assert _last(agents, f"{kind}:radii") == pytest.approx([-point_radius(drawn_count)])  # UI points

    # arrows: (x(t) - x(t - 1)) / dt over the reference speed, arrow_length long per unit of it
    arrows = "Arrows2D" if dim == 2 else "Arrows3D"
    vectors = np.array(_last(batches["/world/agents/headings"], f"{arrows}:vectors"))
    moved = state["x"][selected].astype(np.float64) - before[selected]
    if world.boundary == "periodic":
        moved -= world.box * np.round(moved / world.box)
    length = arrow_length(world.box, drawn_count, dim, spread=pos if world.boundary == "open" else None)
    assert _last(batches["/world/agents/headings"], "arrow_length") == pytest.approx([length])
    expected = moved / world.dt / getattr(p, speed_name) * length
    norm = np.linalg.norm(expected, axis=1, keepdims=True)  # a slow agent's arrow drawn MIN_ARROW long at least
    expected *= np.where(norm > 0, np.maximum(norm, MIN_ARROW * length) / np.maximum(norm, 1e-30), 0.0)
    np.testing.assert_allclose(vectors, expected, atol=2e-3 * length)
    assert np.max(np.linalg.norm(vectors, axis=1)) > 0.3 * length  # drawn, not vanishing
    if world.boundary == "open" and dim == 2:  # the view's frame: every drawn agent and arrow tip inside
        corners = np.array(_last(batches["/world/extent"], "Points2D:positions"))
        low, high = corners.mean(axis=0) - 2 * corners.std(axis=0), corners.mean(axis=0) + 2 * corners.std(axis=0)
        inside = np.concatenate([pos, pos + vectors])
        assert np.all(inside > low) and np.all(inside < high)
    else:
        assert "/world/extent" not in batches

    # edges: both ends are drawn agents (the far end up to the periodic box), at most the cap
    strips = np.array(_last(batches["/world/edges"], f"LineStrips{dim}D:strips"))
    assert 0 < len(strips) <= 400

    def row_of(point: np.ndarray) -> int:
        gap = pos - point
        if world.boundary == "periodic":
            gap -= world.box * np.round(gap / world.box)
        row = int(np.argmin(np.linalg.norm(gap, axis=1)))
        assert np.linalg.norm(gap[row]) < 1e-3, "an edge end that is no drawn agent"
        return row

    pairs = {tuple(sorted((int(selected[row_of(a)]), int(selected[row_of(b)])))) for a, b in strips}
    assert len(pairs) == len(strips)  # each edge once
    if model == "potential":
        graph = {tuple(sorted(e)) for e in sim.model.edges.tolist()}
        assert pairs <= graph
    else:
        assert np.max(np.linalg.norm(strips[:, 1] - strips[:, 0], axis=1)) <= p.radius + 1e-3

    # the field of all agents: every agent binned, in each projection
    if dim == 2:
        images = {"xy": batches["/world/field"]}
    else:
        images = {plane: batches[f"/field/{plane}"] for plane in ("xy", "xz", "yz")}
    for plane, field in images.items():
        assert _last(field, "agents") == [n], plane
        (fmt,) = _last(field, "SegmentationImage:format")
        assert 0 < fmt["width"] <= 32 and 0 < fmt["height"] <= 32
        (image,) = _last(field, "SegmentationImage:buffer")
        assert np.count_nonzero(np.asarray(image)) > 0, plane


def test_series_constant_after_step_0_share_the_constant_plot(tmp_path: Path) -> None:
    """A series of the step just made (Vicsek's ``updated``: 0 at step 0, where no step was made, 1 at every step
    after) counts as constant: the last layout puts it and the other constant series in one plot, "constant", with
    a legend naming them, after the plots of the series that change."""
    path = tmp_path / "steady.rrd"
    metrics = {"order": "polarisation", "updated": "fraction updated", "components": "components"}
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics, path=path) as rec:
        for step in range(4):
            rec.log_metrics(step, {"order": 0.1 * step, "updated": float(step > 0), "components": 1.0})
        assert rec.constant_metrics() == ("updated", "components")
        assert [plot.name for plot in rec._plots(rec.constant_metrics())] == ["order", "constant"]  # constant last
    legends = _plot_components(path)
    assert sorted(legends) == ["constant", "order"]
    assert legends["constant"]["PlotLegend:visible"] == [True]
    # in the constant plot each series goes by its full name (valency_min's short name "min" is its group's)
    assert {"updated", "components"} <= set(_layout_names(path, "SeriesLines:names"))


def test_series_of_very_different_sizes_get_plots_apart() -> None:
    """A series drawn nearly flat beside a larger one (the default Vicsek run's mean neighbours, 6-94, beside their
    maximum, 19-690, on a 0-1000 axis; number fluctuations of 1-6 agents beside 70-2900) gets a plot apart, split
    again while its part still holds such a series; series alike in size, constant series and series without values
    stay together, and the plots keep the group's order."""
    from tflock.record import FLAT_SHARE, metric_groups, plot_range, readable_groups

    extents = {"mean_neighbors": (6.3, 94.0), "max_neighbors": (19.0, 690.0), "polarization": (0.0, 0.07),
               "gnf_std_4": (70.0, 2872.0), "gnf_std_8": (37.6, 1023.0), "gnf_std_16": (19.0, 480.5),
               "gnf_std_32": (9.4, 187.5), "gnf_std_64": (4.9, 67.4), "gnf_std_128": (2.5, 21.7),
               "gnf_std_256": (1.2, 6.1)}
    groups = readable_groups(metric_groups(list(extents)), extents.get)
    assert groups == {
        "mean_neighbors": [("mean_neighbors", "mean")],
        "max_neighbors": [("max_neighbors", "max")],
        "polarization": [("polarization", "polarization")],
        "gnf_std (1 of 3)": [("gnf_std_4", "box L/4"), ("gnf_std_8", "box L/8"), ("gnf_std_16", "box L/16")],
        "gnf_std (2 of 3)": [("gnf_std_32", "box L/32"), ("gnf_std_64", "box L/64"), ("gnf_std_128", "box L/128")],
        "gnf_std_256": [("gnf_std_256", "box L/256")],
    }
    for members in groups.values():  # every series that changes spans at least FLAT_SHARE of its plot's range
        low, high = plot_range([extents[m] for m, _ in members])
        assert all(extents[m][1] - extents[m][0] >= FLAT_SHARE * (high - low) for m, _ in members)
    # alike in size (parallel lines, each spanning little: splitting would not help), constant, or no values yet
    alike = {f"speed_{i}": (i, i + 0.3) for i in range(4)}
    assert len(readable_groups(metric_groups(list(alike)), alike.get)) == 1
    mixed = {"valency_min": (0.0, 0.0), "valency_mean": (4.0, 8.0), "valency_max": (12.0, 20.0)}
    assert readable_groups(metric_groups([*mixed, "valency_7"]), mixed.get) == metric_groups([*mixed, "valency_7"])


def test_the_last_layout_gives_a_flattened_series_its_own_plot(tmp_path: Path) -> None:
    """The layout sent at the end splits a group whose series differ in size; the first one, sent before any values,
    holds the group's one plot. The about page, written again, names the plots as the last layout has them."""
    path = tmp_path / "sizes.rrd"
    metrics = {"mean_neighbors": "mean", "max_neighbors": "max", "order": "order"}
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics, path=path) as rec:
        assert [plot.name for plot in rec._plots(())] == ["neighbors", "order"]
        for step in range(4):
            rec.log_metrics(step, {"mean_neighbors": 6.0 + step, "max_neighbors": 20.0 + 200 * step, "order": 0.1})
        assert [plot.name for plot in rec._plots(rec.constant_metrics())] == ["mean_neighbors", "max_neighbors",
                                                                               "constant: order"]
    assert {"mean_neighbors", "max_neighbors"} <= set(_layout_names(path))
    (about,) = _last(_chunks(path)["/about"], "TextDocument:text")
    assert "- **mean_neighbors** (`mean_neighbors`): mean" in about and "**neighbors**" not in about


def _layouts_in_order(path: Path) -> list[list[str]]:
    """The view and container names of each layout a recording holds, in the order they were sent."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    layouts = []
    for store in reader.blueprints():
        rows = [row for c in reader.stream(store=store) for row in c.to_record_batch().to_pylist()]
        names = [row[key][0] for row in rows for key in row if key.endswith(":display_name") and row[key]]
        layouts.append((max(row["log_time"] for row in rows), names))
    return [names for _, names in sorted(layouts)]


def test_a_live_viewer_gets_the_split_while_the_run_goes_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Streaming to a viewer, the layout is sent again as soon as the values split a plot (not only at the end, which
    a long run reaches late), at most once every LIVE_LAYOUT_S; a recording no viewer watches gets no layout before
    the last. A watching viewer gets each run's first layout as the active one: it kept the layout an earlier run
    streamed to it had made active (a second run with other metrics showed the first one's plots, empty, in the web
    viewer), where a file's first layout stays a default that does not replace the user's."""
    import tflock.record as record

    metrics = {"mean_neighbors": "mean", "max_neighbors": "max", "order": "order"}

    def run(path: Path, connect: str | None) -> None:
        with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics, path=path,
                      connect=connect) as rec:
            for step in range(4):
                rec.log_metrics(step, {"mean_neighbors": 6.0 + step, "max_neighbors": 20.0 + 200 * step,
                                       "order": 0.1 * step})
                rec.flush()  # the rows go out: where the layout may follow them
            assert rec.live == (connect is not None)

    with _receiver(tmp_path / "received.rrd") as url:
        run(tmp_path / "limited.rrd", url)  # within LIVE_LAYOUT_S of the first layout: only the last one follows
        monkeypatch.setattr(record, "LIVE_LAYOUT_S", 0.0)
        run(tmp_path / "live.rrd", url)
    run(tmp_path / "file.rrd", None)
    for name in ("limited", "file"):
        first, last = _layouts_in_order(tmp_path / f"{name}.rrd")
        assert "neighbors" in first and {"mean_neighbors", "max_neighbors"} <= set(last)
    first, mid_run, *_ = layouts = _layouts_in_order(tmp_path / "live.rrd")
    assert len(layouts) == 3  # the first, once when the values split the plot, the last
    assert "neighbors" in first and "mean_neighbors" not in first
    assert {"mean_neighbors", "max_neighbors"} <= set(mid_run) and "neighbors" not in mid_run
    (about,) = _last(_chunks(tmp_path / "live.rrd")["/about"], "TextDocument:text")
    assert "- **mean_neighbors** (`mean_neighbors`): mean" in about
    assert _activations(tmp_path / "live.rrd") == [True, True, True]
    assert _activations(tmp_path / "file.rrd") == [False, True]


def _activations(path: Path) -> list[bool]:
    """Whether each layout of a recording, in order, is made active where it arrives (Rerun's own print of the
    file: the Python reader does not give the activation commands)."""
    from tflock.record import rerun_executable

    printed = subprocess.run([*rerun_executable(), "rrd", "print", "-v", str(path)], capture_output=True, text=True,
                             check=True).stdout
    return [flag == "true" for flag in re.findall(r"BlueprintActivationCommand\(.*make_active: (true|false)", printed)]


def test_a_plot_of_more_series_than_a_legend_holds_says_how_to_find_their_names(tmp_path: Path) -> None:
    """Vicsek's number fluctuations (7 box sizes, one plot) and a fixed graph's constant valencies (16 flat lines in
    one strip) are too many for a legend: their titles say how many lines there are and that hovering one names it
    (a new user saw 16 unnamed lines, and 7 in gnf_std)."""
    path = tmp_path / "many.rrd"
    boxes = [f"gnf_std_{m}" for m in (4, 8, 16, 32, 64, 128, 256)]
    constants = [f"valency_{i}" for i in range(9)]
    metrics = {name: name for name in [*boxes, *constants]}
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics, path=path) as rec:
        for step in range(4):
            rec.log_metrics(step, {**{b: 0.1 * step + k for k, b in enumerate(boxes)}, **dict.fromkeys(constants, 2.0)})
        names = [plot.name for plot in rec._plots(rec.constant_metrics())]
        assert names == ["gnf_std (hover names)", "constant: 9 series (hover a line for its name)"]
    legends = _plot_components(path)
    assert legends["gnf_std (hover names)"]["PlotLegend:visible"] == [False]
    assert legends["constant: 9 series (hover a line for its name)"]["PlotLegend:visible"] == [False]


def test_legend_names_level_with_their_swatches(tmp_path: Path) -> None:
    """The colours view's names sit level with what they name and right of it: each category's name at its dot's
    height (the viewer hangs a label below its point, so the point is raised by LABEL_RISE) starting right of the
    dot; each field level's name at its row of swatches, starting right of the last swatch."""
    from tflock.frame import ColorLegend
    from tflock.record import LABEL_RISE, _label_width

    legend = ColorLegend("agents: speed", entries=(("|v| = 0", (90, 90, 255)), ("|v| = 0.5", (40, 200, 90)),
                                                   ("|v| >= 1", (255, 60, 60))),
                         notes=(("the leader", (255, 255, 255)), ("dimmed: not updated", (76, 76, 76))))
    path = tmp_path / "legend.rrd"
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS, path=path,
                  legend=legend, field=True):
        pass
    batches = _chunks(path)
    dots = np.array(_last(batches["/legend/entries"], "Points2D:positions"))
    names = np.array(_last(batches["/legend/entries/names"], "Points2D:positions"))
    labels = _last(batches["/legend/entries/names"], "Points2D:labels")
    assert labels == [label for label, _ in legend.entries]
    np.testing.assert_allclose(names[:, 1], dots[:, 1] - LABEL_RISE, atol=1e-6)
    starts = names[:, 0] - np.array([_label_width(label) for label in labels]) / 2
    assert np.all(starts > dots[:, 0])
    swatches = np.array(_last(batches["/legend/field"], "Points2D:positions"))
    levels = np.array(_last(batches["/legend/field/levels"], "Points2D:positions"))
    level_labels = _last(batches["/legend/field/levels"], "Points2D:labels")
    rows = np.unique(np.round(swatches[:, 1], 5))
    np.testing.assert_allclose(np.sort(levels[:, 1] + LABEL_RISE), rows, atol=1e-5)
    level_starts = levels[:, 0] - np.array([_label_width(label) for label in level_labels]) / 2
    assert np.all(level_starts > swatches[:, 0].max())
    # an invisible point where the longest level name ends: the view, which fits its points, keeps the names whole
    level_ends = levels[:, 0] + np.array([_label_width(label) for label in level_labels]) / 2
    assert np.array(_last(batches["/legend/field/end"], "Points2D:positions"))[0, 0] >= level_ends.max() - 1e-6
    ends = names[:, 0] + np.array([_label_width(label) for label in labels]) / 2
    assert swatches[:, 0].min() > ends.max()  # the field's swatches right of the category names
    # and one where the legend starts: left of the dots' left halves and of the centred title's left half (without
    # it a legend as wide as the view, categories beside the field, lost both at 1280 x 800: seen)
    start = np.array(_last(batches["/legend/start"], "Points2D:positions"))[0, 0]
    title = np.array(_last(batches["/legend/title"], "Points2D:positions"))[0, 0]
    assert start < dots[:, 0].min() - 0.1 and start <= title - _label_width(legend.title) / 2
    # the notes: each name level with its dot and right of it, all right of the category names
    marks = np.array(_last(batches["/legend/notes"], "Points2D:positions"))
    notes = np.array(_last(batches["/legend/notes/names"], "Points2D:positions"))
    note_labels = _last(batches["/legend/notes/names"], "Points2D:labels")
    assert note_labels == [label for label, _ in legend.notes]
    np.testing.assert_allclose(notes[:, 1], marks[:, 1] - LABEL_RISE, atol=1e-6)
    assert np.all(notes[:, 0] - np.array([_label_width(label) for label in note_labels]) / 2 > marks[:, 0])
    assert marks[:, 0].min() > ends.max()
    note_ends = notes[:, 0] + np.array([_label_width(label) for label in note_labels]) / 2
    assert swatches[:, 0].min() > note_ends.max()  # the field's swatches right of the notes
    # the field's headings named under its columns, below the last row, apart from each other
    headings = np.array(_last(batches["/legend/field/headings"], "Points2D:positions"))
    heading_labels = _last(batches["/legend/field/headings"], "Points2D:labels")
    assert heading_labels == ["0°", "90°", "180°", "270°"]
    assert np.all(np.isin(np.round(headings[:, 0], 5), np.round(swatches[:, 0], 5)))
    assert headings[:, 1].min() > swatches[:, 1].max()
    widths = np.array([_label_width(label) for label in heading_labels])
    assert np.all(np.diff(headings[:, 0]) > (widths[1:] + widths[:-1]) / 2)


@pytest.mark.parametrize("params,notes", [({}, []), ({"leader": {"enabled": True}}, ["the leader"]),
                                          ({"async_bound": 10}, ["dimmed: not updated"])])
def test_vicsek_legend_names_the_leader_and_the_dimmed_agents(cpu_engine, params: dict, notes: list[str]) -> None:
    """Vicsek's colours view names the marks that are not on its heading wheel: the leader (white) and, with
    asynchrony, the agents dimmed because they did not update at this step."""
    import tflock
    from tflock.frame import LEADER_COLOR, angle_colors
    from tflock.models.vicsek import dimmed

    sim = tflock.Simulation(model="vicsek", params={"n": 50, "box": 7.0, **params}, steps=20, record=False,
                            engine={"precision": cpu_engine.precision})
    legend = sim.model.color_legend
    assert legend.wheel and [label for label, _ in legend.notes] == notes
    colors = dict(legend.notes)
    assert colors.get("the leader", LEADER_COLOR) == LEADER_COLOR
    white = tuple(int(c) for c in dimmed(np.full((1, 3), 255))[0])
    assert colors.get("dimmed: not updated", white) == white
    sim.close()
    # every dimmed hue stays visible on the viewer's dark background (contrast ratio >= 2: a blue agent darkened
    # alone was (0, 0, 76), 1.04) and stands apart from the updated agents' full colour
    wheel = angle_colors(np.linspace(0, 2 * np.pi, 96, endpoint=False))

    def luminance(rgb: np.ndarray) -> np.ndarray:
        c = rgb / 255.0
        lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        return lin @ np.array([0.2126, 0.7152, 0.0722])

    background = luminance(np.array([15.0, 15.0, 15.0]))
    assert np.all((luminance(dimmed(wheel).astype(float)) + 0.05) / (background + 0.05) >= 2.0)
    assert np.all(dimmed(wheel).max(axis=1) <= 0.8 * wheel.max(axis=1))


def test_vicsek_frame_dims_the_agents_that_did_not_update(cpu_engine) -> None:
    """With asynchronous updates a frame draws the agents that updated at this step in their heading's colour and the
    others dimmed (tflock.models.vicsek.dimmed), both from the same hue."""
    import tflock
    from tflock.frame import angle_colors
    from tflock.models.vicsek import dimmed

    sim = tflock.Simulation(model="vicsek", params={"n": 60, "box": 5.0, "async_bound": 3}, steps=7, record=False,
                            engine={"precision": cpu_engine.precision})
    sim.run()
    model = sim.model
    agents = np.arange(60)
    frame = model.frame(agents, max_edges=0)
    updated = model.updated_agents()
    assert 0 < updated.sum() < 60
    theta = model.state()["theta"]
    full = angle_colors(theta)
    np.testing.assert_array_equal(frame.colors[updated], full[updated])
    np.testing.assert_array_equal(frame.colors[~updated], dimmed(full[~updated]))
    sim.close()


def test_plots_paged_in_tabs_of_six(tmp_path: Path) -> None:
    """More than PLOTS_PER_TAB plots go to a second tab, "metrics 2", so that each plot keeps a readable height with
    its axis labels (12 a tab left about 70 px a plot at 1600 x 1000, some of them without y labels)."""
    from tflock.record import PLOTS_PER_TAB

    metrics = {f"m{k}": f"metric {k}" for k in range(PLOTS_PER_TAB + 2)}
    path = tmp_path / "pages.rrd"
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics, path=path) as rec:
        for step in range(3):
            rec.log_metrics(step, {name: float(step * k) for k, name in enumerate(metrics)})
    names = _layout_names(path)
    assert PLOTS_PER_TAB == 6
    assert "metrics" in names and "metrics 2" in names and "metrics 3" not in names
    assert all(f"m{k}" in names for k in range(1, PLOTS_PER_TAB + 2)) and "constant: m0" in names


def test_constant_plot_is_a_strip_under_the_last_tab(tmp_path: Path) -> None:
    """The plot of the constant series takes no place in a tab's grid: 12 varying plots and a constant one make two
    tabs (a third tab held the constant plot alone, and the tab bar scrolled at 1280 px), the constant plot a strip
    under the second tab's grid, lower than a row of it."""
    metrics = {f"m{k}": f"metric {k}" for k in range(13)}
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics,
                  path=tmp_path / "strip.rrd") as rec:
        for step in range(3):
            rec.log_metrics(step, {name: float(step * k) for k, name in enumerate(metrics)})
        assert rec.constant_metrics() == ("m0",)
        tabs = rec.blueprint(rec.constant_metrics()).root_container.contents[1].contents[:-2]  # about, config last
    assert [tab.name for tab in tabs] == ["metrics", "metrics 2"]
    assert type(tabs[0]).__name__ == "Grid" and len(tabs[0].contents) == 6
    grid, strip = tabs[1].contents
    assert type(tabs[1]).__name__ == "Vertical" and len(grid.contents) == 6 and strip.name == "constant: m0"
    shares = tabs[1].row_shares
    assert shares[1] < shares[0] / 3  # less than one of the grid's 3 rows
    names = _layout_names(tmp_path / "strip.rrd")
    assert "metrics 3" not in names and "constant: m0" in names


def test_3d_layout_puts_the_field_projections_under_the_world(tmp_path: Path) -> None:
    """3D with the field: the three projections in a row under the 3D view, the colour legend alone above the plots
    (beside three projections it was squeezed to a quarter of the column, its labels over each other)."""
    from tflock.frame import HEADING_LEGEND

    with Recorder(model="m", config_toml="", world=WorldSpec(3, "open", 5.0), metrics=METRICS,
                  path=tmp_path / "3d.rrd", legend=HEADING_LEGEND, field=True) as rec:
        left, right = rec.blueprint().root_container.contents
    world, projections = left.contents
    assert world.name == "world" and [v.name for v in projections.contents] == ["field xy", "field xz", "field yz"]
    legend, tabs = right.contents
    assert legend.name == "colours" and type(tabs).__name__ == "Tabs"


def _layout_names(path: Path, suffix: str = ":display_name") -> list[str]:
    """The names of the views and containers of the last layout in a recording (or other components of it whose
    column ends with `suffix`)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    layouts = {store: [c.to_record_batch().to_pylist() for c in reader.stream(store=store)]
               for store in reader.blueprints()}
    last = max(layouts, key=lambda store: max(row["log_time"] for rows in layouts[store] for row in rows))
    return [row[key][0] for rows in layouts[last] for row in rows for key in row
            if key.endswith(suffix) and row[key]]


def test_legend_goes_to_the_corner_free_of_the_data() -> None:
    """A plot's legend goes to the corner with the fewest of its points under it: a series that decays from the top
    left to the bottom right leaves the right top (the first choice) and the left bottom free; one that rises leaves
    the left top and right bottom; ties (a flat line in the middle) keep the first choice. The legend is as large as
    measured in the viewer (two series: about 0.4 of the plot's height): Samiloglu's neighbours, a max at 8 and a mean
    at 4 on a plot of 0-10, leave the bottom free, where a legend half the plot's height would cover the mean."""
    from tflock.record import LEGEND_CORNERS, place_legend

    steps = list(range(100))
    decay = [math.exp(-s / 10) for s in steps]
    rise = [1 - d for d in decay]
    names = ["max", "mean"]
    assert place_legend([(steps, decay), (steps, [0.5 * d for d in decay])], names) == ("RightTop", None)
    assert place_legend([(steps, rise), (steps, [0.8 * r for r in rise])], names) == ("RightBottom", None)
    # one series high throughout, one that drops at half time: only the left bottom is free
    assert place_legend([(steps, [1.0] * 100), (steps, [1.0 if s < 50 else 0.0 for s in steps])],
                        names)[0] == "LeftBottom"
    assert place_legend([(steps, [8.0] * 100), (steps, [4.0] * 100)], names, (-0.8, 10.8)) == \
        ("LeftBottom", (-0.8, 10.8))
    assert place_legend([(steps, [0.5] * 100)], ["order"]) == (LEGEND_CORNERS[0], None)
    assert place_legend([], []) == (LEGEND_CORNERS[0], None)


def test_legend_covering_the_data_everywhere_gets_room_in_the_last_layout() -> None:
    """Where a legend would cover some points in every corner (a line across the top and one across the bottom), a
    run's last layout widens the plot's y range at the end that needs the least, until the legend's corner is clear
    of the points; a layout sent while the run goes on keeps the viewer's fit (later values could leave a fixed range),
    and so does a plot whose values would be squashed to less than 1 / HEADROOM_MAX of it (four series)."""
    from tflock.record import HEADROOM_MARGIN, HEADROOM_MAX, LEGEND_EDGE_PX, LEGEND_ROW_PX, PLOT_PX, place_legend

    steps = list(range(100))
    top = [1.0 + 0.01 * (s % 2) for s in steps]
    bottom = [0.0 + 0.01 * (s % 3) for s in steps]
    series = [(steps, top), (steps, bottom)]
    corner, shown = place_legend(series, ["high", "low"])
    assert shown is None  # covered somewhere, but not widened while the run goes on
    corner, widened = place_legend(series, ["high", "low"], headroom=True)
    assert widened is not None
    low, high = widened
    assert low <= 0.0 and high >= 1.01
    height = (LEGEND_EDGE_PX + 2 * LEGEND_ROW_PX) / PLOT_PX[1] + HEADROOM_MARGIN
    if corner.endswith("Top"):  # the highest point under the legend's bottom edge
        assert (1.01 - low) / (high - low) <= 1 - height + 1e-9
    else:
        assert (0.02 - low) / (high - low) >= height - 1e-9
    assert (high - low) <= HEADROOM_MAX * 1.01
    # a fixed range given (labelled_range's) keeps its far end: the room is added at the legend's end only
    corner, widened = place_legend(series, ["high", "low"], (-0.1, 1.1), headroom=True)
    assert widened is not None and (widened[0] == -0.1 or widened[1] == 1.1)
    # the strip of constant series (two lines at 0, drawn at half height by the viewer's fit, under the legend in
    # every corner of a strip 90 px high): a range with the lines under the legend
    corner, widened = place_legend([(steps, [0.0] * 100), (steps, [0.0] * 100)], ["connected", "valency_min"],
                                   headroom=True, size_px=(500.0, 90.0))
    assert widened is not None and corner.endswith("Top")
    assert (0.0 - widened[0]) / (widened[1] - widened[0]) <= 1 - (LEGEND_EDGE_PX + 2 * LEGEND_ROW_PX) / 90.0
    # four series spread over the plot: their legend would squash the values to less than half; kept as it was
    spread = [(steps, [k + 0.01 * (s % 2) for s in steps]) for k in range(4)]
    assert place_legend(spread, ["a", "b", "c", "d"], headroom=True)[1] is None


def test_gnf_plot_named_by_box_with_its_legend_off_the_data(make_sim, tmp_path: Path) -> None:
    """A Vicsek recording's number-fluctuation series form the plots ``gnf_std`` (``gnf_std (1 of 2)``, ... where
    their sizes differ too much for one plot, :func:`readable_groups`), whose lines are named by their box size (not
    "agent 4"); the layout sent at the end places each such plot's legend in the corner that covers the fewest of
    its points."""
    from rerun.blueprint.components import Corner2D

    from tflock.record import metric_groups, place_legend, readable_groups

    path = tmp_path / "gnf.rrd"
    sim = make_sim(model="vicsek", params={"n": 2000, "box": 32.0}, steps=12, record=path,
                   log={"max_agents": 100, "max_edges": 10, "field": 0})
    sim.run()
    recorder = sim.recorder
    sim.close()
    traces = {n: recorder._rows.series(n) for n in recorder.metrics if n.startswith("gnf_std_")}
    assert len(traces) >= 2
    batches = _chunks(path)
    for name in traces:
        assert _last(batches[f"/metrics/{name}"], "SeriesLines:names") == [f"box L/{name.rsplit('_', 1)[1]}"]
    # each line its own colour, far from the others' (the viewer's colours from the paths nearly repeated)
    colors = [_last(batches[f"/metrics/{name}"], "SeriesLines:colors")[0] for name in traces]
    rgb = np.array([[(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255] for c in colors], float)
    gaps = np.linalg.norm(rgb[:, None] - rgb[None], axis=2) + 1e9 * np.eye(len(rgb))
    assert gaps.min() > 80
    legends = _plot_components(path)
    assert not any("agent" in name for name in legends)
    plots = {title: [m for m, _ in members]
             for title, members in readable_groups(metric_groups(list(traces)), recorder._rows.extent).items()}
    assert sorted(m for members in plots.values() for m in members) == sorted(traces)
    assert all(title.startswith("gnf_std") for title in plots) and any(len(m) > 1 for m in plots.values())
    constant = recorder.constant_metrics()
    views = [str(view.name) for view in recorder._plots(constant, final=True)]
    size_of = dict(zip(views, recorder._plot_sizes(len(views), bool(constant) and len(views) > 1), strict=True))
    for title, members in plots.items():
        if len(members) > 1:
            assert legends[title]["PlotLegend:visible"] == [True]
            names = [f"box L/{m.rsplit('_', 1)[1]}" for m in members]
            size = size_of[title]  # the plot's size in the default layout
            corner, y_range = place_legend([traces[m] for m in members], names, recorder._y_range(members, size, True),
                                           headroom=True, size_px=size)
            assert legends[title]["PlotLegend:corner"] == [getattr(Corner2D, corner).value]


def test_labelled_range_fixes_only_plots_whose_marks_would_go_unlabelled() -> None:
    """Rerun labels only decade marks, and none that are too close: values spanning more than DENSE_MARKS marks of
    their decade get the two marks of the decade above around them (with a margin, as a mark on the edge is not
    labelled), where they lie between two such marks; values among which lies only one labelled mark get the marks
    around them; the others keep the viewer's fit."""
    from tflock.record import LABEL_MARGIN, enclosing_marks, labelled_range

    def fixed(low: float, high: float) -> tuple[float, float] | None:
        out = labelled_range(low, high) or enclosing_marks(low, high)
        return None if out is None else (round(out[0], 12), round(out[1], 12))

    m = LABEL_MARGIN
    assert fixed(0.003, 0.068) == (round(-0.1 * m, 12), round(0.1 * (1 + m), 12))  # polarization, default run
    assert fixed(-0.068, -0.003) == (round(-0.1 * (1 + m), 12), round(0.1 * m, 12))
    assert fixed(0.02, 1.0) == (-m, 1 + m)  # the top on the mark itself
    assert fixed(4.0, 690.0) == (-1000 * m, 1000 * (1 + m))
    assert fixed(83.0, 85.6) is None  # 2.6 marks of 1: labelled as fitted
    assert fixed(950.0, 1400.0) is None  # 4.5 marks of 100 around the labelled 1000
    assert fixed(0.3, 0.36) == (round(0.3 - 0.1 * m, 12), round(0.4 + 0.1 * m, 12))  # low on a mark: 0.3 / 0.1 < 3
    assert fixed(0.5, 0.5) is None and fixed(0.0, math.inf) is None and fixed(0.0, math.nan) is None
    # labelled marks, but only one among the values: the marks around them, if that at most doubles the span
    assert fixed(-17.5, -4.9) == (round(-20 - 20 * m, 12), round(20 * m, 12))  # Tanner's Q: -20, -10 and 0
    assert fixed(-156109.0, -14240.0) == (round(-2e5 - 2e5 * m, 12), round(2e5 * m, 12))  # potential's Q
    assert fixed(0.95, 1.05) == (round(0.9 - 0.2 * m, 12), round(1.1 + 0.2 * m, 12))
    assert fixed(4.0, 5.0) is None and fixed(16.0, 25.0) is None  # two marks already
    assert fixed(1.0, 1.4) is None  # one mark, 1; the marks around, 1 and 2, would more than double the span
    assert fixed(0.004, 1.41) is None  # Tanner's kinetic energy: 0 lies in the viewer's fit, labelled with 1
    assert fixed(341.0, 1434.0) == (-2000 * m, 2000 * (1 + m))  # Vicsek's clusters: 1000 alone; 0, 1000, 2000


def test_dense_plots_get_a_labelled_range_from_every_row(tmp_path: Path) -> None:
    """The layout sent at the end fixes the y range of a plot whose values span too many marks to be labelled on
    it (:func:`labelled_range` at the plot's height: two plots in a column of the tabs without the colours view,
    about 300 px high, label up to about 9 marks), from the smallest and largest of all the rows logged, not only of
    those kept for placing legends (a spike of 0.15 in a dropped row takes the range away: 0.002 to 0.15 is
    labelled as fitted); a plot labelled as fitted keeps the fit."""
    from tflock.metric_log import TRACE_POINTS
    from tflock.record import labelled_range, plot_px

    def record(spike: float) -> dict[str, dict[str, list]]:
        path = tmp_path / f"dense-{spike}.rrd"
        with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS,
                      path=path) as rec:
            for step in range(2 * TRACE_POINTS + 2):
                order = spike if step == 2 * TRACE_POINTS + 1 else 0.002 + 0.088 * (step % 7) / 6
                rec.log_metrics(step, {"order": order, "speed": 83.0 + 2.6 * (step % 5) / 4})
            assert rec._rows.series("order")[1].max() < spike  # the spike's row is not among those kept
        return _plot_components(path, "ScalarAxis")

    height = plot_px(1, 2, colours=False)[1]
    fixed = labelled_range(0.002, 0.099, height)
    assert fixed is not None and labelled_range(0.002, 0.06, height) is None  # 9.7 marks of 0.01 are too many, 5.8 not
    axes = record(0.099)
    assert axes["order"]["ScalarAxis:range"] == [list(fixed)]
    assert "speed" not in axes
    assert "order" not in record(0.15)  # 0.002 to 0.15: 1.5 marks of 0.1, labelled as fitted (0 and 0.1)


def test_enclosing_marks_only_in_the_last_layout(tmp_path: Path) -> None:
    """Values with one labelled mark among them (-17.5 to -4.9) get the marks around them in the run's last layout
    only: while the run goes on, a range fixed around the values so far could cut off those to come."""
    from tflock.record import enclosing_marks

    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS,
                  path=tmp_path / "q.rrd") as rec:
        for step in range(10):
            rec.log_metrics(step, {"order": -17.5 + 1.4 * step, "speed": 1.0 + 0.01 * step})
        assert rec._y_range(["order"]) is None
        assert rec._y_range(["order"], final=True) == enclosing_marks(-17.5, -4.9)
    assert _plot_components(tmp_path / "q.rrd", "ScalarAxis")["order"]["ScalarAxis:range"] == \
        [list(enclosing_marks(-17.5, -4.9))]


def test_plot_sizes_follow_the_tabs_layout() -> None:
    """Each plot's size is that of its place in the tabs :meth:`_metric_tabs` builds: a full tab's 3 x 2 grid, a
    last tab of one plot above the strip of constant series, and the strip's share of that tab (no colours view)."""
    from tflock.record import STRIP_ROWS, plot_px

    rec = Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=METRICS)
    assert rec._plot_sizes(8, strip=True) == [plot_px(2, 3, False)] * 6 + [plot_px(1, 1 + STRIP_ROWS, False),
                                                                            plot_px(1, (1 + STRIP_ROWS) / STRIP_ROWS,
                                                                                    False)]
    assert rec._plot_sizes(4, strip=False) == [plot_px(2, 2, False)] * 4
    rec.close()


def test_short_plots_label_fewer_marks_and_fit_their_legends() -> None:
    """A plot's labels and its legend are judged at its height in the default layout: min_distance in [0.25, 0.6]
    (3.5 marks of 0.1) is labelled as fitted on a plot of the first tab's 3 x 2 grid (130 px) but gets the range 0 to
    1 on one 64 px high; four plots share a tab in two columns, not one (their legends and labels need the height)."""
    from tflock.record import PLOT_PX, labelled_range, plot_px, tab_pages

    assert labelled_range(0.25, 0.6) is None and labelled_range(0.25, 0.6, PLOT_PX[1]) is None
    assert labelled_range(0.25, 0.6, 64.0) == pytest.approx((-0.08, 1.08))
    assert [tab_pages(k)[0][2] for k in range(1, 7)] == [1, 1, 1, 2, 2, 2]  # columns
    assert tab_pages(16) == [(0, 6, 2), (6, 6, 2), (12, 4, 2)] and tab_pages(7) == [(0, 6, 2), (6, 1, 1)]
    assert abs(plot_px(2, 3)[1] - PLOT_PX[1]) < 5 and abs(plot_px(2, 3)[0] - PLOT_PX[0]) < 20
    assert plot_px(2, 2 + 0.75)[1] > 120  # four plots and the strip of constant series under the colours view


def test_last_layout_makes_room_for_a_legend_that_covers_lines_everywhere(tmp_path: Path) -> None:
    """A plot whose two lines run across its top and its bottom (a maximum and a mean neighbour count, each barely
    moving) leaves its legend no free corner: the layout sent at the end fixes its y range with room for the legend
    (:func:`place_legend` with headroom), the legend in the corner so cleared; a plot of one series (no legend) keeps
    the viewer's fit."""
    from rerun.blueprint.components import Corner2D

    from tflock.record import place_legend, plot_px

    metrics = {"max_neighbors": "most neighbours", "mean_neighbors": "mean neighbours", "order": "order"}
    path = tmp_path / "room.rrd"
    with Recorder(model="m", config_toml="", world=WorldSpec(2, "periodic", 5.0), metrics=metrics,
                  path=path) as rec:
        for step in range(200):
            rec.log_metrics(step, {"max_neighbors": 7.0 + 0.2 * (step % 2), "mean_neighbors": 4.0 + 0.1 * (step % 3),
                                   "order": 0.6 + 0.3 * math.exp(-step / 20)})
        traces = [rec._rows.series(m) for m in ("max_neighbors", "mean_neighbors")]
        assert rec._y_range(["max_neighbors", "mean_neighbors"]) is None  # 4.0-7.2: labelled as the viewer fits it
    size = plot_px(1, 2, colours=False)  # two plots in a column, no colours view: the layout's plot
    corner, y_range = place_legend(traces, ["max", "mean"], None, headroom=True, size_px=size)
    assert y_range is not None and place_legend(traces, ["max", "mean"], size_px=size)[1] is None
    axes = _plot_components(path, "ScalarAxis")
    assert axes["neighbors"]["ScalarAxis:range"] == [list(y_range)]
    assert "order" not in axes
    assert _plot_components(path)["neighbors"]["PlotLegend:corner"] == [getattr(Corner2D, corner).value]


def test_wrapped_angles_plotted_as_points(make_sim, tmp_path: Path) -> None:
    """Vicsek's mean heading, an angle wrapped into [0, 2 pi), is plotted as points: a line would cross the whole
    plot each time the flock's heading passes 0; its other metrics keep their lines."""
    path = tmp_path / "angles.rrd"
    sim = make_sim(model="vicsek", params={"n": 2000, "box": 32.0}, steps=3, record=path,
                   log={"max_agents": 100, "max_edges": 10, "field": 0})
    sim.run()
    sim.close()
    batches = _chunks(path)
    assert _last(batches["/metrics/mean_heading"], "SeriesPoints:names") == ["mean_heading"]
    assert _last(batches["/metrics/mean_heading"], "SeriesLines:names") is None
    assert _last(batches["/metrics/polarization"], "SeriesLines:names") == ["polarization"]
    assert _last(batches["/metrics/polarization"], "SeriesPoints:names") is None


def test_about_keeps_descriptions_whole(make_sim, tmp_path: Path) -> None:
    """The about page lists every metric with its whole description: `potential`'s "mean |v_i - mean v|" was cut
    at its first | (read as a table's cell) and showed as "mean"."""
    path = tmp_path / "about.rrd"
    sim = make_sim(model="potential", params={"n": 12}, steps=2, record=path)
    sim.run()
    sim.close()
    (about,) = _last(_chunks(path)["/about"], "TextDocument:text")
    # (a series of its group's plot, "  - mean (`...`)", or a plot of its own where the sizes split the group)
    assert "(`velocity_mismatch_mean`): mean \\|v\\_i - mean v\\|\n" in about
    assert "- **polarization** (`polarization`): polarization \\|mean v\\_i / \\|v\\_i\\|\\|\n" in about


@pytest.mark.parametrize("topology,edges", [
    ("fixed", "edges of the fixed interaction graph among the drawn agents"),
    ("switching", "pairs within the interaction radius among the drawn agents"),
])
def test_about_says_what_the_edges_join(make_sim, tmp_path: Path, topology: str, edges: str) -> None:
    """The about text names the edges drawn: a fixed-topology potential run draws its fixed graph's edges, longer
    than R too, where the about text said "pairs within the interaction radius" for every model."""
    path = tmp_path / f"{topology}.rrd"
    params = {"n": 30, "box": 6.0, "topology": topology}
    if topology == "fixed":
        params.update(graph="random", graph_p=0.2)
    sim = make_sim(model="potential", params=params, steps=2, record=path)
    sim.run()
    sim.close()
    (about,) = _last(_chunks(path)["/about"], "TextDocument:text")
    assert f"- **edges**: {edges} (" in about


def _plot_components(path: Path, archetype: str = "PlotLegend") -> dict[str, dict[str, list]]:
    """The plots of the last layout in a recording: view name -> its components of `archetype` (PlotLegend,
    ScalarAxis)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    layouts = {store: [c.to_record_batch().to_pylist() for c in reader.stream(store=store)]
               for store in reader.blueprints()}
    last = max(layouts, key=lambda store: max(row["log_time"] for rows in layouts[store] for row in rows))
    names: dict[str, str] = {}
    legends: dict[str, dict[str, list]] = {}
    for chunk, rows in zip(reader.stream(store=last), layouts[last], strict=True):
        for row in rows:
            for key, value in row.items():
                if key.endswith(":display_name"):
                    names[chunk.entity_path] = value[0]
                elif key.startswith(f"{archetype}:"):
                    legends.setdefault(chunk.entity_path.rsplit("/", 1)[0], {})[key] = value
    return {names[view]: legend for view, legend in legends.items()}


@pytest.mark.parametrize("boundary", ["periodic", "reflecting", "open"])
def test_3d_box_view_looks_at_the_whole_box(make_sim, tmp_path: Path, boundary: str) -> None:
    """A 3D box's world view starts with its camera on the box: aimed at its centre from EYE_OFFSET box sides away
    (the viewer's own fit cut the box's lower front edges); open space keeps the viewer's fit of the agents."""
    from tflock.record import EYE_OFFSET

    path = tmp_path / "eye.rrd"
    sim = make_sim(model="vicsek", params={"n": 200, "dim": 3, "box": 6.0, "boundary": boundary}, steps=2,
                   record=path)
    sim.run()
    sim.close()
    eyes = _plot_components(path, "EyeControls3D")
    assert "world" in _layout_names(path)
    if boundary == "open":
        assert not any(k.endswith(("position", "look_target")) for eye in eyes.values() for k in eye)
        return
    (eye,) = eyes.values()
    assert eye["EyeControls3D:look_target"] == [pytest.approx([3.0, 3.0, 3.0])]
    assert eye["EyeControls3D:position"] == [pytest.approx(list(3.0 + 6.0 * EYE_OFFSET))]


def test_colours_view_labels_clear_of_the_wheel_and_the_band_profile_tab(make_sim, tmp_path: Path) -> None:
    """The hue wheel's angle labels are centred on their spots 1.3 radii out (the viewer hangs a label below its
    point: the 90° one lay over the arrows), the title's label ends above the 90° label, and the band profile's tab
    is named in words with no legend (its one entry was the entity path)."""
    from tflock.record import LABEL_RISE, LEGEND_PX, TITLE_Y

    path = tmp_path / "legend.rrd"
    sim = make_sim(model="vicsek", params={"n": 500, "box": 16.0}, steps=2, record=path)
    sim.run()
    sim.close()
    batches = _chunks(path)
    spots = np.array(_last(batches["/legend/wheel/angles"], "Points2D:positions"))
    quarter = np.arange(4) * (np.pi / 2)
    want = 1.3 * np.stack([np.cos(quarter), -np.sin(quarter)], axis=1) - [0.0, LABEL_RISE]
    np.testing.assert_allclose(spots, want, atol=1e-6)
    (title,) = _last(batches["/legend/title"], "Points2D:positions")
    label_height = 20.0 / LEGEND_PX
    assert title[1] == pytest.approx(TITLE_Y) and TITLE_Y + label_height < spots[1][1]  # 90°: y = -1.3 - rise
    profiles = _plot_components(path)
    assert profiles["band profile"]["PlotLegend:visible"] == [False]


def test_a_leader_run_plots_the_leader_error_on_the_first_tab(make_sim, tmp_path: Path) -> None:
    """Vicsek with a leader puts the leader error beside the polarization, the first plots of the first tab (it was
    the ninth plot, on the second tab), while the metrics table keeps the model's order; without a leader the plots
    follow the metrics' order."""
    orders = {}
    for leader in (True, False):
        sim = make_sim(model="vicsek", params={"n": 60, "box": 5.0, "leader": {"enabled": leader}}, steps=3,
                       record=tmp_path / f"leader-{leader}.rrd")
        sim.run()
        recorder = sim.recorder
        right = recorder.blueprint(recorder.constant_metrics()).root_container.contents[1]
        legend, tabs = right.contents  # the colours view above the tabs
        first = tabs.contents[0]
        orders[leader] = [view.name for view in first.contents]
        columns = list(sim.metrics())
        sim.close()
        assert columns[:3] == ["step", "time", "polarization"]
    assert orders[True][:2] == ["polarization", "leader_error"]
    assert orders[False][:2] == ["polarization", "mean_heading"]
