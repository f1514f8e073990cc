"""Vicsek family of heading-alignment models (DESIGN.md section 3.1).

One synchronous step t -> t+1 for every agent i:

1. neighbours N_i(t) = {j != i : |x_j - x_i| <= R} from the positions x(t) (minimum image when periodic);
2. desired heading by `rule`:
   - ``vector``: Vicsek et al. 1995; Samiloglu-Gazi-Koku strategy 3, eq. (6a): atan2 of the summed unit vectors
     of N_i and i;
   - ``average``: Jadbabaie-Lin-Morse eq. (2); strategy 1, eq. (3a): plain arithmetic mean of the angle values of
     N_i and i (which biases headings toward pi, as 003 section 3.1 explains);
   - ``relative``: strategy 2, eqs. (4a)-(5): theta_i + sum wrap(theta_j - theta_i) / (1 + n_i), wrap into
     [-pi, pi);
   - ``laplacian``: Jadbabaie eqs. (17)-(20) with G = gI: theta_i + (1/g) sum (theta_j - theta_i), g > n;
3. turn limit, 003 eq. (7a): theta_i + clamp(phi, -alpha, alpha), phi the desired turn (eqs. 8-10; wrapped into
   [-pi, pi) for ``vector`` and ``relative``); alpha = 360 degrees is no limit for any rule;
4. noise xi ~ U[-eta/2, eta/2] (Vicsek 1995), then headings are wrapped into [0, 2 pi) (003's convention);
5. move x(t+1) = x(t) + v0 (cos, sin) theta_i(t+1) and apply the boundary (reflecting: mirror the position
   and reflect the heading, 003 section 5.2).

Leader (Jadbabaie section 3, eq. 22): agent 0 keeps its heading theta0 and is never updated by the rule or
the noise (only a reflecting wall turns it); followers count it as a neighbour when within R.
Noise for agent i at step t is ``uniform(seed, t, i, Stream.NOISE)``; initial positions are uniform in the box
and headings uniform in [0, 2 pi), from streams INIT_X, INIT_Y, INIT_HEADING at step 0.
"""


import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.config import VicsekParams
from tflock.engine import EngineInfo
from tflock.metrics import NeighbourGraph, heading_order
from tflock.models.base import Model
from tflock.neighbors import (
    CellGrid,
    SubsetDrawing,
    load_ivec,
    load_vec,
    same_cell,
    span_count,
    stencil_span,
)
from tflock.record import Frame, WorldSpec
from tflock.rng import Stream, uniform_np, uniform_ti
from tflock.space import OPEN, PERIODIC, REFLECTING, boundary_code, displacement, reflect, wrap_periodic

RULES = {"vector": 0, "average": 1, "relative": 2, "laplacian": 3}
VECTOR, AVERAGE, RELATIVE, LAPLACIAN = 0, 1, 2, 3
TWO_PI = 2 * math.pi


def initial_state(params: VicsekParams, seed: int) -> dict[str, np.ndarray]:
    """Positions uniform in [0, box)^2 and headings uniform in [0, 2 pi) (float64; leader heading theta0)."""
    ids = np.arange(params.n)
    x = np.stack([params.box * uniform_np(seed, 0, ids, Stream.INIT_X),
                  params.box * uniform_np(seed, 0, ids, Stream.INIT_Y)], axis=1)
    theta = TWO_PI * uniform_np(seed, 0, ids, Stream.INIT_HEADING)
    if params.leader.enabled:
        theta[0] = math.radians(params.leader.heading_deg) % TWO_PI
    return {"x": x, "theta": theta}


@ti.func
def wrap_pi(a):
    """Angle into [-pi, pi)."""
    return a - TWO_PI * ti.floor((a + math.pi) / TWO_PI)


@ti.func
def wrap_two_pi(a):
    """Angle into [0, 2 pi)."""
    a -= TWO_PI * ti.floor(a / TWO_PI)
    if a >= TWO_PI or a < 0:
        a = 0.0
    return a


