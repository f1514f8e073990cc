"""The Vicsek model in three dimensions: the vector rule with unit headings on the sphere (DESIGN.md 3.1, issue 29).

State: positions x_i in the box (or open space) and unit directions d_i. One synchronous step t -> t+1 (as Chate,
Ginelli, Gregoire & Raynaud, PRE 77 046113 (2008), run the model in 3D):

1. neighbours N_i(t) from x(t): the agents within R (minimum image when periodic), or the k nearest
   (``neighbours = "topological"``, :mod:`tflock.topological`);
2. m_i = d_i + sum_j d_j over N_i (the vector rule); with vectorial noise, m_i += eta (1 + n_i) xi_i, xi_i a unit
   vector uniform on the sphere (z = 1 - 2u, azimuth 2 pi v);
3. desired direction m_i / |m_i| (d_i kept when m_i = 0); with a turn limit alpha < 180 degrees, d_i turns toward
   it by at most alpha, in the plane of the two (Samiloglu eq. 7 read in 3D);
4. angular noise: the new direction is drawn uniformly in the spherical cap of half-angle eta/2 around it (cos of
   the polar angle uniform in [cos(eta/2), 1] from u, azimuth 2 pi v; the cap of adaptive's 3D noise), so that, as
   U[-eta/2, eta/2] in 2D, eta = 2 pi draws from the whole sphere;
5. move x_i(t+1) = x_i(t) + v0 d_i(t+1), then the boundary: periodic wraps; reflecting mirrors the coordinate and
   flips that component of d_i.

u and v are ``uniform(seed, t, i, Stream.NOISE)`` and ``Stream.NOISE_2``. Initial positions are uniform in the box,
directions uniform on the sphere (adaptive's draw: ``INIT_X/Y/Z``, ``INIT_HEADING``, ``INIT_HEADING_2``). The
rules that average angles (average, relative, laplacian), asynchrony and a leader are 2D only (config errors).
"""

import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.config import VicsekParams
from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.engine import EngineInfo
from tflock.field import UNIT_VECTORS
from tflock.frame import Frame, WorldSpec, arrow_length
from tflock.metrics import NeighbourGraph
from tflock.models.adaptive import cone_noise
from tflock.models.base import GridModel
from tflock.neighbors import CellGrid, load_cell, load_vec, same_cell, span_agents, span_count, stencil_span
from tflock.observables import TransitionObservables
from tflock.reductions import BLOCK, mean, n_blocks
from tflock.reference.adaptive import initial_draws
from tflock.rng import Stream, replica_key, uniform_ti
from tflock.space import OPEN, PERIODIC, REFLECTING, displacement, reflect, wrap_periodic
from tflock.topological import cell_side, nearest

TWO_PI = 2 * math.pi


@ti.kernel
def _payload(n: ti.i32, order: ti.types.ndarray(), dirs: ti.types.ndarray(), payload: ti.types.ndarray()):
    """Directions in cell order: contiguous reads in the neighbour loop."""
    for s in range(n):
        e = order[s]
        for a in ti.static(range(3)):
            payload[a, s] = dirs[a, e]


@ti.func
def turn_toward(d, target, cos_max, sin_max):
    """d turned toward the unit vector `target` by at most the angle whose cosine and sine are given, in the plane
    of the two (for a target exactly opposite d: the plane of d and its first basis vector, as in cone_noise)."""
    c = d.dot(target)
    out = target
    if c < cos_max:
        w = target - c * d
        norm = w.norm()
        if norm > 0:
            w = w / norm
        else:
            sign = ti.select(d[2] >= 0, 1.0, -1.0)
            a = -1.0 / (sign + d[2])
            w = ti.Vector([1.0 + sign * d[0] * d[0] * a, sign * d[0] * d[1] * a, -sign * d[0]])
        out = cos_max * d + sin_max * w
    return out


