"""Rerun recording for tflock: the only module that talks to Rerun.

The simulation hands a :class:`Recorder` plain NumPy arrays (a :class:`Frame` per drawn step and a mapping of
metric values); the recorder lays them out as described in DESIGN.md section 5:

* timelines ``step`` (sequence) and ``time`` (duration, ``step * dt`` seconds); ``log_time`` is disabled so a
  recording only depends on what was logged;
* ``world/agents`` (Points2D/3D), ``world/agents/headings`` (Arrows2D/3D), ``world/edges`` (LineStrips2D/3D),
  ``world/leader`` (+ ``world/leader/heading``), ``world/bounds`` (static);
* ``metrics/<name>``: one Scalars series per metric with a static SeriesLines naming it;
* ``profiles/<name>``: a BarChart per drawn frame for each 1D profile the model declares (e.g. the density along
  the mean heading, which shows travelling bands);
* ``config`` (static markdown TextDocument holding the resolved TOML) and ``meta`` (static AnyValues);
* a default blueprint: the world view beside stacked time-series views and the config.

:func:`read_recording`, :func:`verify_recording` and :func:`open_viewer` serve ``tflock inspect`` /
``tflock view`` and the tests.
"""

from __future__ import annotations

import csv
import functools
import math
import os
import re
import shutil
import subprocess
import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO
from urllib.parse import quote

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from tflock.frame import BOUNDARIES, Frame, Marker, WorldSpec, heading_colors

__all__ = [
    "BOUNDARIES",
    "Frame",
    "Recorder",
    "RecordingSummary",
    "WorldSpec",
    "heading_colors",
    "open_viewer",
    "read_recording",
    "rerun_executable",
    "verify_recording",
]

AGENTS = "world/agents"
HEADINGS = "world/agents/headings"
EDGES = "world/edges"
LEADER = "world/leader"
LEADER_HEADING = "world/leader/heading"
BOUNDS = "world/bounds"
CONFIG = "config"
META = "meta"
METRICS = "metrics"
PROFILES = "profiles"

SPAWN_PORT = 9876
LEADER_COLOR = (255, 255, 255)
EDGE_COLOR = (170, 170, 170, 90)
BOUNDS_COLOR = (200, 200, 200)
#: Rerun's batcher sends its pending rows on once they hold this many bytes (see :func:`batcher_config`)
FLUSH_NUM_BYTES = 256 * 1024
_METRIC_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
_TOML_BLOCK = re.compile(r"^(`{3,})toml\n(.*?)\n\1[ \t]*$", re.DOTALL | re.MULTILINE)