@ti.kernel
def _step(t: ti.i32, seed: ti.u32, n: ti.i32, radius: float, speed: float, noise: float, box: float,
          max_turn: float, inv_g: float,
          rule: ti.template(), boundary: ti.template(), leader: ti.template(),
          nc: ti.i32, n_buckets: ti.i32, start: ti.types.ndarray(), order: ti.types.ndarray(),
          id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
          payload: ti.types.ndarray(), pos: ti.types.ndarray(), theta: ti.types.ndarray(), ids: ti.types.ndarray()):
    for s in range(n):  # headings in cell order: contiguous reads in the neighbour loop
        th = theta[order[s]]
        payload[0, s] = ti.cos(th)
        payload[1, s] = ti.sin(th)
        payload[2, s] = th
    r2 = radius * radius
    for s in range(n):  # new state written at slot s: the arrangement becomes this step's cell order
        i = id_sorted[s]
        p = load_vec(pos_sorted, s, 2)
        c = load_ivec(coords_sorted, s, 2)
        th_i = payload[2, s]
        acc_a = 0.0
        acc_b = 0.0
        count = 0.0
        for o in ti.static(range(span_count(boundary, 2))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, 2)
            for k in range(start[lo], start[hi]):
                d = displacement(p, load_vec(pos_sorted, k, 2), box, boundary)
                w = ti.select(d.norm_sqr() <= r2, 1.0, 0.0) * ti.select(k != s, 1.0, 0.0)
                if ti.static(boundary == OPEN):
                    w *= same_cell(coords_sorted, k, cell, boundary, 2)
                if ti.static(rule == VECTOR):
                    acc_a += w * payload[0, k]
                    acc_b += w * payload[1, k]
                elif ti.static(rule == RELATIVE):
                    acc_a += w * wrap_pi(payload[2, k] - th_i)
                else:
                    acc_a += w * payload[2, k]
                count += w
        phi = 0.0  # desired turn, 003 eqs. (8)-(10)
        if ti.static(rule == VECTOR):
            phi = wrap_pi(ti.atan2(acc_b + payload[1, s], acc_a + payload[0, s]) - th_i)
        elif ti.static(rule == AVERAGE):
            phi = (th_i + acc_a) / (1.0 + count) - th_i
        elif ti.static(rule == RELATIVE):
            phi = acc_a / (1.0 + count)
        else:
            phi = inv_g * (acc_a - count * th_i)
        xi = noise * (uniform_ti(seed, t, i, Stream.NOISE) - 0.5)
        new = wrap_two_pi(th_i + ti.math.clamp(phi, -max_turn, max_turn) + xi)
        if ti.static(leader):
            if i == 0:
                new = th_i
        q = p + speed * ti.Vector([ti.cos(new), ti.sin(new)])
        if ti.static(boundary == PERIODIC):
            q = wrap_periodic(q, box)
        elif ti.static(boundary == REFLECTING):
            q, flips = reflect(q, box)
            if flips[0] == 1:
                new = math.pi - new
            if flips[1] == 1:
                new = -new
            new = wrap_two_pi(new)
        pos[0, s] = q[0]
        pos[1, s] = q[1]
        theta[s] = new
        ids[s] = i


@ti.kernel
def _frame_rows(m: ti.i32, selected: ti.types.ndarray(), slot_of: ti.types.ndarray(), order: ti.types.ndarray(),
                pos_sorted: ti.types.ndarray(), theta: ti.types.ndarray(), out: ti.types.ndarray()):
    for r in range(m):
        s = slot_of[selected[r]]
        out[r, 0] = pos_sorted[0, s]
        out[r, 1] = pos_sorted[1, s]
        out[r, 2] = theta[order[s]]