@ti.kernel
def _step(t: ti.i32, seed: ti.u32, n: ti.i32, per_replica: ti.i32, radius: float, speed: float, noise: float,
          cos_half: float, cos_max: float, sin_max: float, box: float, k: ti.template(), topological: ti.template(),
          vectorial: ti.template(), limited: ti.template(), boundary: ti.template(), nc: ti.i32, n_buckets: ti.i32,
          start: ti.types.ndarray(), mixed: ti.types.ndarray(), id_sorted: ti.types.ndarray(),
          pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), payload: ti.types.ndarray(),
          nbr: ti.types.ndarray(), pos: ti.types.ndarray(), dirs: ti.types.ndarray(), ids: ti.types.ndarray(),
          turn: ti.types.ndarray()):
    """Steps 1-5 for every agent (cell order); the new state is written at each agent's slot."""
    for s in range(n):
        r2 = radius * radius
        i = id_sorted[s]
        p = load_vec(pos_sorted, s, 3)
        d = load_vec(payload, s, 3)
        acc = d
        count = 1.0
        if ti.static(topological):
            for e in ti.static(range(k)):
                acc += load_vec(payload, nbr[e, s], 3)
            count += k
        else:
            c = load_cell(coords_sorted, s, 3)
            for o in range(ti.static(span_count(boundary, 3))):
                lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, 3)
                begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, 3)
                for kk in range(begin, end):
                    w = ti.select(displacement(p, load_vec(pos_sorted, kk, 3), box, boundary).norm_sqr() <= r2, 1.0,
                                  0.0) * ti.select(kk != s, 1.0, 0.0)
                    if ti.static(boundary == OPEN):
                        if check:
                            w *= same_cell(coords_sorted, kk, cell, boundary, 3)
                    acc += w * load_vec(payload, kk, 3)
                    count += w
        key, local = replica_key(seed, i, per_replica)
        u = uniform_ti(key, t, local, Stream.NOISE)
        v = uniform_ti(key, t, local, Stream.NOISE_2)
        if ti.static(vectorial):  # Gregoire-Chate: a unit vector of weight eta (1 + n_i) joins the sum
            z = 1.0 - 2.0 * u
            rho = ti.sqrt(ti.max(0.0, 1.0 - z * z))
            azimuth = TWO_PI * v
            acc += noise * count * ti.Vector([rho * ti.cos(azimuth), rho * ti.sin(azimuth), z])
        norm = acc.norm()
        new = d
        if norm > 0:
            new = acc / norm
        if ti.static(limited):
            new = turn_toward(d, new, cos_max, sin_max)
        if ti.static(not vectorial):
            new = cone_noise(new, u, v, cos_half)
        q = p + speed * new
        if ti.static(boundary == PERIODIC):
            q = wrap_periodic(q, box)
        elif ti.static(boundary == REFLECTING):
            q, flips = reflect(q, box)
            for a in ti.static(range(3)):
                if flips[a] == 1:
                    new[a] = -new[a]
        for a in ti.static(range(3)):
            pos[a, s] = q[a]
            dirs[a, s] = new[a]
        ids[s] = i
        turn[s] = ti.atan2(d.cross(new).norm(), d.dot(new))


