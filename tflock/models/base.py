"""The interface every model implements."""

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import taichi as ti

from tflock.engine import EngineInfo
from tflock.field import Field, FieldImage
from tflock.frame import HEADING_LEGEND, RADIUS_EDGES, ColorLegend, Frame, WorldSpec
from tflock.guard import Guarded, first_non_finite
from tflock.neighbors import DrawnEdges, SubsetDrawing


class Lyapunov(NamedTuple):
    """A Lyapunov function of a model's continuous dynamics at the current state, which must not increase:
    ``name`` (its metric's), its kinetic and potential parts."""

    name: str
    kinetic: float
    potential: float

    @property
    def value(self) -> float:
        return self.kinetic + self.potential

    @property
    def scale(self) -> float:
        """The energy it holds, kinetic plus the magnitude of the potential part."""
        return self.kinetic + abs(self.potential)


class Model(ABC):
    """A model owns its state arrays and kernels; it knows nothing of files, CLI or Rerun.

    The simulation loop calls :meth:`advance`, :meth:`metrics` and :meth:`frame`; tests and notebooks use
    :meth:`state` / :meth:`set_state` to compare kernels with the NumPy reference from the same state.
    """

    name: str
    dt: float = 1.0
    #: state arrays of the non-finite guard: attribute name -> quantity (those the model has; agents in ``ids`` order)
    guarded_state: Mapping[str, str] = {"pos": "position", "theta": "heading", "dirs": "heading",
                                        "vel": "velocity", "phi": "velocity"}
    #: metric name -> one-line description, in the order the metrics table uses
    metric_descriptions: Mapping[str, str]
    #: metrics that are angles wrapped into [0, 2 pi): the recording plots them as points (a line would cross the
    #: plot at each wrap)
    angle_metrics: tuple[str, ...] = ()
    #: what a frame's edges join, for the recording's about text
    edges_description: str = RADIUS_EDGES
    #: metrics whose plots the recording puts first, in this order (the run's main quantities: Vicsek with a leader,
    #: the leader error beside the polarization); the metrics table keeps its own order
    first_plots: tuple[str, ...] = ()
    #: name -> description of the 1D profiles each frame carries (Frame.profiles), drawn as bar charts
    profile_descriptions: Mapping[str, str] = {}
    #: what the colours of the drawn agents mean (the recorder draws it beside the world view)
    color_legend: ColorLegend = HEADING_LEGEND
    _edge_finder: DrawnEdges | None = None
    _field: Field | None = None

    @classmethod
    def can_batch(cls, params) -> bool:
        """Whether replicas of this model with these parameters run batched (``replicas=`` in the constructor,
        :meth:`replica_metrics`); see :mod:`tflock.ensemble`."""
        return False

    def __init__(self, params, seed: int, engine: EngineInfo) -> None:
        self.params = params
        self.seed = seed
        self.engine = engine
        self.step_index = 0

    @abstractmethod
    def advance(self, steps: int) -> None:
        """Run `steps` steps."""

    @abstractmethod
    def state(self) -> dict[str, np.ndarray]:
        """A NumPy snapshot of the state (copies)."""

    @abstractmethod
    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state (arrays shaped as :meth:`state` returns them) and the step counter."""

    @abstractmethod
    def metrics(self) -> dict[str, float]:
        """Metrics of the current state over all agents."""

    @abstractmethod
    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """What to draw now: the `selected` agents (sorted ids), up to `max_edges` neighbour edges among them
        (:class:`~tflock.neighbors.DrawnEdges`) and, with `field_size` > 0, the coarse-grained field of all agents
        at most that many pixels a side (:class:`~tflock.field.Field`). Arrows follow the convention of
        :mod:`tflock.frame`: the velocity over the step just made."""

    @abstractmethod
    def world(self) -> WorldSpec:
        """Geometry of the world for the recorder."""

    def _edges_among(self, positions: np.ndarray, max_edges: int, radius: float) -> np.ndarray:
        """Edges within `radius` among the drawn agents at `positions` (their frame rows), at most `max_edges`."""
        if self._edge_finder is None:
            world = self.world()
            self._edge_finder = DrawnEdges(world.dim, world.boundary, world.box, radius, self.engine.real)
        return self._edge_finder.edges(np.asarray(positions), max_edges).astype(np.float32)

    def _field_images(self, size: int, pos: ti.Ndarray, dirs: ti.Ndarray, mode: int, grid=None,
                      row: int = 0, rolled: np.ndarray | None = None) -> list[FieldImage]:
        """The field of all agents (`pos`, `dirs` in the same element order; `grid` built for `pos`), or none for
        size 0; `rolled`: see :meth:`tflock.field.Field.compute`."""
        if size <= 0:
            return []
        world = self.world()
        if self._field is None or self._field.size != size:
            self._field = Field(self.params.n, world.dim, size)
        return self._field.compute(pos, dirs, box=world.box, bounded=world.bounded, grid=grid, mode=mode, row=row,
                                   rolled=rolled)

    def first_non_finite(self) -> tuple[int, str] | None:
        """``(agent, quantity)`` of the smallest agent id with a non-finite position, heading or velocity (one
        kernel pass over each array of :attr:`guarded_state`), or None when the state is finite."""
        guarded = [Guarded(quantity, getattr(self, name)) for name, quantity in self.guarded_state.items()
                   if isinstance(getattr(self, name, None), ti.Ndarray)]
        return first_non_finite(guarded, self.ids)

    def lyapunov(self) -> Lyapunov | None:
        """The Lyapunov function of the model's equations at the current state, for models that have one (the
        integrator-stability guard, :mod:`tflock.stability`, watches it); None for the others."""
        return None

    def step_spread(self) -> tuple[float, float] | None:
        """For models with an integrator that can leave its stable range: how far apart two agents move in one
        step at their current velocities, at least (dt times the largest spread of a velocity component), and the
        length it must stay below (the stability guard's cheap test); None for the others."""
        return None

    def checkpoint(self) -> dict[str, np.ndarray]:
        """Everything the model holds, exactly as held: its ndarrays (alone or in lists, e.g. double buffers,
        the agents' arrangement included) and its plain number attributes (e.g. which buffer is current). With the
        config this is enough to continue bit for bit: the random draws are keyed by (seed, step)."""
        out: dict[str, np.ndarray] = {}
        for name, value in vars(self).items():
            if isinstance(value, ti.Ndarray):
                out[name] = value.to_numpy()
            elif isinstance(value, (list, tuple)) and value and all(isinstance(v, ti.Ndarray) for v in value):
                out.update({f"{name}.{k}": v.to_numpy() for k, v in enumerate(value)})
            elif isinstance(value, (bool, int, float)):
                out[f"attr.{name}"] = np.asarray(value)
        return out

    def restore(self, arrays: Mapping[str, np.ndarray], step: int) -> None:
        """Load what :meth:`checkpoint` wrote (same config) and set the step counter."""
        expected = self.checkpoint()
        if set(arrays) != set(expected) or any(arrays[k].shape != v.shape for k, v in expected.items()):
            raise ValueError("the checkpoint does not match this model and config (arrays differ)")
        for name, value in vars(self).items():
            if isinstance(value, ti.Ndarray):
                value.from_numpy(np.ascontiguousarray(arrays[name]))
            elif isinstance(value, (list, tuple)) and value and all(isinstance(v, ti.Ndarray) for v in value):
                for k, v in enumerate(value):
                    v.from_numpy(np.ascontiguousarray(arrays[f"{name}.{k}"]))
            elif isinstance(value, (bool, int, float)):
                setattr(self, name, type(value)(arrays[f"attr.{name}"]))
        self.step_index = step
        self.invalidate()

    def invalidate(self) -> None:  # noqa: B027 (an optional hook: models without derived data need nothing)
        """Forget data derived from the state (e.g. a neighbour grid) after the state was replaced."""

    #: whether :meth:`draw_next` may name a step further ahead than the next (the run then reaches it in one
    #: ``advance``); False for a model whose announcement reads the state the drawn step starts from
    draws_ahead = True

    def draw_next(self, selected: np.ndarray, step: int | None = None) -> None:  # noqa: B027 (an optional hook)
        """Say that the state of step `step` (default: the next step's) will be drawn, for the `selected` agents
        (sorted ids): a model may gather what :meth:`frame` needs during the step that makes it instead of in passes
        of its own."""


class GridModel(Model):
    """A model whose positions ``pos`` and agent ids ``ids`` feed one cell grid ``grid``, built lazily once per
    step (``_grid_step`` is the step whose positions the grid holds)."""

    _grid_step = -1
    _drawing: SubsetDrawing | None = None
    # the frame draw_next announced, (its step, its drawing), and the rows a step wrote for it, (step, drawing,
    # rows): tuples, which checkpoint() leaves out where it would keep a plain number; a step's unused drawing
    # arguments (bits, word_rank, rows) when it writes no rows
    _announced: tuple[int, SubsetDrawing] | None = None
    _drawn: tuple[int, SubsetDrawing, np.ndarray] | None = None
    _no_draw: tuple[ti.Ndarray, ti.Ndarray, np.ndarray] | None = None

    def _ensure_grid(self) -> None:
        if self._grid_step != self.step_index:
            self.grid.build(self.pos, self.ids)
            self._grid_step = self.step_index

    def invalidate(self) -> None:
        self._grid_step = -1
        self._drawn = None

    def draw_next(self, selected: np.ndarray, step: int | None = None) -> None:
        """Steps that can write the drawn agents' frame rows (the lane-wise CPU steps) do so for the state they make
        (see :meth:`_draw_arguments`); the frame then needs no pass of its own."""
        self._announced = (self.step_index + 1 if step is None else step, self._subset(selected))

    def _draw_arguments(self, layers: int, width: int, made: int | None = None) -> tuple:
        """``(draw, bits, word_rank, rows)`` for a step kernel about to make the state of step `made` (default: the
        next step), if a frame was announced for it: draw = True and fresh rows (layers, M, width) for it to write,
        which :meth:`_rows_written` then returns; else draw = False and unused arrays (a kernel may take draw as an
        i32 or as a template)."""
        announced = self._announced
        made = self.step_index + 1 if made is None else made
        if announced is not None and announced[0] == made and len(announced[1].selected_ids):
            drawing = announced[1]
            rows = np.empty((layers, len(drawing.selected_ids), width), dtype=self.grid.real)
            self._drawn = (made, drawing, rows)
            return True, drawing.bits, drawing.word_rank, rows
        self._drawn = None
        return self._no_draw_arguments(layers, width)

    def _no_draw_arguments(self, layers: int, width: int) -> tuple:
        """:meth:`_draw_arguments` of a step kernel that writes no frame rows (draw = False, unused arrays)."""
        if self._no_draw is None or self._no_draw[2].shape != (layers, 1, width):
            self._no_draw = (ti.ndarray(ti.u32, 1), ti.ndarray(ti.i32, 1),
                             np.zeros((layers, 1, width), dtype=self.grid.real))
        return False, *self._no_draw

    def _rows_written(self, drawing: SubsetDrawing) -> np.ndarray | None:
        """The frame rows the last step wrote for the current state and `drawing`, if it wrote them."""
        drawn = self._drawn
        return drawn[2] if drawn is not None and drawn[0] == self.step_index and drawn[1] is drawing else None

    def build_neighbours(self) -> None:
        """Rebuild the neighbour grid for the current positions (benchmarks time it apart from the step)."""
        self.invalidate()
        self._ensure_grid()

    def drawing(self, selected: np.ndarray) -> SubsetDrawing:
        """The drawn subset on the current grid (its index arrays are uploaded once per subset)."""
        self._ensure_grid()
        return self._subset(selected)

    def _subset(self, selected: np.ndarray) -> SubsetDrawing:
        if self._drawing is None or not np.array_equal(self._drawing.selected_ids, selected):
            self._drawing = SubsetDrawing(self.grid, selected)
        return self._drawing
