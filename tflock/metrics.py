"""Order parameters and neighbour-graph metrics computed in kernels over all agents (DESIGN.md section 4).

Reductions are deterministic: floating-point sums run over fixed blocks of agents inside a kernel and the block
partials are added in NumPy (plain sums and means on the CPU: NumPy over the ndarray's memory), so metrics do not
change with the thread count. Clusters are the connected components of the graph |x_i - x_j| <= R, found on a
grid by a lock-free parallel union-find (:mod:`tflock.components`; a small swarm's on one thread, with its degrees,
in one launch); on Vulkan, whose compiler mishandles that union-find, by rounds of smallest labels. Degrees are
counted per agent without atomics, or taken from a model step's own neighbour pass.
"""


import math

import numpy as np
import taichi as ti

from tflock.components import Components, near, pair_sizes, pair_union
from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.engine import current_engine
from tflock.fastmath import sin_cos
from tflock.lane_graph import count_roots
from tflock.neighbors import (
    CellGrid,
    load_cell,
    load_vec,
    same_cell,
    span_agents,
    span_count,
    stencil_span,
)
from tflock.reductions import BLOCK, maximum, mean, n_blocks, scratch
from tflock.rng import Stream, hash_ti, randint_ti
from tflock.space import OPEN, displacement, wrap_pi
from tflock.taichi_host import host_array

#: swarms of at most this many agents take their degrees and components (and Vicsek's heading and pair sums) in one
#: launch on one CPU thread (:func:`_small_graph`, :func:`_small_orders`): the parallel passes' launches cost more
#: than the arithmetic
SMALL_GRAPH_MAX = 128


@ti.kernel
def _angle_block_sums(theta: ti.types.ndarray(), n: ti.i32, reference: float, partial: ti.types.ndarray()):
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            _angle_block(theta, n, reference, partial, blk)


@ti.func
def _angle_block(theta: ti.template(), n, reference, partial: ti.template(), blk):
    """Block blk of BLOCK agents: the sums of cos theta, sin theta and |wrap(theta - reference)|."""
    c = 0.0
    s = 0.0
    gap = 0.0
    for i in range(blk * BLOCK, ti.min(n, (blk + 1) * BLOCK)):  # polynomial sin/cos: the loop vectorises
        sin_th, cos_th = sin_cos(theta[i])
        c += cos_th
        s += sin_th
        gap += ti.abs(wrap_pi(theta[i] - reference))
    partial[blk, 0] = c
    partial[blk, 1] = s
    partial[blk, 2] = gap


def heading_order(theta: ti.Ndarray, n: int, reference: float = 0.0) -> tuple[float, float, float]:
    """Polarization |mean (cos, sin)| (Vicsek 1995 order parameter), circular mean heading in [0, 2 pi), and the
    sum over agents of |wrap(theta - reference)| (e.g. the followers' distance to a leader's heading)."""
    partial = scratch((n_blocks(n), 3), theta.dtype)
    _angle_block_sums(theta, n, reference, partial)
    return _heading_totals(partial, n)


def _heading_totals(partial: ti.Ndarray, n: int) -> tuple[float, float, float]:
    """:func:`heading_order` from its block sums (cos, sin, |gap|)."""
    c, s, gap = host_array(partial).astype(np.float64).sum(axis=0)
    return float(math.hypot(c, s) / n), float(math.atan2(s, c) % (2 * math.pi)), float(gap)


def _on_one_thread(n: int) -> bool:
    """Whether a swarm of n agents takes its small passes in one launch on one thread: at most
    :data:`SMALL_GRAPH_MAX` agents, on the CPU (a GPU thread alone is slow)."""
    engine = current_engine()
    return n <= SMALL_GRAPH_MAX and engine is not None and engine.arch == "cpu"


@ti.func
def _tally(n, parent: ti.template(), size: ti.template(), result: ti.template()):
    """From each slot's root in ``parent``: the component count and the largest component in ``result``
    (``size``: zeros on entry, each root's component size on exit)."""
    for s in range(n):
        ti.atomic_add(size[parent[s]], 1)
    count_roots(n, parent, size, result)


