"""Li-Wang adaptive-velocity model in 2D and 3D (DESIGN.md section 3.2; papers/002, Li & Wang, PRE 75, 021917).

State: positions X_i, unit directions d_i and local polarities phi_i. One step k -> k+1 (dt = 1):

1. move, eqs. (5) and (8): X_i(k+1) = X_i(k) + v0 c(phi_i(k)) d_i(k), with c(phi) = phi^alpha (Fig. 2);
   alpha = "inf" is eq. (6): c = 1 where phi >= 1 - tol and 0 elsewhere (tol of
   :func:`~tflock.models.adaptive_params.agreement_tolerance`: 1e-6 at f64, 1e-5 at f32);
2. neighbours Gamma_i(k+1) = {j : |X_j(k+1) - X_i(k+1)| <= R}, i itself included (minimum image when periodic);
3. eqs. (4), (7), (9): m_i = mean of d_j(k) over Gamma_i(k+1); phi_i(k+1) = |m_i| (clamped to 1 against
   rounding), d_i(k+1) = m_i / |m_i| (d_i(k) kept when m_i = 0);
4. noise, eq. (12): in 2D d_i(k+1) is turned by xi ~ U[-eta, eta] (``Stream.NOISE``); in 3D, where the paper
   defines none, it is drawn uniformly in the spherical cap of half-angle eta around m_i / |m_i| (cos of the
   polar angle uniform in [cos eta, 1] from ``Stream.NOISE``, azimuth from ``Stream.NOISE_2``). phi is unchanged.

Initialisation (section IV): X(0) uniform in [0, L)^d (``INIT_X/Y/Z``), directions uniform on the circle or the
sphere (``INIT_HEADING``, and ``INIT_HEADING_2`` for the 3D azimuth), then phi_i(0), d_i(0) from eq. (4) with the
neighbours at X(0), without noise. Open space (the paper's) has no walls: the neighbour grid hashes cells, so
agents may spread without bound; ``periodic`` wraps into [0, L)^d.
"""

import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.engine import EngineInfo
from tflock.field import UNIT_VECTORS
from tflock.frame import Frame, WorldSpec, arrow_length
from tflock.metrics import NeighbourGraph
from tflock.models.adaptive_params import AdaptiveParams, agreement_tolerance
from tflock.models.base import GridModel
from tflock.neighbors import CellGrid, load_cell, load_vec, same_cell, span_agents, span_count, stencil_span
from tflock.reductions import BLOCK, n_blocks
from tflock.reference.adaptive import initial_draws
from tflock.rng import Stream, replica_key, uniform_ti
from tflock.space import OPEN, PERIODIC, boundary_code, displacement, wrap_periodic

TWO_PI = 2 * math.pi
#: mean speed / v0 at which the transient ends (the paper's tau: 98 % of v0)
TRANSIENT_SPEED = 0.98
#: converged: one cluster (S = 1) and Phi_theta >= 1 - CONVERGED_TOL
CONVERGED_TOL = 1e-3
FINITE, INFINITE = 0, 1


@ti.func
def speed_coefficient(phi, alpha, tol, mode: ti.template()):
    """c_alpha(phi) = phi^alpha (Fig. 2); mode INFINITE: eq. (6), 1 where phi >= 1 - tol, else 0."""
    c = 0.0
    if ti.static(mode == INFINITE):
        c = ti.select(phi >= 1.0 - tol, 1.0, 0.0)
    else:
        c = ti.pow(phi, alpha)
    return c


