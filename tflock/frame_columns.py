"""Small frames gathered and handed to Rerun as columns (DESIGN.md section 5, the Rerun layout).

Logging a frame costs Rerun's Python side about a millisecond whatever its size (building four archetypes and
four log calls), which is most of a small swarm's step when every step is drawn. :class:`FrameColumns` keeps the
per-step parts of small frames (the agents' positions and colours, the heading arrows, the neighbour edges and the
profiles' bar charts) and sends each entity's rows with one ``send_columns`` call for many steps: the first frame
at once, then every :data:`GATHER_FRAMES` frames or :data:`GATHER_S` seconds after the first one waiting, and
whenever the recorder flushes or closes (so a run stopped with Ctrl-C keeps every frame it drew). The recording
holds the same rows on the same timelines as one log call per frame would write; what does not change from frame to
frame (point radii, draw order, the edges' colour) is logged by the recorder when it changes. A frame's other
shapes (the leader, markers such as the virtual agent and its circle) are gathered the same way, each entity's
per-step components (positions, arrow vectors, strips) in its own columns.
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun._unions import build_dense_union
from rerun.encodings import TensorDataBatch

#: frames of at most this many drawn agents are gathered; larger ones are logged as they come
GATHER_AGENTS = 2048
#: gathered frames are sent after this many, or this many seconds after the first one waiting (Rerun's own batcher
#: writes what it holds every 0.2 s: a run killed outright loses at most about twice that)
GATHER_FRAMES, GATHER_S = 256, 0.2


@functools.cache
def _strips_type(dim: int) -> pa.DataType:
    """Arrow type of a LineStrip2D/3D batch, taken from an empty batch (the public way to get it)."""
    batch = rr.components.LineStrip2DBatch if dim == 2 else rr.components.LineStrip3DBatch
    return batch(np.zeros((0, 2, dim), np.float32)).as_arrow_array().type


def line_strips(points: np.ndarray) -> pa.ListArray:
    """An (S, K, dim) float32 array as S line strips of K points each, built directly in Arrow.

    Equal to what ``LineStrips2D(points)`` builds, but that path computes the offsets in a Python loop, one
    iteration a strip; here they are one NumPy range.
    """
    n, k, dim = points.shape
    strips_type = _strips_type(dim)
    flat = pa.FixedSizeListArray.from_arrays(pa.array(points.reshape(-1)), type=strips_type.value_type)
    offsets = pa.array(np.arange(0, k * n + 1, k, dtype=np.int32))
    return pa.ListArray.from_arrays(offsets, flat, type=strips_type)


def time_columns(steps: np.ndarray, dt: float) -> list[rr.TimeColumn]:
    """The recording's two timelines for rows at these steps: ``step`` and ``time`` (step x dt)."""
    at = np.asarray(steps, dtype=np.int64)
    return [rr.TimeColumn("step", sequence=at), rr.TimeColumn("time", duration=at * dt)]


def bar_chart_rows(values: np.ndarray) -> pa.Array:
    """Rows of ``BarChart:values`` (Rerun TensorData, a 1D f32 tensor each) for `values` (K, bins): one array for K
    charts, where Rerun's Python API builds one chart per call."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    k, bins = values.shape
    dtype = TensorDataBatch._ARROW_DATATYPE
    shape = pa.ListArray.from_arrays(pa.array(np.arange(k + 1, dtype=np.int32)),
                                     pa.array(np.full(k, bins, dtype=np.uint64)), type=dtype.field("shape").type)
    lists = pa.ListArray.from_arrays(pa.array(np.arange(0, k * bins + 1, bins, dtype=np.int32)),
                                     pa.array(values.ravel()))
    buffer = build_dense_union(dtype.field("buffer").type, "F32", lists)
    names = pa.nulls(k, type=dtype.field("names").type)
    return pa.StructArray.from_arrays([shape, names, buffer], fields=list(dtype))


class Shape(NamedTuple):
    """One entity's per-step components in a frame: ``archetype.columns(**data)`` for one step, where the data are
    (k, dim) f32 arrays (``positions``; ``origins`` and ``vectors``) or (S, K, dim) line strips (``strips``)."""

    archetype: type  # rr.Points2D/3D, rr.Arrows2D/3D or rr.LineStrips2D/3D
    data: dict[str, np.ndarray]


def _shape_columns(shapes: list[Shape]) -> tuple[object, list[int]]:
    """The columns of one entity's shapes over several steps, and each step's rows."""
    archetype = shapes[0].archetype
    if "strips" in shapes[0].data:
        strips = [s.data["strips"] for s in shapes]
        return archetype.columns(strips=line_strips(np.concatenate(strips))), [len(a) for a in strips]
    data = {name: np.concatenate([s.data[name] for s in shapes]) for name in shapes[0].data}
    return archetype.columns(**data), [len(next(iter(s.data.values()))) for s in shapes]


class _Gathered(NamedTuple):
    """One frame's per-step parts."""

    step: int
    positions: np.ndarray  # (m, dim) f32
    colors: np.ndarray  # (m,) packed RGBA
    vectors: np.ndarray  # (m, dim) f32
    edges: np.ndarray | None  # (E, 2, dim) f32, None where the frame draws none
    profiles: dict[str, np.ndarray]  # bar chart values (f32)
    shapes: dict[str, Shape]  # the frame's other entities