@ti.kernel
def _degrees(n: ti.i32, radius: float, box: float, nc: ti.i32, n_buckets: ti.i32, boundary: ti.template(),
             dim: ti.template(), start: ti.types.ndarray(), mixed: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
             coords_sorted: ti.types.ndarray(), id_sorted: ti.types.ndarray(), degree: ti.types.ndarray()):
    _count_degrees(n, radius, box, nc, n_buckets, boundary, dim, start, mixed, pos_sorted, coords_sorted, id_sorted,
                   degree)


@ti.kernel
def _small_graph(n: ti.i32, radius: float, r2: float, box: float, nc: ti.i32, n_buckets: ti.i32,
                 boundary: ti.template(), dim: ti.template(), strict: ti.template(), start: ti.types.ndarray(),
                 mixed: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                 id_sorted: ti.types.ndarray(), degree: ti.types.ndarray(), parent: ti.types.ndarray(),
                 size: ti.types.ndarray(), pairs: ti.types.ndarray(), result: ti.types.ndarray()):
    """A small swarm's graph metrics in one launch on one thread (a launch costs more than their arithmetic): the
    degrees of :func:`_degrees` and the components of the pairs pass (:func:`tflock.components.pair_union`,
    :func:`~tflock.components.pair_sizes`; `r2` as :class:`~tflock.components.Components` squares R), the same
    integers."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        _count_degrees(n, radius, box, nc, n_buckets, boundary, dim, start, mixed, pos_sorted, coords_sorted,
                       id_sorted, degree)
        pair_union(n, r2, box, nc, n_buckets, strict, boundary, dim, start, mixed, pos_sorted, coords_sorted, parent,
                   pairs)
        pair_sizes(n, parent, size, result)


@ti.func
def _count_degrees(n, radius, box, nc, n_buckets, boundary: ti.template(), dim: ti.template(), start: ti.template(),
                   mixed: ti.template(), pos_sorted: ti.template(), coords_sorted: ti.template(),
                   id_sorted: ti.template(), degree: ti.template()):
    """Each agent's neighbour count (agent order, itself excluded), counted from its own stencil: branch-free,
    no atomics."""
    for s in range(n):
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        count = 0
        for o in range(ti.static(span_count(boundary, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, dim)
            for k in range(begin, end):
                d = displacement(p, load_vec(pos_sorted, k, dim), box, boundary)
                w = ti.select(d.norm_sqr() <= radius * radius, 1, 0) * ti.select(k != s, 1, 0)
                if ti.static(boundary == OPEN):
                    if check:
                        w *= same_cell(coords_sorted, k, cell, boundary, dim)
                count += w
        degree[id_sorted[s]] = count


@ti.kernel
def _identity(n: ti.i32, parent: ti.types.ndarray()):
    for s in range(n):
        parent[s] = s


@ti.kernel
def _label_round(n: ti.i32, radius: float, box: float, nc: ti.i32, n_buckets: ti.i32, boundary: ti.template(),
                 dim: ti.template(), strict: ti.template(), start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                 pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), label: ti.types.ndarray(),
                 label_next: ti.types.ndarray(), round_no: ti.i32, changed: ti.types.ndarray()):
    """One round of the components on Vulkan, with no atomics: each slot's next label is the smallest label among
    itself and its neighbours, then that label's own label (a slot of the same component, so labels jump
    ahead). ``changed[0]`` becomes ``round_no`` when a label dropped. Labels only drop and stay slots of their
    component, so rounds end, each component labelled by its smallest slot: the roots the one-pass union-find
    gives."""
    for s in range(n):
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        m = label[s]
        for o in range(ti.static(span_count(boundary, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, dim)
            for k in range(begin, end):
                d = displacement(p, load_vec(pos_sorted, k, dim), box, boundary)
                w = near(d.norm_sqr(), radius * radius, strict)
                if ti.static(boundary == OPEN):
                    if check:
                        w = w and same_cell(coords_sorted, k, cell, boundary, dim) == 1
                m = ti.select(w, ti.min(m, label[k]), m)
        m = label[m]
        label_next[s] = m
        if m != label[s]:
            changed[0] = round_no  # not a constant: a constant stored here came back set in rounds where no
            # label dropped (Taichi 1.7's Vulkan backend), so the rounds never ended


@ti.kernel
def _finish(n: ti.i32, parent: ti.types.ndarray(), size: ti.types.ndarray(), result: ti.types.ndarray()):
    for s in range(n):
        size[s] = 0
    _tally(n, parent, size, result)


class NeighbourGraph:
    """The R-graph metrics of one grid's agents: each agent's degree (counted by :func:`_degrees`, or handed over
    by a model whose step counts them in its own neighbour pass) and the connected components
    (:class:`~tflock.subcells.SubcellComponents`; on Vulkan, rounds of labels). ``strict``: the graph of
    |x_i - x_j| < R (the potential model's) for the components, instead of <= R."""

    def __init__(self, grid: CellGrid, strict: bool = False) -> None:
        self.grid = grid
        self.strict = strict
        n = grid.n
        self.degree = ti.ndarray(ti.i32, n)  # neighbours of each agent (agent order, itself excluded)
        self._components: Components | None = None  # allocated on first use
        # on Vulkan a lock-free union-find lost every union (clusters came out as lone agents; an atomic in its
        # loops is miscompiled by Taichi 1.7's SPIR-V backend): there the components come from rounds of labels
        engine = current_engine()
        self.in_rounds = engine is not None and engine.arch == "vulkan"
        if self.in_rounds:
            self.parent = ti.ndarray(ti.i32, n)
            self.size = ti.ndarray(ti.i32, n)
            self.result = ti.ndarray(ti.i32, 2)
            self.changed = ti.ndarray(ti.i32, 1)

    def degrees(self, radius: float, box: float) -> ti.Ndarray:
        """Each agent's neighbour count in ``degree`` (agent order)."""
        g, grid = self.grid.geometry, self.grid
        _degrees(grid.n, radius, box, g.cells_per_side, g.n_buckets, g.boundary, g.dim, grid.start, grid.mixed,
                 grid.pos_sorted, grid.coords_sorted, grid.id_sorted, self.degree)
        return self.degree

    def _pairs_with_degrees(self, radius: float, box: float) -> bool:
        """Whether :meth:`compute` takes the degrees and the components in one pairs pass: an earlier call found the
        swarm sparse enough for it (the density is known only after the degrees), by union-find, in the grid's box."""
        found = self._components  # None before the first call, and on Vulkan
        return found is not None and found.radius == radius and found.takes_pairs() and box == self.grid.box

    def _found(self, radius: float) -> Components:
        if self._components is None or self._components.radius != radius:
            self._components = Components(self.grid, radius, self.strict)
        return self._components

    def components(self, radius: float, box: float, mean_degree: float | None = None) -> tuple[int, int]:
        """The number of connected components and the largest one's size; `mean_degree`, where known, picks the
        faster pass (see :class:`~tflock.components.Components`)."""
        if not self.in_rounds:
            return self._found(radius).compute(mean_degree)
        g, grid = self.grid.geometry, self.grid
        _identity(grid.n, self.parent)
        self.changed.fill(0)
        round_no = 0
        while round_no == 0 or self.changed.to_numpy()[0] == round_no:  # labels alternate between parent and size
            round_no += 1
            _label_round(grid.n, radius, box, g.cells_per_side, g.n_buckets, g.boundary, g.dim, self.strict,
                         grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, self.parent, self.size,
                         round_no, self.changed)
            self.parent, self.size = self.size, self.parent  # the new labels are the parents
        _finish(grid.n, self.parent, self.size, self.result)
        clusters, largest = (int(v) for v in self.result.to_numpy())
        return clusters, largest

    def _small(self, radius: float, box: float) -> tuple[int, int]:
        """:meth:`degrees` and :meth:`components` of a swarm of at most :data:`SMALL_GRAPH_MAX` agents, by
        :func:`_small_graph` (the pairs pass, as :class:`~tflock.components.Components` takes it)."""
        g, grid, found = self.grid.geometry, self.grid, self._found(radius)
        _small_graph(grid.n, radius, radius**2, box, g.cells_per_side, g.n_buckets, g.boundary, g.dim, self.strict,
                     grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, grid.id_sorted, self.degree,
                     found.parent, found.size, found.pairs, found.result)
        found.slot_grid = grid
        clusters, largest, _ = (int(v) for v in host_array(found.result))
        return clusters, largest

    def _roots(self) -> tuple[np.ndarray, np.ndarray]:
        """After :meth:`components`: the grid slot and the size of each component's root."""
        if self.in_rounds:
            parent, size, slot_of = self.parent.to_numpy(), self.size.to_numpy(), np.arange(self.grid.n)
        else:
            found = self._components
            parent, size = found.parent.to_numpy(), found.size.to_numpy()
            slot_of = np.arange(self.grid.n)  # the pairs pass's slots are the grid's, the sub-cells' are named
            if found.slot_grid is not self.grid:
                slot_of = found.slot_grid.id_sorted.to_numpy()
        roots = parent == np.arange(self.grid.n)
        return slot_of[roots], size[roots]

    def compute(self, radius: float, box: float, degree: ti.Ndarray | None = None) -> dict[str, float]:
        """Clusters, largest-cluster fraction S and neighbour counts of the grid's current positions; `degree`:
        the agents' neighbour counts, in any order, where the model has them already."""
        n = self.grid.n
        if degree is None and _on_one_thread(n):
            clusters, largest = self._small(radius, box)
            degree = self.degree
            mean_degree = mean(degree, n)
        elif degree is None and self._pairs_with_degrees(radius, box):
            # a sparse swarm (the last call's, with the pairs pass next): its degrees from the same walk
            clusters, largest = self._found(radius).compute_with_degrees(radius, self.degree)
            degree = self.degree
            mean_degree = mean(degree, n)
        else:
            if degree is None:
                degree = self.degrees(radius, box)
            mean_degree = mean(degree, n)
            clusters, largest = self.components(radius, box, mean_degree)
        return {
            "clusters": float(clusters),
            "largest_cluster": largest / n,
            "mean_neighbors": mean_degree,
            "max_neighbors": maximum(degree, n),
        }

    def compute_replicas(self, radius: float, box: float, degree: ti.Ndarray | None = None) -> dict[str, np.ndarray]:
        """:meth:`compute` for each replica of a batched grid (arrays of length ``grid.replicas``); `degree` in
        agent or grid-slot order (both hold each replica's agents together).

        One pass over the whole batch (no edge joins two replicas, so every component lies in one), then the
        per-replica counts in NumPy: a grid's slots hold the replicas one after the other.
        """
        if degree is None:
            degree = self.degrees(radius, box)
        self.components(radius, box, mean(degree, self.grid.n))
        replicas, per = self.grid.replicas, self.grid.geometry.agents_per_replica
        slots, sizes = self._roots()
        replica_of_root = slots // per
        largest = np.zeros(replicas, dtype=np.int64)
        np.maximum.at(largest, replica_of_root, sizes)
        by_replica = degree.to_numpy()[: self.grid.n].reshape(replicas, per)
        return {
            "clusters": np.bincount(replica_of_root, minlength=replicas).astype(np.float64),
            "largest_cluster": largest / per,
            "mean_neighbors": by_replica.sum(axis=1) / per,
            "max_neighbors": by_replica.max(axis=1).astype(np.float64),
        }


#: up to this many agents, e_d and e_theta are exact (all n (n - 1) / 2 pairs); above, estimates
EXACT_PAIRS_MAX = 4096
#: pairs sampled (uniformly, with replacement) for the estimates
SAMPLED_PAIRS = 1 << 16


@ti.func
def _pair_terms(pos: ti.template(), theta: ti.template(), i, j, box, boundary: ti.template(), dim: ti.template()):
    d = displacement(load_vec(pos, i, dim), load_vec(pos, j, dim), box, boundary)
    return d.norm(), ti.abs(wrap_pi(theta[j] - theta[i]))


@ti.kernel
def _pairs_exact(pos: ti.types.ndarray(), theta: ti.types.ndarray(), n: ti.i32, box: float,
                 boundary: ti.template(), dim: ti.template(), partial: ti.types.ndarray()):
    _pair_sums(pos, theta, n, box, boundary, dim, partial)


@ti.kernel
def _small_pairs(pos: ti.types.ndarray(), theta: ti.types.ndarray(), n: ti.i32, box: float,
                 boundary: ti.template(), dim: ti.template(), partial: ti.types.ndarray()):
    """:func:`_pairs_exact` of a small swarm on one thread (a parallel loop waits for Taichi's thread pool)."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        _pair_sums(pos, theta, n, box, boundary, dim, partial)


@ti.kernel
def _small_orders(theta: ti.types.ndarray(), pos: ti.types.ndarray(), n: ti.i32, reference: float, box: float,
                  boundary: ti.template(), dim: ti.template(), headings: ti.types.ndarray(),
                  partial: ti.types.ndarray()):
    """:func:`_angle_block_sums` and :func:`_pairs_exact` of a small swarm in one launch on one thread."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        for blk in range(headings.shape[0]):
            _angle_block(theta, n, reference, headings, blk)
        _pair_sums(pos, theta, n, box, boundary, dim, partial)


@ti.func
def _pair_sums(pos: ti.template(), theta: ti.template(), n, box, boundary: ti.template(), dim: ti.template(),
               partial: ti.template()):
    """partial[i]: the sums of the pair terms of agent i with the later agents (distance, heading difference)."""
    for i in range(n):
        dist = 0.0
        angle = 0.0
        for j in range(i + 1, n):
            a, b = _pair_terms(pos, theta, i, j, box, boundary, dim)
            dist += a
            angle += b
        partial[i, 0] = dist
        partial[i, 1] = angle


#: sampled pairs whose terms :func:`_pairs_sampled` adds in the run's float type, in sample order (few enough that
#: an f32 sum keeps its precision; NumPy adds the blocks in float64)
PAIR_BLOCK = 64
#: sampled pairs whose agents are read before any is used: independent loads the CPU overlaps, where one pair at a
#: time waits on each of its (cache-missing, at large N) reads in turn
PAIRS_IN_FLIGHT = 16


@ti.kernel
def _pairs_sampled(pos: ti.types.ndarray(), theta: ti.types.ndarray(), n: ti.i32, box: float, seed: ti.u32,
                   step: ti.i32, boundary: ti.template(), dim: ti.template(), partial: ti.types.ndarray()):
    """Sums of the pair terms over samples [b PAIR_BLOCK, (b + 1) PAIR_BLOCK) in ``partial[b]``. Sample m is the
    ordered pair (i, j), i != j, drawn uniformly from (seed, step, m): unbiased for the mean over pairs."""
    for b in range(partial.shape[0]):
        dist = 0.0
        angle = 0.0
        for c in range(PAIR_BLOCK // PAIRS_IN_FLIGHT):
            first = ti.Vector([0] * PAIRS_IN_FLIGHT)
            second = ti.Vector([0] * PAIRS_IN_FLIGHT)
            for u in ti.static(range(PAIRS_IN_FLIGHT)):
                m = (b * PAIR_BLOCK + c * PAIRS_IN_FLIGHT) + u
                i = randint_ti(hash_ti(seed, step, m, Stream.PAIR_I), n)
                j = randint_ti(hash_ti(seed, step, m, Stream.PAIR_J), n - 1)
                first[u] = i
                second[u] = ti.select(j >= i, j + 1, j)
            for u in ti.static(range(PAIRS_IN_FLIGHT)):
                a, e = _pair_terms(pos, theta, first[u], second[u], box, boundary, dim)
                dist += a
                angle += e
        partial[b, 0] = dist
        partial[b, 1] = angle


def pairwise_errors(pos: ti.Ndarray, theta: ti.Ndarray, n: int, box: float, boundary: int, dim: int, seed: int,
                    step: int) -> tuple[float, float]:
    """Samiloglu-Gazi-Koku section V: e_d, the mean pairwise distance (minimum image when periodic), and
    e_theta, the mean pairwise circular heading difference |wrap(theta_i - theta_j)| in [0, pi].

    Exact for n <= EXACT_PAIRS_MAX (and then invariant to the order of the agents; on the CPU on one thread up to
    SMALL_GRAPH_MAX agents, the same sums); above, the mean over SAMPLED_PAIRS uniformly drawn pairs of array
    elements (unbiased; drawn from (seed, step, sample), so the estimate is reproducible: the arrays' order is the
    same whatever the thread count).
    """
    if n < 2:
        return 0.0, 0.0
    if n <= EXACT_PAIRS_MAX:
        partial = scratch((n, 2), pos.dtype)
        (_small_pairs if _on_one_thread(n) else _pairs_exact)(pos, theta, n, box, boundary, dim, partial)
        return _pair_means(partial, n)
    partial = scratch((SAMPLED_PAIRS // PAIR_BLOCK, 2), pos.dtype)
    _pairs_sampled(pos, theta, n, box, seed, step, boundary, dim, partial)
    return tuple(host_array(partial).astype(np.float64).sum(axis=0) / SAMPLED_PAIRS)


def orders_and_pairs(theta: ti.Ndarray, pos: ti.Ndarray, n: int, reference: float, box: float, boundary: int,
                     dim: int, seed: int, step: int) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """:func:`heading_order` and :func:`pairwise_errors` of the same state; on the CPU a swarm of at most
    :data:`SMALL_GRAPH_MAX` agents takes both passes in one launch on one thread (:func:`_small_orders`)."""
    if n < 2 or not _on_one_thread(n):
        return heading_order(theta, n, reference), pairwise_errors(pos, theta, n, box, boundary, dim, seed, step)
    headings = scratch((n_blocks(n), 3), theta.dtype)
    partial = scratch((n, 2), pos.dtype)
    _small_orders(theta, pos, n, reference, box, boundary, dim, headings, partial)
    return _heading_totals(headings, n), _pair_means(partial, n)


def _pair_means(partial: ti.Ndarray, n: int) -> tuple[float, float]:
    """e_d and e_theta from each agent's exact pair sums."""
    return tuple(host_array(partial).astype(np.float64).sum(axis=0) / (n * (n - 1) / 2))


@ti.kernel
def _replica_pairs_exact(pos: ti.types.ndarray(), theta: ti.types.ndarray(), per_replica: ti.i32, box: float,
                         boundary: ti.template(), dim: ti.template(), slot_of: ti.types.ndarray(),
                         order: ti.types.ndarray(), partial: ti.types.ndarray()):
    for a in range(partial.shape[0]):  # agent a against the later agents of its replica, in agent order
        dist = 0.0
        angle = 0.0
        ea = order[slot_of[a]]
        for b in range(a + 1, (a // per_replica + 1) * per_replica):
            u, v = _pair_terms(pos, theta, ea, order[slot_of[b]], box, boundary, dim)
            dist += u
            angle += v
        partial[a, 0] = dist
        partial[a, 1] = angle


def replica_pairwise_errors(grid: CellGrid, pos: ti.Ndarray, theta: ti.Ndarray, box: float, boundary: int,
                            dim: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pairwise_errors` (exact) of each replica of a batch whose state arrays follow `grid`'s current
    arrangement (element of agent a = ``order[slot_of[a]]``): arrays e_d and e_theta of length ``grid.replicas``."""
    per = grid.geometry.agents_per_replica
    if per < 2:
        return np.zeros(grid.replicas), np.zeros(grid.replicas)
    partial = scratch((grid.n, 2), pos.dtype)
    _replica_pairs_exact(pos, theta, per, box, boundary, dim, grid.slots(), grid.order, partial)
    sums = host_array(partial).astype(np.float64).reshape(grid.replicas, per, 2).sum(axis=1) / (per * (per - 1) / 2)
    return sums[:, 0], sums[:, 1]