class Vicsek(Model):
    """Vicsek / Jadbabaie / Samiloglu-Gazi-Koku heading alignment on the cell grid (synchronous updates).

    The state arrays hold the agents in the cell order of the last step (``ids`` names the agent at each
    element), so the grid build and the step read and write memory nearly sequentially; :meth:`state` returns
    them in agent order.
    """

    name = "vicsek"
    metric_descriptions = {
        "polarization": "polarization |mean unit heading| (Vicsek order parameter)",
        "mean_heading": "circular mean heading (rad)",
        "mean_neighbors": "mean neighbour count",
        "max_neighbors": "max neighbour count",
        "clusters": "clusters (components of the R-graph)",
        "largest_cluster": "largest cluster fraction S",
    }

    def __init__(self, params: VicsekParams, seed: int, engine: EngineInfo) -> None:
        super().__init__(params, seed, engine)
        if params.leader.enabled:
            self.metric_descriptions = {**self.metric_descriptions,
                                        "leader_error": "mean |heading - leader heading| of followers (rad)"}
        n, real = params.n, engine.real
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = ti.ndarray(ftype, (2, n))  # component-major, as every kernel array
        self.theta = ti.ndarray(ftype, n)
        self.ids = ti.ndarray(ti.i32, n)
        self.payload = ti.ndarray(ftype, (3, n))  # cos, sin, theta in cell order
        self.grid = CellGrid(n, 2, params.boundary, params.box, params.radius, real)
        self.graph = NeighbourGraph(self.grid)
        self._grid_step = -1  # step whose positions the grid holds
        self._drawing: SubsetDrawing | None = None
        self._leader_id = ti.ndarray(ti.i32, 1)  # agent 0
        self._leader_id.fill(0)
        self.set_state(initial_state(params, seed), 0)

    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        real = self.engine.real
        self.pos.from_numpy(np.ascontiguousarray(np.asarray(state["x"]).T, dtype=real))
        self.theta.from_numpy(np.ascontiguousarray(state["theta"], dtype=real))
        self.ids.from_numpy(np.arange(self.params.n, dtype=np.int32))
        self.step_index = step
        self._grid_step = -1

    def state(self) -> dict[str, np.ndarray]:
        ids = self.ids.to_numpy()
        x = np.empty((self.params.n, 2), dtype=self.engine.real)
        theta = np.empty(self.params.n, dtype=self.engine.real)
        x[ids] = self.pos.to_numpy().T
        theta[ids] = self.theta.to_numpy()
        return {"x": x, "theta": theta}

    def _ensure_grid(self) -> None:
        if self._grid_step != self.step_index:
            self.grid.build(self.pos, self.ids)
            self._grid_step = self.step_index

    def advance(self, steps: int) -> None:
        p = self.params
        g = self.grid.geometry
        inv_g = 1.0 / p.g if p.rule == "laplacian" else 0.0
        for _ in range(steps):
            self._ensure_grid()
            _step(self.step_index, self.seed, p.n, p.radius, p.speed, p.noise, p.box,
                  math.radians(p.max_turn_deg), inv_g,
                  RULES[p.rule], boundary_code(p.boundary), p.leader.enabled,
                  g.cells_per_side, g.n_buckets, self.grid.start, self.grid.order, self.grid.id_sorted,
                  self.grid.pos_sorted, self.grid.coords_sorted, self.payload, self.pos, self.theta, self.ids)
            self.step_index += 1

    def metrics(self) -> dict[str, float]:
        p = self.params
        self._ensure_grid()
        polarization, mean_heading = heading_order(self.theta, p.n)
        out = {"polarization": polarization, "mean_heading": mean_heading}
        out.update(self.graph.compute(p.radius, p.box))
        if p.leader.enabled:
            theta = self.state()["theta"].astype(np.float64)
            diff = np.abs((theta[1:] - theta[0] + math.pi) % TWO_PI - math.pi)
            out["leader_error"] = float(diff.mean()) if p.n > 1 else 0.0
        return {name: out[name] for name in self.metric_descriptions}

    def frame(self, selected: np.ndarray, max_edges: int) -> Frame:
        p = self.params
        self._ensure_grid()
        if self._drawing is None or not np.array_equal(self._drawing.selected_ids, selected):
            self._drawing = SubsetDrawing(self.grid, selected)
        rows = self._rows(self._drawing.ids, len(selected))
        leader = leader_direction = None
        if p.leader.enabled:
            x0, y0, th0 = self._rows(self._leader_id, 1)[0]
            leader = np.array([x0, y0], dtype=np.float32)
            leader_direction = np.array([math.cos(th0), math.sin(th0)], dtype=np.float32)
        return Frame(
            positions=rows[:, :2].astype(np.float32),
            directions=np.stack([np.cos(rows[:, 2]), np.sin(rows[:, 2])], axis=1).astype(np.float32),
            arrow_length=0.5 * p.radius,
            edges=self._drawing.edges(p.box, p.radius, max_edges).astype(np.float32),
            leader=leader,
            leader_direction=leader_direction,
            radius=0.15 * p.radius,
        )

    def _rows(self, agents: ti.Ndarray, m: int) -> np.ndarray:
        """(m, 3) rows x, y, theta of agents[:m] (grid current)."""
        out = ti.ndarray(self.pos.dtype, (max(1, m), 3))
        if m:
            _frame_rows(m, agents, self.grid.slot_of, self.grid.order, self.grid.pos_sorted, self.theta, out)
        return out.to_numpy()[:m]

    def world(self) -> WorldSpec:
        return WorldSpec(dim=2, boundary=self.params.boundary, box=self.params.box, dt=self.dt)