@ti.func
def cone_noise(m, u, v, cos_eta):
    """Unit vector in the spherical cap of half-angle eta around the unit vector m (3D noise).

    cos of the polar angle = cos_eta + (1 - cos_eta) u, azimuth 2 pi v, in the basis of Duff et al. (2017).
    """
    sign = ti.select(m[2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + m[2])
    b = m[0] * m[1] * a
    b1 = ti.Vector([1.0 + sign * m[0] * m[0] * a, sign * b, -sign * m[0]])
    b2 = ti.Vector([b, sign + m[1] * m[1] * a, -m[1]])
    ct = cos_eta + (1.0 - cos_eta) * u
    st = ti.sqrt(ti.max(0.0, 1.0 - ct * ct))
    azimuth = TWO_PI * v
    return ct * m + (st * ti.cos(azimuth)) * b1 + (st * ti.sin(azimuth)) * b2


@ti.kernel
def _move(n: ti.i32, speed: float, alpha: float, tol: float, box: float, mode: ti.template(),
          boundary: ti.template(), dim: ti.template(), pos: ti.types.ndarray(), dirs: ti.types.ndarray(),
          phi: ti.types.ndarray()):
    """Eqs. (5), (8): X_i += v0 c(phi_i) d_i, wrapped into the box when periodic."""
    for e in range(n):
        q = load_vec(pos, e, dim) + speed * speed_coefficient(phi[e], alpha, tol, mode) * load_vec(dirs, e, dim)
        if ti.static(boundary == PERIODIC):
            q = wrap_periodic(q, box)
        for a in ti.static(range(dim)):
            pos[a, e] = q[a]


@ti.kernel
def _align(t: ti.i32, seed: ti.u32, n: ti.i32, per_replica: ti.i32, radius: float, box: float, noise: float,
           cos_eta: float, with_noise: ti.template(), boundary: ti.template(), dim: ti.template(), nc: ti.i32,
           n_buckets: ti.i32,
           start: ti.types.ndarray(), mixed: ti.types.ndarray(), order: ti.types.ndarray(),
           id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
           payload: ti.types.ndarray(), pos: ti.types.ndarray(), dirs: ti.types.ndarray(), phi: ti.types.ndarray(),
           ids: ti.types.ndarray(), degree: ti.types.ndarray()):
    """Eqs. (4), (7), (9), (12) with the neighbours of the grid's positions; writes the state in cell order, and
    each agent's neighbour count (itself excluded) for the metrics, which then need no pass of their own."""
    for s in range(n):  # d_j(k) in cell order: contiguous reads in the neighbour loop
        e = order[s]
        for a in ti.static(range(dim)):
            payload[a, s] = dirs[a, e]
    for s in range(n):
        r2 = radius * radius
        i = id_sorted[s]
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        acc = ti.Vector([0.0] * dim)
        count = 0.0
        for o in range(ti.static(span_count(boundary, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, dim)
            for k in range(begin, end):
                d = displacement(p, load_vec(pos_sorted, k, dim), box, boundary)
                w = ti.select(d.norm_sqr() <= r2, 1.0, 0.0)  # k == s passes: i itself is in Gamma_i
                if ti.static(boundary == OPEN):
                    if check:
                        w *= same_cell(coords_sorted, k, cell, boundary, dim)
                acc += w * load_vec(payload, k, dim)
                count += w
        m = acc / count
        norm = m.norm()
        new = load_vec(payload, s, dim)
        if norm > 0:
            new = m / norm
        if ti.static(with_noise):
            key, local = replica_key(seed, i, per_replica)
            u = uniform_ti(key, t, local, Stream.NOISE)
            if ti.static(dim == 2):  # eq. (12): turn by xi ~ U[-eta, eta]
                xi = noise * (2.0 * u - 1.0)
                cx, sx = ti.cos(xi), ti.sin(xi)
                new = ti.Vector([cx * new[0] - sx * new[1], sx * new[0] + cx * new[1]])
            else:
                new = cone_noise(new, u, uniform_ti(key, t, local, Stream.NOISE_2), cos_eta)
        for a in ti.static(range(dim)):
            pos[a, s] = p[a]
            dirs[a, s] = new[a]
        phi[s] = ti.min(norm, 1.0)
        ids[s] = i
        degree[s] = ti.cast(count, ti.i32) - 1
        order[s] = s  # element s now holds slot s: the grid's order stays valid for the new arrangement


@ti.kernel
def _order_sums(n: ti.i32, length: ti.i32, alpha: float, tol: float, mode: ti.template(), dim: ti.template(),
                by_agent: ti.template(), slot_of: ti.types.ndarray(), order: ti.types.ndarray(),
                dirs: ti.types.ndarray(), phi: ti.types.ndarray(), partial: ti.types.ndarray()):
    """Per segment of `length` elements (by_agent: agents, element ``order[slot_of[agent]]``, so a segment can be
    one replica of a batch): sum d_i, sum c_i d_i, sum c_i, sum c_i |d_i| (c_i = c_alpha(phi_i))."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        seg = task_at(t)
        if seg >= 0:
            sd = ti.Vector([0.0] * dim)
            sv = ti.Vector([0.0] * dim)
            sc = 0.0
            ss = 0.0
            for k in range(seg * length, ti.min(n, (seg + 1) * length)):
                e = k
                if ti.static(by_agent):
                    e = order[slot_of[k]]
                d = load_vec(dirs, e, dim)
                c = speed_coefficient(phi[e], alpha, tol, mode)
                sd += d
                sv += c * d
                sc += c
                ss += c * d.norm()
            for a in ti.static(range(dim)):
                partial[seg, a] = sd[a]
                partial[seg, dim + a] = sv[a]
            partial[seg, 2 * dim] = sc
            partial[seg, 2 * dim + 1] = ss


@ti.kernel
def _frame_rows(m: ti.i32, alpha: float, tol: float, mode: ti.template(), dim: ti.template(),
                slot: ti.types.ndarray(), order: ti.types.ndarray(),
                pos_sorted: ti.types.ndarray(), dirs: ti.types.ndarray(), phi: ti.types.ndarray(),
                out: ti.types.ndarray()):
    """Rows (position, velocity / v0 = c_alpha(phi) d) of the drawn agents, at their grid slots `slot`."""
    for r in range(m):
        s = slot[r]
        e = order[s]
        c = speed_coefficient(phi[e], alpha, tol, mode)
        for a in ti.static(range(dim)):
            out[r, a] = pos_sorted[a, s]
            out[r, dim + a] = c * dirs[a, e]


class Adaptive(GridModel):
    """Li-Wang adaptive velocity on the cell grid (hashed cells in open space), 2D and 3D.

    The state arrays hold the agents in the cell order of the last step (``ids`` names the agent at each
    element); :meth:`state` returns ``x`` (n, d), ``d`` (n, d) and ``phi`` (n,) in agent order. The transient
    time tau (first step with mean speed >= 0.98 v0) is tracked at every step, from the initial state or the
    last :meth:`set_state`, and reported (NaN before) once reached.

    ``replicas`` > 1 runs that many independent realisations in the same kernel launches: replica r is the run
    with seed ``seed + r`` (bit-identical to running it alone), agent ids are ``r * n + i``, the state arrays
    hold all ``replicas * n`` agents (replica-major in :meth:`state`) and :meth:`replica_metrics` gives the
    metrics of each.
    """

    name = "adaptive"
    draws_ahead = False  # a frame's announcement keeps velocities of the state the drawn step starts from

    @classmethod
    def can_batch(cls, params: AdaptiveParams) -> bool:
        return True

    def __init__(self, params: AdaptiveParams, seed: int, engine: EngineInfo, replicas: int = 1) -> None:
        super().__init__(params, seed, engine)
        self.replicas = replicas
        n, dim, real = params.n * replicas, params.dim, engine.real
        self.n_total = n
        self.metric_descriptions = {
            "phi_theta": "Phi_theta |mean unit direction| (eq. 3)",
            "phi_v": "Phi_v |sum of velocities| / (N v0) (eq. 2)",
            "c_alpha": "C_alpha mean speed coefficient phi^alpha (eq. 11)",
            "mean_speed": "mean speed / v0",
            "clusters": "clusters (components of the R-graph)",
            "largest_cluster": "largest cluster fraction S",
            "mean_neighbors": "mean neighbour count",
            "max_neighbors": "max neighbour count",
            "tau": "transient time tau: first step with mean speed >= 0.98 v0",
            "converged": "converged: S = 1 and Phi_theta >= 0.999",
        }
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = ti.ndarray(ftype, (dim, n))  # component-major, as every kernel array
        self.dirs = ti.ndarray(ftype, (dim, n))
        self.phi = ti.ndarray(ftype, n)
        self.ids = ti.ndarray(ti.i32, n)
        self.payload = ti.ndarray(ftype, (dim, n))  # d_j(k) in cell order
        self.partial = ti.ndarray(ti.f64, (n_blocks(n), 2 * dim + 2))
        self._replica_partial = ti.ndarray(ti.f64, (replicas, 2 * dim + 2))
        self.grid = CellGrid(n, dim, params.boundary, params.box, params.radius, real, replicas)
        self.graph = NeighbourGraph(self.grid)
        self._boundary = boundary_code(params.boundary)
        self._mode = INFINITE if params.alpha == "inf" else FINITE
        self._alpha = 0.0 if params.alpha == "inf" else float(params.alpha)
        self._tol = agreement_tolerance(np.dtype(real).itemsize)
        self._grid_step = -1  # step whose positions the grid holds
        self._last_move: tuple[int, np.ndarray] | None = None  # (step of the frame, velocities) from draw_next
        self.tau = -1  # first step with mean speed >= 0.98 v0; -1 until reached
        self._replica_tau = np.full(replicas, -1)  # the same for each replica of a batch
        draws = [initial_draws(params, seed + r) for r in range(replicas)]
        self._upload(np.concatenate([x for x, _ in draws]), np.concatenate([d for _, d in draws]), np.zeros(n))
        self._ensure_grid()
        self._align(with_noise=False)  # phi_i(0), d_i(0) from eq. (4)
        self._degrees_step = (0,)
        self._track_tau()

    # ------------------------------------------------------------------ state
    def _upload(self, x: np.ndarray, d: np.ndarray, phi: np.ndarray) -> None:
        real = self.engine.real
        self.pos.from_numpy(np.ascontiguousarray(np.asarray(x).T, dtype=real))
        self.dirs.from_numpy(np.ascontiguousarray(np.asarray(d).T, dtype=real))
        self.phi.from_numpy(np.ascontiguousarray(phi, dtype=real))
        self.ids.from_numpy(np.arange(self.n_total, dtype=np.int32))
        self.invalidate()

    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state (``x``, ``d``, ``phi`` as :meth:`state` returns them); tau is tracked anew."""
        self._upload(state["x"], state["d"], state["phi"])
        self.step_index = step
        self.tau = -1
        self._replica_tau[:] = -1
        self._track_tau()

    def state(self) -> dict[str, np.ndarray]:
        ids = self.ids.to_numpy()
        n, dim, real = self.n_total, self.params.dim, self.engine.real
        x = np.empty((n, dim), dtype=real)
        d = np.empty((n, dim), dtype=real)
        phi = np.empty(n, dtype=real)
        x[ids] = self.pos.to_numpy().T
        d[ids] = self.dirs.to_numpy().T
        phi[ids] = self.phi.to_numpy()
        return {"x": x, "d": d, "phi": phi}

    # ------------------------------------------------------------------ stepping

    def _align(self, with_noise: bool) -> None:
        p, g = self.params, self.grid.geometry
        _align(self.step_index, self.seed, self.n_total, p.n, p.radius, p.box, p.noise, math.cos(p.noise),
               with_noise, self._boundary, p.dim, g.cells_per_side, g.n_buckets, self.grid.start, self.grid.mixed,
               self.grid.order, self.grid.id_sorted, self.grid.pos_sorted, self.grid.coords_sorted, self.payload,
               self.pos, self.dirs, self.phi, self.ids, self.graph.degree)

    def advance(self, steps: int) -> None:
        p = self.params
        for _ in range(steps):
            _move(self.n_total, p.speed, self._alpha, self._tol, p.box, self._mode, self._boundary, p.dim, self.pos,
                  self.dirs, self.phi)
            self.grid.build(self.pos, self.ids)  # Gamma_i(k+1) from X(k+1)
            self._align(with_noise=p.noise > 0)
            self.step_index += 1
            self._grid_step = self.step_index  # the step moved no agent after the build
            self._degrees_step = (self.step_index,)  # and its pass counted the neighbours there
            self._track_tau()

    # ------------------------------------------------------------------ metrics
    def _sums(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Mean d, mean c d, mean c and mean c |d| over all agents (deterministic block sums)."""
        p = self.params
        _order_sums(p.n, BLOCK, self._alpha, self._tol, self._mode, p.dim, False, self.grid.slots(),
                    self.grid.order, self.dirs, self.phi, self.partial)
        total = self.partial.to_numpy().sum(axis=0) / p.n
        return total[: p.dim], total[p.dim: 2 * p.dim], float(total[-2]), float(total[-1])

    def _track_tau(self) -> None:
        if self.replicas > 1:
            reached = (self._replica_tau < 0) & (self._replica_sums()["mean_speed"] >= TRANSIENT_SPEED)
            self._replica_tau[reached] = self.step_index
        elif self.tau < 0 and self._sums()[3] >= TRANSIENT_SPEED:
            self.tau = self.step_index

    def _replica_sums(self) -> dict[str, np.ndarray]:
        """Phi_theta, Phi_v, C_alpha and mean speed of each replica of a batch."""
        p = self.params
        self._ensure_grid()
        _order_sums(self.n_total, p.n, self._alpha, self._tol, self._mode, p.dim, True, self.grid.slots(),
                    self.grid.order, self.dirs, self.phi, self._replica_partial)
        means = self._replica_partial.to_numpy() / p.n
        return {"phi_theta": np.linalg.norm(means[:, : p.dim], axis=1),
                "phi_v": np.linalg.norm(means[:, p.dim: 2 * p.dim], axis=1),
                "c_alpha": means[:, -2], "mean_speed": means[:, -1]}

    def replica_metrics(self) -> dict[str, np.ndarray]:
        """:meth:`metrics` of each replica of a batch: one array of length ``replicas`` per metric."""
        p = self.params
        self._ensure_grid()
        out = self._replica_sums()
        out.update(self.graph.compute_replicas(p.radius, p.box, self._step_degrees()))
        tau = self.tau if self.replicas == 1 else self._replica_tau
        out["tau"] = np.where(np.asarray(tau) < 0, np.nan, tau).astype(np.float64).reshape(self.replicas)
        converged = (out["largest_cluster"] == 1.0) & (out["phi_theta"] >= 1 - CONVERGED_TOL)
        out["converged"] = converged.astype(np.float64)
        return {name: out[name] for name in self.metric_descriptions}

    def metrics(self) -> dict[str, float]:
        if self.replicas > 1:
            raise RuntimeError("a batch of replicas has no single set of metrics: use replica_metrics()")
        p = self.params
        self._ensure_grid()
        mean_d, mean_v, c_alpha, speed = self._sums()
        out = {"phi_theta": float(np.linalg.norm(mean_d)), "phi_v": float(np.linalg.norm(mean_v)),
               "c_alpha": c_alpha, "mean_speed": speed}
        out.update(self.graph.compute(p.radius, p.box, self._step_degrees()))
        out["tau"] = math.nan if self.tau < 0 else float(self.tau)
        converged = out["largest_cluster"] == 1.0 and out["phi_theta"] >= 1 - CONVERGED_TOL
        out["converged"] = float(converged)
        return {name: out[name] for name in self.metric_descriptions}

    # ------------------------------------------------------------------ drawing
    def _velocity_rows(self, selected: np.ndarray) -> np.ndarray:
        """Rows (position, c_alpha(phi) d: the velocity / v0 of the next move, eq. 5) of the drawn agents now."""
        p = self.params
        drawing = self.drawing(selected)
        m = len(selected)
        rows = np.zeros((m, 2 * p.dim), dtype=self.grid.real)  # written in place on the CPU: no copy kernel
        if m:
            drawing.locate()
            _frame_rows(m, self._alpha, self._tol, self._mode, p.dim, drawing.slot,
                        self.grid.order, self.grid.pos_sorted, self.dirs, self.phi, rows)
        return rows

    def invalidate(self) -> None:
        super().invalidate()
        self._last_move = None
        # the step whose neighbour counts the step's own pass left in graph.degree (a tuple: checkpoints leave it out)
        self._degrees_step = (-1,)

    def build_neighbours(self) -> None:
        """Rebuild the grid for the same positions: the neighbour counts of the last pass stay the state's."""
        counted = self._degrees_step
        super().build_neighbours()
        self._degrees_step = counted

    def _step_degrees(self) -> ti.Ndarray | None:
        """The neighbour counts the last neighbour pass left, where they are the current state's."""
        return self.graph.degree if self._degrees_step == (self.step_index,) else None

    def draw_next(self, selected: np.ndarray, step: int | None = None) -> None:
        """Keep the drawn agents' velocities of the move the next step makes (eq. 5 uses phi(k) and d(k), which
        that step replaces): the arrows of its frame show the move just made, as every model's do. `step` can only
        be the next (see ``draws_ahead``)."""
        if step is not None and step != self.step_index + 1:
            raise ValueError(f"the adaptive model draws the next step's state ({self.step_index + 1}), not {step}")
        self._last_move = (self.step_index + 1, self._velocity_rows(selected)[:, self.params.dim:])

    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """Agents coloured by heading, arrows of length proportional to the speed v0 phi^alpha of the move just made
        (at the first frame, and one no step announced, the move about to be made)."""
        p = self.params
        rows = self._velocity_rows(selected)
        moved = self._last_move
        velocity = moved[1] if moved is not None and moved[0] == self.step_index else rows[:, p.dim:]
        return Frame(
            positions=rows[:, : p.dim].astype(np.float32),
            directions=velocity.astype(np.float32),
            arrow_length=arrow_length(p.box, len(selected), p.dim,
                                      spread=rows[:, : p.dim] if p.boundary == "open" else None),
            edges=self._edges_among(rows[:, : p.dim], max_edges, p.radius),
            ids=selected,
            fields=self._field_images(field_size, self.pos, self.dirs, UNIT_VECTORS, self.grid),
        )

    def world(self) -> WorldSpec:
        return WorldSpec(dim=self.params.dim, boundary=self.params.boundary, box=self.params.box, dt=self.dt)