def _packed_rgba(rgb: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 colours as Rerun's packed 0xRRGGBBAA uint32 (opaque). Rerun converts RGB rows itself, but
    element by element, which dominated the logging of a large frame."""
    c = rgb.astype(np.uint32)
    return (c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | np.uint32(255)


def _f32(name: str, a: np.ndarray, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``a`` as a C-contiguous float32 array, checking its shape (None: any length)."""
    arr = np.ascontiguousarray(a, dtype=np.float32)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("M" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"Frame.{name} must have shape {want}, got {arr.shape}")
    return arr


@functools.cache
def _strips_type(dim: int) -> pa.DataType:
    """Arrow type of a LineStrip2D/3D batch, taken from an empty batch (the public way to get it)."""
    batch = rr.components.LineStrip2DBatch if dim == 2 else rr.components.LineStrip3DBatch
    return batch(np.zeros((0, 2, dim), np.float32)).as_arrow_array().type


def _segments(edges: np.ndarray) -> pa.ListArray:
    """An (E, 2, dim) float32 array as E two-point line strips, built directly in Arrow.

    Equal to what ``LineStrips2D(edges)`` builds, but that path computes the offsets in a Python loop, one
    iteration an edge; here they are one NumPy range.
    """
    n, _, dim = edges.shape
    strips_type = _strips_type(dim)
    points = pa.FixedSizeListArray.from_arrays(pa.array(edges.reshape(-1)), type=strips_type.value_type)
    offsets = pa.array(np.arange(0, 2 * n + 1, 2, dtype=np.int32))
    return pa.ListArray.from_arrays(offsets, points, type=strips_type)


def _has_display() -> bool:
    """Whether a native viewer window can open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _check_writable(path: Path, what: str) -> Path:
    """Create ``path``'s parent and open the file for writing, turning failures into one clear OSError."""
    path = Path(path).expanduser()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb"):
            pass
    except OSError as e:
        reason = e.strerror or str(e)
        raise OSError(e.errno, f"cannot write the {what} to {path}: {reason}") from e
    return path


def batcher_config() -> rr.ChunkBatcherConfig | None:
    """Rerun's batching with :data:`FLUSH_NUM_BYTES` in place of its 2 MiB default, unless RERUN_FLUSH_NUM_BYTES is
    set (None: Rerun reads its environment). With the default, a frame of 50k agents (0.6 MB of points, 1 MB of
    arrows) waits for the next and the two are copied into one chunk, in fresh pages; sent on alone, each row is
    its own chunk, with no copy and far fewer page faults (see docs/performance.md, Logging).
    Rerun's other thresholds (its 200 ms tick, the RERUN_FLUSH_TICK_SECS it reads) still gather small rows."""
    if "RERUN_FLUSH_NUM_BYTES" in os.environ:
        return None
    return rr.ChunkBatcherConfig(flush_num_bytes=FLUSH_NUM_BYTES)


class Recorder:
    """Writes a tflock run to Rerun (file, native viewer and/or a running viewer) and a metrics CSV.

    Use as a context manager or call :meth:`close` in a ``finally:``; closing finalises the ``.rrd`` file (its
    footer) so that ``rerun rrd verify`` passes even after Ctrl-C or SIGTERM mapped to KeyboardInterrupt.
    With none of ``path`` / ``spawn`` / ``connect`` the Rerun side is disabled (``enabled`` is False) and only
    the metrics table is written.
    """

    def __init__(
        self,
        *,
        model: str,
        config_toml: str,
        world: WorldSpec,
        metrics: Mapping[str, str],
        profiles: Mapping[str, str] | None = None,
        path: Path | None = None,
        spawn: bool = False,
        connect: str | None = None,
        metrics_table: Path | None = None,
        application_id: str = "tflock",
        recording_id: str | None = None,
    ) -> None:
        """``recording_id``: give a resumed run's new file the id of the first one, so that the viewer shows the
        segments (``rerun first.rrd resumed.rrd``) as one recording on the same timelines."""
        for name in metrics:
            if not _METRIC_NAME.match(name):
                raise ValueError(f"metric name {name!r} must be letters, digits, '_' or '-'")
        if spawn and not _has_display():
            raise RuntimeError(
                "--spawn needs a display (no DISPLAY is set); use --out and `tflock view --web`"
            )
        self.model = model
        self.config_toml = config_toml
        self.world = world
        self.metrics = dict(metrics)
        self.profiles = dict(profiles or {})  # name -> description of the frames' profiles (one bar chart each)
        self.path = _check_writable(path, "recording") if path is not None else None
        self.metrics_table = _check_writable(metrics_table, "metrics table") if metrics_table else None
        self._closed = False
        self._edges_drawn = False
        self._leader_drawn = False
        self._leader_heading_drawn = False

        sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self.path is not None:
            sinks.append(rr.FileSink(self.path))
        if connect:
            sinks.append(rr.GrpcSink(connect))
        self.enabled = bool(sinks) or spawn
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id, default_enabled=self.enabled,
                                      batcher_config=batcher_config())
        self.rec.set_log_time_enabled(False)
        self._csv_file: IO[str] | None = None
        try:
            if self.metrics_table is not None:
                self._csv_file = open(self.metrics_table, "w", newline="", encoding="utf-8")
                self._csv = csv.writer(self._csv_file)
                self._csv.writerow(["step", *self.metrics])
                self._csv_file.flush()
            if self.enabled:
                if spawn:
                    self.rec.spawn(port=SPAWN_PORT, connect=False)
                    sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"))
                self.rec.set_sinks(*sinks, default_blueprint=self.blueprint())
                self._log_static()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ layout
    def blueprint(self) -> rrb.Blueprint:
        """The default layout: world view on the left, metric plots stacked with the config on the right."""
        world = self.world
        if world.dim == 2:
            bounds = None
            if world.bounded:
                margin = 0.02 * world.box
                span = [-margin, world.box + margin]
                bounds = rrb.VisualBounds2D(x_range=span, y_range=span)
            world_view: rrb.View = rrb.Spatial2DView(name="world", origin="/world", visual_bounds=bounds)
        else:
            world_view = rrb.Spatial3DView(name="world", origin="/world")
        plots = [rrb.TimeSeriesView(name=n, origin=f"/{METRICS}/{n}") for n in self.metrics]
        plots += [rrb.BarChartView(name=n, origin=f"/{PROFILES}/{n}") for n in self.profiles]
        config_view = rrb.TextDocumentView(name="config", origin=f"/{CONFIG}")
        if len(plots) > 4:
            right = rrb.Vertical(rrb.Grid(*plots, grid_columns=2), config_view, row_shares=[4, 1])
        else:
            right = rrb.Vertical(*plots, config_view, row_shares=[2] * len(plots) + [1])
        return rrb.Blueprint(
            rrb.Horizontal(world_view, right, column_shares=[3, 2]),
            rrb.TimePanel(timeline="step"),
            collapse_panels=False,
        )

    def _log_static(self) -> None:
        """Log everything that does not change over the run, once."""
        rec, world = self.rec, self.world
        toml_text = self.config_toml.rstrip("\n")
        fence = "```"
        while fence in toml_text:
            fence += "`"
        doc = (
            f"# tflock run: `{self.model}`\n\n"
            f"{world.dim}D, {world.boundary} boundary, box {world.box:g}, dt {world.dt:g}\n\n"
            f"Resolved configuration:\n\n{fence}toml\n{toml_text}\n{fence}\n"
        )
        rec.log(CONFIG, rr.TextDocument(doc, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log(
            META,
            rr.AnyValues(
                model=self.model,
                dim=world.dim,
                boundary=world.boundary,
                box=float(world.box),
                dt=float(world.dt),
                metrics=list(self.metrics),
            ),
            static=True,
        )
        for name, description in self.metrics.items():
            rec.log(f"{METRICS}/{name}", rr.SeriesLines(names=description), static=True)
        if world.bounded:
            L = float(world.box)
            edge = rr.Radius.ui_points(1.0)
            if world.dim == 2:
                outline = np.array([[[0, 0], [L, 0], [L, L], [0, L], [0, 0]]], dtype=np.float32)
                rec.log(BOUNDS, rr.LineStrips2D(outline, colors=BOUNDS_COLOR, radii=edge), static=True)
            else:
                rec.log(
                    BOUNDS,
                    rr.Boxes3D(mins=[0.0, 0.0, 0.0], sizes=[L, L, L], colors=BOUNDS_COLOR, radii=edge,
                               fill_mode=rr.components.FillMode.MajorWireframe),
                    static=True,
                )

    # ------------------------------------------------------------------ logging
    def _set_time(self, step: int) -> None:
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        self.rec.set_time("step", sequence=int(step))
        self.rec.set_time("time", duration=float(step) * self.world.dt)

    def log_frame(self, step: int, frame: Frame) -> None:
        """Draw the agents (points + heading arrows), neighbour edges and leader at ``step``."""
        if not self.enabled:
            return
        dim = self.world.dim
        pos = _f32("positions", frame.positions, (None, dim))
        dirs = _f32("directions", frame.directions, (pos.shape[0], dim))
        if frame.colors is None:
            colors = heading_colors(dirs)
        else:
            colors = np.ascontiguousarray(frame.colors, dtype=np.uint8)
            if colors.shape != (pos.shape[0], 3):
                raise ValueError(f"Frame.colors must have shape ({pos.shape[0]}, 3), got {colors.shape}")
        edges = None if frame.edges is None else _f32("edges", frame.edges, (None, 2, dim))
        colors = _packed_rgba(colors)

        if dim == 2:
            Points, Arrows, Strips = rr.Points2D, rr.Arrows2D, rr.LineStrips2D
        else:
            Points, Arrows, Strips = rr.Points3D, rr.Arrows3D, rr.LineStrips3D
        radius = float(frame.radius)
        rec = self.rec
        self._set_time(step)
        rec.log(AGENTS, Points(pos, colors=colors, radii=radius))
        rec.log(
            HEADINGS,
            Arrows(origins=pos, vectors=dirs * np.float32(frame.arrow_length), colors=colors,
                   radii=0.3 * radius),
        )
        if edges is not None or self._edges_drawn:  # an empty batch clears edges drawn at earlier steps
            if edges is None:
                edges = np.zeros((0, 2, dim), dtype=np.float32)
            rec.log(EDGES, Strips(_segments(edges), colors=EDGE_COLOR, radii=rr.Radius.ui_points(0.75)))
            self._edges_drawn = True
        if frame.leader is not None or self._leader_drawn:
            lead = np.zeros((0, dim), np.float32)
            if frame.leader is not None:
                lead = _f32("leader", np.reshape(frame.leader, (1, -1)), (1, dim))
            rec.log(LEADER, Points(lead, colors=LEADER_COLOR, radii=2.5 * radius))
            self._leader_drawn = True
            has_heading = frame.leader is not None and frame.leader_direction is not None
            if has_heading or self._leader_heading_drawn:
                vec = np.zeros((0, dim), np.float32)
                if has_heading:
                    d = _f32("leader_direction", np.reshape(frame.leader_direction, (1, -1)), (1, dim))
                    vec = d * np.float32(1.5 * frame.arrow_length)
                rec.log(LEADER_HEADING, Arrows(origins=lead[: len(vec)], vectors=vec, colors=LEADER_COLOR,
                                               radii=0.6 * radius))
                self._leader_heading_drawn = True
        for marker in frame.markers:
            self._log_marker(marker, Points, Arrows, Strips, radius, frame.arrow_length)
        for name, values in frame.profiles.items():
            rec.log(f"{PROFILES}/{name}", rr.BarChart(np.asarray(values, dtype=np.float32)))

    def _log_marker(self, marker: Marker, Points: type, Arrows: type, Strips: type, radius: float,
                    arrow_length: float) -> None:
        dim = self.world.dim
        entity = f"world/{marker.name}"
        where = _f32(marker.name, np.reshape(marker.position, (1, -1)), (1, dim))
        self.rec.log(entity, Points(where, colors=marker.color, radii=marker.size * radius))
        if marker.direction is not None:
            vec = _f32(marker.name, np.reshape(marker.direction, (1, -1)), (1, dim)) * np.float32(1.5 * arrow_length)
            self.rec.log(f"{entity}/heading", Arrows(origins=where, vectors=vec, colors=marker.color,
                                                    radii=0.6 * radius))
        if marker.circle is not None and dim == 2:
            angle = np.linspace(0.0, 2 * math.pi, 97, dtype=np.float32)
            ring = where[0] + np.float32(marker.circle) * np.stack([np.cos(angle), np.sin(angle)], axis=1)
            self.rec.log(f"{entity}/range", Strips([ring.astype(np.float32)], colors=(*marker.color, 140),
                                                   radii=rr.Radius.ui_points(1.0)))

    def log_metrics(self, step: int, values: Mapping[str, float]) -> None:
        """Log one value per metric at ``step`` and append a row to the metrics table.

        Metrics missing from ``values`` are skipped (an empty CSV cell); unknown names raise ValueError.
        """
        unknown = set(values) - set(self.metrics)
        if unknown:
            raise ValueError(
                f"unknown metric(s) {', '.join(sorted(unknown))}; declared: {', '.join(self.metrics)}"
            )
        self._set_time(step)
        for name, value in values.items():
            self.rec.log(f"{METRICS}/{name}", rr.Scalars(float(value)))
        if self._csv_file is not None:
            cells = [repr(float(values[n])) if n in values else "" for n in self.metrics]
            self._csv.writerow([int(step), *cells])
            self._csv_file.flush()

    # ------------------------------------------------------------------ lifecycle
    def flush(self) -> None:
        """Wait until everything logged so far has gone through Rerun's batcher to the sinks (its encoding and
        writing run on background threads)."""
        self.rec.flush()

    def close(self) -> None:
        """Flush and finalise the recording (writes the .rrd footer) and close the CSV. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.rec.disconnect()
        finally:
            if self._csv_file is not None:
                self._csv_file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


# ---------------------------------------------------------------------- read-back
@dataclass
class RecordingSummary:
    """What ``tflock inspect`` shows about a recording."""

    model: str
    config_toml: str  # the fenced TOML block of the config document, ending with a newline
    frames: int  # rows of world/agents
    steps: list[int]  # step of each frame, ascending
    metric_rows: int  # rows of the longest metric series
    final_metrics: dict[str, float]  # value at the last step of each metric
    entities: list[str]  # recorded entity paths ("/world/agents", ...), sorted
    metric_descriptions: dict[str, str] = field(default_factory=dict)  # metric name -> series name

    @property
    def last_step(self) -> int | None:
        """The step of the last frame, or None without frames."""
        return self.steps[-1] if self.steps else None


def _column(batch: pa.RecordBatch, name: str) -> list:
    """One column of a chunk's record batch as Python values (only small columns are read this way)."""
    return batch.column(name).to_pylist()


def _first(column: list) -> object:
    """First scalar of a list<...> record-batch cell (AnyValues and components are lists per row)."""
    value = column[0]
    return value[0] if isinstance(value, list) and len(value) == 1 else value


def read_recording(path: Path) -> RecordingSummary:
    """Summarise a tflock ``.rrd`` file; also works on a file without footer (interrupted run).

    Raises ValueError if the file cannot be read or is not a tflock recording.
    """
    from rerun.chunk import RrdReader

    path = Path(path)
    entities: set[str] = set()
    steps: list[int] = []
    metric_points: dict[str, list[tuple[int, float]]] = {}
    descriptions: dict[str, str] = {}
    model: str | None = None
    doc: str | None = None
    prefix = f"/{METRICS}/"
    try:
        with warnings.catch_warnings():  # a file without footer (interrupted run) is read by a full scan
            warnings.filterwarnings("ignore", message="RRD file has no footer")
            reader = RrdReader(path)
        for chunk in reader.stream():
            entity = chunk.entity_path
            if entity.startswith("/__"):
                continue
            entities.add(entity)
            if chunk.num_rows == 0:
                continue
            batch = chunk.to_record_batch()
            names = set(batch.schema.names)

            if entity == f"/{META}" and "model" in names:
                model = str(_first(_column(batch, "model")))
            elif entity == f"/{CONFIG}" and "TextDocument:text" in names:
                doc = str(_first(_column(batch, "TextDocument:text")))
            elif entity == f"/{AGENTS}" and "step" in names:
                steps.extend(_column(batch, "step"))
            elif entity.startswith(prefix):
                name = entity[len(prefix):]
                if "SeriesLines:names" in names:
                    descriptions[name] = str(_first(_column(batch, "SeriesLines:names")))
                if "Scalars:scalars" in names and "step" in names:
                    pts = metric_points.setdefault(name, [])
                    rows = zip(_column(batch, "step"), _column(batch, "Scalars:scalars"), strict=True)
                    pts.extend((s, float(v[0])) for s, v in rows if v)
    except (OSError, RuntimeError, ValueError) as e:
        raise ValueError(f"cannot read {path} as a Rerun recording: {e}") from e
    if model is None or doc is None:
        raise ValueError(f"{path} is not a tflock recording (no /{META} model or /{CONFIG} document)")
    match = _TOML_BLOCK.search(doc)
    if match is None:
        raise ValueError(f"{path}: the /{CONFIG} document has no ```toml block")
    final = {}
    for name, pts in metric_points.items():
        pts.sort(key=lambda p: p[0])  # stable: the last logged value wins on equal steps
        final[name] = pts[-1][1]
    return RecordingSummary(
        model=model,
        config_toml=match.group(2) + "\n",
        frames=len(steps),
        steps=sorted(steps),
        metric_rows=max((len(p) for p in metric_points.values()), default=0),
        final_metrics=final,
        entities=sorted(entities),
        metric_descriptions=descriptions,
    )


def rerun_executable() -> list[str]:
    """Command prefix that runs the ``rerun`` CLI installed with rerun-sdk.

    The binary itself where it can be found: the ``rerun`` console script is a Python wrapper that runs it as a
    child, and terminating the wrapper would leave the viewer or web server running.
    """
    exe = "rerun.exe" if sys.platform == "win32" else "rerun"
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / exe
        if binary.is_file():
            return [str(binary)]
    except ImportError:
        pass
    beside = Path(sys.executable).parent / exe
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("rerun")
    if found:
        return [found]
    return [sys.executable, "-m", "rerun_cli"]


def verify_recording(path: Path) -> bool:
    """Run ``rerun rrd verify`` (footer included) on ``path``; True when the file is complete and valid.

    ``rerun rrd verify`` exits 0 on a file that is not an RRD at all ("0 files verified"), so its report
    must name exactly one verified file as well.
    """
    result = subprocess.run(
        [*rerun_executable(), "rrd", "verify", str(path)],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        check=False,
    )
    return result.returncode == 0 and re.search(r"\b1 file verified without error", result.stderr) is not None


def open_viewer(path: Path, web: bool = False, port: int = 9090, grpc_port: int = 9876) -> None:
    """Open a recording in the Rerun viewer; blocks until the viewer closes (native) or Ctrl-C (web).

    ``web=True`` serves the web viewer on ``port`` (and the data over gRPC on ``grpc_port``) and prints the
    URL to open; this works without a display. The native viewer needs one (RuntimeError otherwise).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no recording at {path}")
    if web:
        cmd = [*rerun_executable(), "--serve-web", str(path), "--web-viewer-port", str(port),
               "--port", str(grpc_port)]
        data_url = quote(f"rerun+http://127.0.0.1:{grpc_port}/proxy", safe="")
        print(f"Web viewer: http://127.0.0.1:{port}/?url={data_url}  (Ctrl-C to stop)", flush=True)
    else:
        if not _has_display():
            raise RuntimeError(
                "the native viewer needs a display (no DISPLAY is set); use `tflock view --web`"
            )
        cmd = [*rerun_executable(), str(path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL)
    try:
        proc.wait()
    except KeyboardInterrupt:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