@ti.kernel
def _direction_sums(n: ti.i32, dirs: ti.types.ndarray(), partial: ti.types.ndarray()):
    """Sum of the directions over fixed blocks of elements (deterministic, whatever the thread count)."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            acc = ti.Vector([0.0, 0.0, 0.0])
            for e in range(blk * BLOCK, ti.min(n, (blk + 1) * BLOCK)):
                acc += load_vec(dirs, e, 3)
            for a in ti.static(range(3)):
                partial[blk, a] = acc[a]


@ti.kernel
def _frame_rows(m: ti.i32, slot: ti.types.ndarray(), order: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
                dirs: ti.types.ndarray(), out: ti.types.ndarray()):
    """Rows (position, direction) of the drawn agents, at their grid slots `slot`."""
    for r in range(m):
        s = slot[r]
        e = order[s]
        for a in ti.static(range(3)):
            out[r, a] = pos_sorted[a, s]
            out[r, 3 + a] = dirs[a, e]


class Vicsek3D(GridModel):
    """The 3D Vicsek model on the cell grid; ``Vicsek(params, ...)`` builds it for ``params.dim = 3``.

    The state arrays hold the agents in the cell order of the last step (``ids`` names the agent at each element);
    :meth:`state` returns ``x`` (n, 3) and ``d`` (n, 3) in agent order. ``replicas`` > 1 runs that many
    independent realisations in the same kernel launches (replica r is the run with seed + r, bit for bit; agent
    ids ``r * n + i``), with :meth:`replica_metrics`.
    """

    name = "vicsek"

    @classmethod
    def can_batch(cls, params: VicsekParams) -> bool:
        return True

    def __init__(self, params: VicsekParams, seed: int, engine: EngineInfo, replicas: int = 1) -> None:
        super().__init__(params, seed, engine)
        self.replicas = replicas
        n, real = params.n * replicas, engine.real
        self.n_total = n
        self.metric_descriptions = {
            "polarization": "polarization |mean unit heading| (Vicsek order parameter)",
            "mean_neighbors": "mean neighbour count (R-graph)",
            "max_neighbors": "max neighbour count (R-graph)",
            "clusters": "clusters (components of the R-graph)",
            "largest_cluster": "largest cluster fraction S",
            "de_theta": "de_theta mean angle turned per step (rad)",
        }
        self.observables = TransitionObservables(params.n, 3, params.boundary, params.box, params.radius, replicas)
        self.metric_descriptions.update(self.observables.descriptions)
        self.profile_descriptions = self.observables.profile_descriptions
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = ti.ndarray(ftype, (3, n))  # component-major, as every kernel array
        self.dirs = ti.ndarray(ftype, (3, n))
        self.ids = ti.ndarray(ti.i32, n)
        self.turn = ti.ndarray(ftype, n)  # angle turned at the last step, in the arrangement's order
        self.payload = ti.ndarray(ftype, (3, n))  # directions in cell order
        self.topological = params.neighbours == "topological"
        reach = params.radius
        if self.topological:  # cells sized for the k nearest, at least R for the R-graph metrics
            reach = max(reach, cell_side(params.n, params.k, 3, params.box))
        self.nbr = ti.ndarray(ti.i32, (params.k if self.topological else 1, n if self.topological else 1))
        self.rings = ti.ndarray(ti.i32, n if self.topological else 1)
        self.partial = ti.ndarray(ti.f64, (n_blocks(n), 3))
        self.grid = CellGrid(n, 3, params.boundary, params.box, reach, real, replicas)
        self.graph = NeighbourGraph(self.grid)
        self._grid_step = -1
        draws = [initial_draws(params, seed + r) for r in range(replicas)]
        self.set_state({"x": np.concatenate([x for x, _ in draws]), "d": np.concatenate([d for _, d in draws])}, 0)

    # ------------------------------------------------------------------ state
    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state (``x``, ``d`` as :meth:`state` returns them)."""
        real = self.engine.real
        self.pos.from_numpy(np.ascontiguousarray(np.asarray(state["x"]).T, dtype=real))
        self.dirs.from_numpy(np.ascontiguousarray(np.asarray(state["d"]).T, dtype=real))
        self.ids.from_numpy(np.arange(self.n_total, dtype=np.int32))
        self.turn.fill(0)
        self.step_index = step
        self.invalidate()

    def state(self) -> dict[str, np.ndarray]:
        ids = self.ids.to_numpy()
        x = np.empty((self.n_total, 3), dtype=self.engine.real)
        d = np.empty((self.n_total, 3), dtype=self.engine.real)
        x[ids] = self.pos.to_numpy().T
        d[ids] = self.dirs.to_numpy().T
        return {"x": x, "d": d}

    # ------------------------------------------------------------------ stepping
    def advance(self, steps: int) -> None:
        p = self.params
        half = 0.5 * p.noise
        alpha = math.radians(min(p.max_turn_deg, 180.0))
        for _ in range(steps):
            self._ensure_grid()
            grid, g = self.grid, self.grid.geometry
            _payload(self.n_total, grid.order, self.dirs, self.payload)
            if self.topological:
                nearest(self.n_total, p.n, p.box, g.cell_size, g.cells_per_side, g.n_buckets, p.k, g.boundary, 3,
                        grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, grid.id_sorted, self.nbr,
                        self.rings)
            _step(self.step_index, self.seed, self.n_total, p.n, p.radius, p.speed, p.noise, math.cos(half),
                  math.cos(alpha), math.sin(alpha), p.box, p.k, self.topological, p.noise_type == "vectorial",
                  p.max_turn_deg < 180, g.boundary, g.cells_per_side, g.n_buckets, grid.start, grid.mixed,
                  grid.id_sorted, grid.pos_sorted, grid.coords_sorted, self.payload, self.nbr, self.pos, self.dirs,
                  self.ids, self.turn)
            self.step_index += 1

    # ------------------------------------------------------------------ metrics
    def metrics(self) -> dict[str, float]:
        if self.replicas > 1:
            raise RuntimeError("a batch of replicas has no single set of metrics: use replica_metrics()")
        p = self.params
        self._ensure_grid()
        _direction_sums(p.n, self.dirs, self.partial)
        total = self.partial.to_numpy().sum(axis=0)
        out = {"polarization": float(np.linalg.norm(total) / p.n)}
        out.update(self.graph.compute(p.radius, p.box))
        out["de_theta"] = mean(self.turn, p.n)
        out.update({k: float(v[0]) for k, v in self.observables.compute(self.pos, self.ids, total[None]).items()})
        return {name: out[name] for name in self.metric_descriptions}

    def replica_metrics(self) -> dict[str, np.ndarray]:
        """:meth:`metrics` of each replica of a batch: one array of length ``replicas`` per metric."""
        p = self.params
        self._ensure_grid()
        replicas, n = self.replicas, p.n
        d = np.empty((self.n_total, 3))
        d[self.ids.to_numpy()] = self.dirs.to_numpy().T
        mean_d = d.reshape(replicas, n, 3).mean(axis=1)
        out = {"polarization": np.linalg.norm(mean_d, axis=1)}
        out.update(self.graph.compute_replicas(p.radius, p.box))
        # turn is in the arrangement's order, the last grid's slots: replica-major, as the grid's buckets
        out["de_theta"] = self.turn.to_numpy().astype(np.float64).reshape(replicas, n).mean(axis=1)
        out.update(self.observables.compute(self.pos, self.ids, mean_d))
        return {name: out[name] for name in self.metric_descriptions}

    # ------------------------------------------------------------------ drawing
    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """Agents coloured by the hue of their heading's planar angle, arrows along it (the direction of the step
        just made, at unit speed), the field of all agents in three projections."""
        p = self.params
        drawing = self.drawing(selected)
        m = len(selected)
        rows = np.zeros((m, 6), dtype=self.grid.real)  # written in place on the CPU: no copy kernel
        if m:
            drawing.locate()
            _frame_rows(m, drawing.slot, self.grid.order, self.grid.pos_sorted, self.dirs, rows)
        profiles = {}
        if self.observables.enabled:
            _direction_sums(p.n, self.dirs, self.partial)
            profiles = self.observables.frame_profiles(self.pos, self.ids, self.partial.to_numpy().sum(axis=0))
        return Frame(
            positions=rows[:, :3].astype(np.float32),
            directions=rows[:, 3:].astype(np.float32),
            arrow_length=arrow_length(p.box, m, 3, spread=rows[:, :3] if p.boundary == "open" else None),
            edges=self._edges_among(rows[:, :3], max_edges, p.radius),
            ids=selected,
            fields=self._field_images(field_size, self.pos, self.dirs, UNIT_VECTORS, self.grid),
            profiles=profiles,
        )

    def world(self) -> WorldSpec:
        return WorldSpec(dim=3, boundary=self.params.boundary, box=self.params.box, dt=self.dt)