class FrameColumns:
    """The small frames of a recording not yet handed to Rerun (see the module)."""

    def __init__(self, rec: rr.RecordingStream, dim: int, dt: float, agents: str, headings: str, edges: str,
                 profiles: str) -> None:
        self.rec, self.dim, self.dt = rec, dim, dt
        self.entities = (agents, headings, edges, profiles)
        self._gathered: list[_Gathered] = []
        self._sent: set[str] = set()  # entities whose columns of the gathered frames went already
        self._since = time.monotonic()
        self._first = True  # the first frame goes at once: a viewer shows the run from its start

    def add(self, step: int, positions: np.ndarray, colors: np.ndarray, vectors: np.ndarray,
            edges: np.ndarray | None, profiles: dict[str, np.ndarray], shapes: dict[str, Shape]) -> None:
        """Keep one frame (`edges`: (E, 2, dim) f32 segments, None where the frame draws none; `shapes`: its other
        entities' per-step components); sent when due. The frame joins the others in one list append, so an
        interrupt (Ctrl-C) leaves it either kept whole or not at all."""
        bars = {name: np.asarray(values, dtype=np.float32) for name, values in profiles.items()}
        gathered = self._gathered
        bins = {name: len(values) for name, values in bars.items()}
        if self._sent or gathered and bins != {name: len(v) for name, v in gathered[0].profiles.items()}:
            self.send()  # a send left unfinished, or another set of bar charts: the gathered frames go first
        if not self._gathered:
            self._since = time.monotonic()
        self._gathered.append(_Gathered(int(step), positions, colors, vectors, edges, bars, shapes))
        if self._first or len(self._gathered) >= GATHER_FRAMES or time.monotonic() - self._since >= GATHER_S:
            self._first = False
            self.send()

    def send(self) -> None:
        """Hand the gathered frames to Rerun, one ``send_columns`` per entity, and forget them. A send interrupted
        (Ctrl-C) is finished by the next, which skips the entities already sent (one sent just as the interrupt
        came may go twice: the same rows again, which the viewer shows as one)."""
        frames = self._gathered
        if not frames:
            return
        indexes = time_columns([f.step for f in frames], self.dt)
        agents, headings, edges, profiles = self.entities
        Points, Arrows, Strips = ((rr.Points2D, rr.Arrows2D, rr.LineStrips2D) if self.dim == 2
                                  else (rr.Points3D, rr.Arrows3D, rr.LineStrips3D))
        sizes = [len(f.positions) for f in frames]
        positions = np.concatenate([f.positions for f in frames])
        colors = np.concatenate([f.colors for f in frames])
        columns = {
            agents: lambda: Points.columns(positions=positions, colors=colors).partition(sizes),
            headings: lambda: Arrows.columns(origins=positions, vectors=np.concatenate([f.vectors for f in frames]),
                                             colors=colors).partition(sizes),
        }
        drawn = [f.edges for f in frames if f.edges is not None]
        if drawn:  # the strips of all frames built at once: building them costs more than their points
            columns[edges] = lambda: Strips.columns(strips=line_strips(np.concatenate(drawn))).partition(
                [0 if f.edges is None else len(f.edges) for f in frames])
        for name in frames[0].profiles:
            columns[f"{profiles}/{name}"] = lambda name=name: rr.BarChart.columns(
                values=bar_chart_rows(np.stack([f.profiles[name] for f in frames])))
        for entity, column in columns.items():
            if entity not in self._sent:
                self.rec.send_columns(entity, indexes=indexes, columns=column())
                self._sent.add(entity)
        for entity in dict.fromkeys(name for f in frames for name in f.shapes):  # in the order they were drawn
            if entity not in self._sent:
                having = [f for f in frames if entity in f.shapes]  # steps that did not draw it keep what was drawn
                rows, sizes = _shape_columns([f.shapes[entity] for f in having])
                self.rec.send_columns(entity, indexes=time_columns([f.step for f in having], self.dt),
                                      columns=rows.partition(sizes))
                self._sent.add(entity)
        self._gathered, self._sent = [], set()
