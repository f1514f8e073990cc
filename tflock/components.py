"""Connected components of the R-graph (DESIGN.md section 4: clusters and S), by a lock-free parallel union-find
in one of two passes, whichever suits the swarm's size and density (:class:`Components` picks):

- pairs (sparse swarms, and any swarm of at most SUBCELL_MIN_AGENTS agents): each agent joins its neighbours at
  smaller slots of the model's own grid, a union only where the two roots differ (no atomics but the hooks).
- sub-cells (dense flocks: the adaptive-velocity model's hundreds to over a thousand neighbours each): a sub-cell
  of side at most R / sqrt(dim) holds agents that are all within R of each other, so they are joined without
  looking at pairs; the work is then per pair of neighbouring sub-cells, not per pair of agents. Three passes over
  a grid of sub-cells (:class:`tflock.neighbors.CellGrid` with ``at_most`` cells, built from the model grid's
  cell-sorted positions):

  1. per bucket, no atomics: the bounding box of its agents; when the box's diagonal is within R (as the kernel's
     own float arithmetic computes a distance: every pair's computed distance is then within R too, since rounding
     is monotone), every agent hangs under the bucket's first slot (``merged``). Otherwise (a hash bucket shared by
     several cells, or cells enlarged by the grid's cap) its pairs are tested and joined by one thread.
  2. per bucket, the sub-cells of the half stencil (each pair of cells once, nearest first): two merged buckets
     already in one set are skipped after one root lookup each; otherwise, unless the gap between the two bounding
     boxes exceeds R (exact by the same monotone rounding), their agents are compared until one pair within R joins
     the two sets (merged buckets), or every pair within R is joined (others).
  3. each set's size at its root: one atomic add per merged bucket, one per agent elsewhere.

Roots are smallest slots whatever the thread timing, and the partition is the graph's: the cluster count and the
largest cluster do not depend on the thread count or on the pass.
"""

import itertools
import math

import numpy as np
import taichi as ti

from tflock.engine import current_engine
from tflock.lane_graph import count_roots, local_root
from tflock.neighbors import (
    CellGrid,
    bucket_of_cell,
    load_cell,
    load_vec,
    same_cell,
    span_agents,
    span_count,
    stencil_span,
)
from tflock.reductions import total
from tflock.space import BOUNDARIES, OPEN, PERIODIC, displacement
from tflock.union_find import find_root, union


@ti.func
def near(d2, r2, strict: ti.template()):
    """The graph's test on a squared distance: |r| < R (strict) or |r| <= R."""
    ok = False
    if ti.static(strict):
        ok = d2 < r2
    else:
        ok = d2 <= r2
    return ok


@ti.kernel
def _premerge(total_buckets: ti.i32, r2: float, box: float, strict: ti.template(), boundary: ti.template(),
              dim: ti.template(), start: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
              parent: ti.types.ndarray(), lower: ti.types.ndarray(), upper: ti.types.ndarray(),
              merged: ti.types.ndarray()):
    """Pass 1 (see the module): bounding boxes, and each bucket's agents joined, whole or pair by pair."""
    for b in range(total_buckets):
        lo = start[b]
        hi = start[b + 1]
        merged[b] = 0
        if lo < hi:
            small = load_vec(pos_sorted, lo, dim)
            big = small
            for s in range(lo + 1, hi):
                p = load_vec(pos_sorted, s, dim)
                small = ti.min(small, p)
                big = ti.max(big, p)
            for a in ti.static(range(dim)):
                lower[a, b] = small[a]
                upper[a, b] = big[a]
            if near((big - small).norm_sqr(), r2, strict):
                for s in range(lo, hi):
                    parent[s] = lo
                merged[b] = 1
            else:
                one = 1
                for s in range(lo, hi):
                    parent[s] = s
                    p = load_vec(pos_sorted, s, dim)
                    for k in range(lo, s):
                        if near(displacement(p, load_vec(pos_sorted, k, dim), box, boundary).norm_sqr(), r2,
                                 strict):
                            x = local_root(parent, s)
                            y = local_root(parent, k)
                            parent[ti.max(x, y)] = ti.min(x, y)
                for s in range(lo, hi):
                    one &= ti.select(local_root(parent, s) == lo, 1, 0)
                merged[b] = one


@ti.func
def _gap2(p_lo, p_hi, lower: ti.template(), upper: ti.template(), b, dim: ti.template()):
    """Squared gap between the box [p_lo, p_hi] and bucket b's bounding box (0 along axes where they overlap),
    summed in the order of a distance's norm_sqr; no computed distance between points of the two boxes is
    smaller."""
    g = p_lo * 0.0
    for a in ti.static(range(dim)):
        g[a] = ti.max(0.0, ti.max(lower[a, b] - p_hi[a], p_lo[a] - upper[a, b]))
    return g.norm_sqr()


@ti.kernel
def _join_buckets(total_buckets: ti.i32, r2: float, box: float, nc: ti.i32, n_buckets: ti.i32, wide: ti.i32,
                  strict: ti.template(), boundary: ti.template(), layout: ti.template(), dim: ti.template(),
                  offsets: ti.types.ndarray(), start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                  pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), parent: ti.types.ndarray(),
                  lower: ti.types.ndarray(), upper: ti.types.ndarray(), merged: ti.types.ndarray()):
    """Pass 2 (see the module), over the cell `offsets` of the half stencil, nearest first (so that later, farther
    cells mostly find their set joined already). A bucket shared by several cells (open space) takes its agents
    one at a time, each with its own cell's stencil. `layout`: the grid's (a bounded grid's cells are clipped to
    it, as a reflecting box's); `boundary`: the space's, for distances; `wide`: 1 unless a periodic grid is too
    small for the plain difference of two positions in a stencil to be their minimum image."""
    for b in range(total_buckets):
        lo = start[b]
        hi = start[b + 1]
        if lo < hi:
            shared = 0
            if ti.static(layout == OPEN):
                shared = mixed[b]
            for first in range(lo, ti.select(shared == 1, hi, lo + 1)):
                a_lo = first
                a_hi = ti.select(shared == 1, first + 1, hi)
                c = load_cell(coords_sorted, first, dim)
                for o in range(offsets.shape[0]):
                    t = c
                    ok = True
                    wrapped = False
                    for k in ti.static(range(dim)):
                        v = c[k] + offsets[o, k]
                        if ti.static(layout == PERIODIC):
                            if v < 0 or v >= nc:
                                wrapped = True
                                v = (v % nc + nc) % nc
                        elif ti.static(layout != OPEN):
                            if v < 0 or v >= nc:
                                ok = False
                        t[k] = v
                    lo2 = 0
                    hi2 = 0
                    if ok:
                        b2 = bucket_of_cell(t, nc, n_buckets, layout, dim)
                        if b2 != b:  # pairs within one bucket: joined by pass 1
                            lo2 = start[b2]
                            hi2 = start[b2 + 1]
                        if ti.static(layout == OPEN):
                            if lo2 < hi2 and mixed[b2] == 0:  # a bucket of one other cell: not a neighbour
                                for k in ti.static(range(dim)):
                                    if coords_sorted[k, lo2] != t[k]:
                                        hi2 = lo2
                        # the bounding boxes' gap is a lower bound where distances are plain differences
                        bounded = not wrapped and wide == 1
                        if lo2 < hi2 and bounded:
                            p_lo = ti.Vector([lower[a, b] for a in ti.static(range(dim))])
                            p_hi = ti.Vector([upper[a, b] for a in ti.static(range(dim))])
                            if shared == 1:
                                p_lo = load_vec(pos_sorted, first, dim)
                                p_hi = p_lo
                            if not near(_gap2(p_lo, p_hi, lower, upper, b2, dim), r2, strict):
                                hi2 = lo2
                        both = shared == 0 and merged[b] == 1 and merged[b2] == 1
                        if lo2 < hi2 and both:
                            if find_root(parent, lo) == find_root(parent, lo2):
                                hi2 = lo2
                        done = False
                        s = a_lo
                        while s < a_hi and lo2 < hi2 and not done:
                            p = load_vec(pos_sorted, s, dim)
                            far = False
                            if bounded and a_hi - a_lo > 1:
                                far = not near(_gap2(p, p, lower, upper, b2, dim), r2, strict)
                            if not far:
                                root = find_root(parent, s)
                                for k in range(lo2, hi2):
                                    d2 = displacement(p, load_vec(pos_sorted, k, dim), box, boundary).norm_sqr()
                                    if near(d2, r2, strict):
                                        if parent[k] != root:
                                            root = union(parent, root, k)
                                        if both:  # the two buckets are one set now
                                            done = True
                                            break
                            s += 1


def half_stencil(dim: int, cell: float, radius: float) -> np.ndarray:
    """Offsets (m, dim) of the cells that may hold an agent within `radius` of an agent of cell 0 (cells of side
    `cell`), one of each pair o, -o, nearest first (by the smallest distance between the two cells)."""
    reach = int(radius // cell) + 1  # two agents within R lie at most this many cells apart along an axis
    span = range(-reach, reach + 1)
    out = []
    for o in itertools.product(span, repeat=dim):
        gap2 = sum(max(abs(v) - 1, 0) ** 2 for v in o) * cell * cell
        if o[::-1] > (0,) * dim and gap2 <= radius * radius * (1 + 1e-6):  # last axis first: a positive offset
            out.append((gap2, sum(v * v for v in o), o))
    return np.array([o for _, _, o in sorted(out)], dtype=np.int32).reshape(-1, dim)


@ti.kernel
def _sizes(n: ti.i32, total_buckets: ti.i32, start: ti.types.ndarray(), parent: ti.types.ndarray(),
           merged: ti.types.ndarray(), size: ti.types.ndarray(), result: ti.types.ndarray()):
    """Pass 3: each set's size at its root; result[0] the number of sets, result[1] the largest, result[2] the
    number of occupied buckets."""
    for s in range(n):
        size[s] = 0
    result[2] = 0
    for b in range(total_buckets):
        lo = start[b]
        hi = start[b + 1]
        if lo < hi:
            ti.atomic_add(result[2], 1)
            if merged[b] == 1:
                ti.atomic_add(size[find_root(parent, lo)], hi - lo)
            else:
                for s in range(lo, hi):
                    ti.atomic_add(size[find_root(parent, s)], 1)
    count_roots(n, parent, size, result)


@ti.kernel
def _pair_union(n: ti.i32, r2: float, box: float, nc: ti.i32, n_buckets: ti.i32, strict: ti.template(),
                layout: ti.template(), dim: ti.template(), start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), parent: ti.types.ndarray(),
                pairs: ti.types.ndarray()):
    pair_union(n, r2, box, nc, n_buckets, strict, layout, dim, start, mixed, pos_sorted, coords_sorted, parent, pairs)


@ti.func
def pair_union(n, r2, box, nc, n_buckets, strict: ti.template(), layout: ti.template(), dim: ti.template(),
               start: ti.template(), mixed: ti.template(), pos_sorted: ti.template(), coords_sorted: ti.template(),
               parent: ti.template(), pairs: ti.template()):
    """The pairs pass (see the module) on a model's grid: each slot joins its neighbours at smaller slots;
    ``pairs[s]``: how many there are (their sum is the number of edges)."""
    _pair_walk(n, 0.0, r2, box, nc, n_buckets, strict, layout, dim, start, mixed, pos_sorted, coords_sorted, pairs,
               parent, pairs, pairs, False)


@ti.func
def _pair_walk(n, radius, r2, box, nc, n_buckets, strict: ti.template(), layout: ti.template(), dim: ti.template(),
               start: ti.template(), mixed: ti.template(), pos_sorted: ti.template(), coords_sorted: ti.template(),
               id_sorted: ti.template(), parent: ti.template(), pairs: ti.template(), degree: ti.template(),
               degrees: ti.template()):
    """:func:`pair_union`; where `degrees`, in the same walk over every slot's whole stencil, also each agent's
    degree (tflock.metrics' ``_count_degrees``: its neighbours within `radius`, itself excluded, agent order), where
    two passes would each walk it: the same unions in the same order (the neighbours at smaller slots, within `r2`),
    and the same counts. Without `degrees` only the neighbours at smaller slots are visited."""
    for s in range(n):
        parent[s] = s
    for s in range(n):
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        root = s  # a recent root of s's set: saves walking s's chain for every neighbour
        count = 0
        neighbours = 0
        for o in range(ti.static(span_count(layout, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, layout, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, layout, dim)
            last = ti.min(end, s)
            if ti.static(degrees):
                last = end
            for k in range(begin, last):
                d2 = displacement(p, load_vec(pos_sorted, k, dim), box, layout).norm_sqr()
                same = 1
                if check != 0:
                    same = same_cell(coords_sorted, k, cell, layout, dim)
                if ti.static(degrees):
                    w = ti.select(d2 <= radius * radius, 1, 0) * ti.select(k != s, 1, 0)
                    if ti.static(layout == OPEN):  # as the degree pass tests it
                        w *= same
                    neighbours += w
                if k < s and near(d2, r2, strict) and same == 1:
                    count += 1
                    if parent[k] != root:  # k already hangs under s's root: nothing to merge
                        root = union(parent, root, k)
        pairs[s] = count
        if ti.static(degrees):
            degree[id_sorted[s]] = neighbours


@ti.kernel
def _pair_union_degrees(n: ti.i32, radius: float, r2: float, box: float, nc: ti.i32, n_buckets: ti.i32,
                        strict: ti.template(), layout: ti.template(), dim: ti.template(), start: ti.types.ndarray(),
                        mixed: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                        id_sorted: ti.types.ndarray(), parent: ti.types.ndarray(), pairs: ti.types.ndarray(),
                        degree: ti.types.ndarray()):
    """:func:`_pair_walk` with the degrees."""
    _pair_walk(n, radius, r2, box, nc, n_buckets, strict, layout, dim, start, mixed, pos_sorted, coords_sorted,
               id_sorted, parent, pairs, degree, True)


#: slots per task of :func:`_pair_sizes`: a run of slots with one root adds its length at once
SIZE_CHUNK = 256


@ti.kernel
def _pair_sizes(n: ti.i32, parent: ti.types.ndarray(), size: ti.types.ndarray(), result: ti.types.ndarray()):
    pair_sizes(n, parent, size, result)


@ti.func
def pair_sizes(n, parent: ti.template(), size: ti.template(), result: ti.template()):
    """After :func:`pair_union`: every slot's parent made its root, each root's set size, and result[0] the
    number of sets, result[1] the largest. In a flock neighbouring slots share a root: one atomic add per run of
    them, not per slot, keeps the threads off that root's counter."""
    for s in range(n):
        size[s] = 0
        parent[s] = find_root(parent, s)
    for chunk in range((n + SIZE_CHUNK - 1) // SIZE_CHUNK):
        root = parent[chunk * SIZE_CHUNK]
        run = 0
        for s in range(chunk * SIZE_CHUNK, ti.min(n, (chunk + 1) * SIZE_CHUNK)):
            r = parent[s]
            if r != root:
                ti.atomic_add(size[root], run)
                root = r
                run = 0
            run += 1
        ti.atomic_add(size[root], run)
    count_roots(n, parent, size, result)


#: by arch: (agents a sub-cell holds on average, at least, for the sub-cell pass to beat the pairs pass; agents per
#: occupied sub-cell below which a swarm that took it goes back to pairs, the hysteresis). On CUDA the pairs pass,
#: which also counts the degrees there, stays ahead to denser swarms than on the CPU (an H200, 2026-11-28, Vicsek
#: at 1e7, a run's ms a step, sub-cells against pairs: 17.2 / 15.6 at a mean degree of 22, 18.5 / 18.3 at 42,
#: 17.1 / 23.9 at 83; benchmarks/cuda-subcells-ab.jsonl). Other arches take the CPU's.
SUBCELL_OCCUPANCY = {"cpu": (3.0, 2.0), "cuda": (6.0, 4.0)}
#: the sub-cell pass only for more agents than this: a smaller swarm's pairs pass, however dense, costs less than
#: the sub-cell grid's build and passes (launches, most of it)
SUBCELL_MIN_AGENTS = 256


class Components:
    """Components of the graph |x_i - x_j| <= R (or < R, ``strict``) among the agents of a model's grid, by the
    pairs pass or the sub-cell pass (see the module), chosen from the density: the caller's mean degree where it
    has one, else what the last call saw.

    After :meth:`compute`: ``parent[s] == s`` marks the root of each set and ``size[s]`` its size, s a slot of
    ``slot_grid``, whose ``id_sorted[s]`` is the model grid's slot (the model grid's slots are grouped by replica,
    so s's replica is that slot // agents_per_replica).
    """

    def __init__(self, model_grid: CellGrid, radius: float, strict: bool = False) -> None:
        self.model_grid = model_grid
        self.radius = radius
        self.strict = strict
        n = model_grid.n
        self.parent = ti.ndarray(ti.i32, n)
        self.size = ti.ndarray(ti.i32, n)
        self.result = ti.ndarray(ti.i32, 3)
        self.pairs = ti.ndarray(ti.i32, n)
        self._model_slots = ti.ndarray(ti.i32, n)  # the model grid's slots: the sub-cell grid's agent ids
        self._model_slots.from_numpy(np.arange(n, dtype=np.int32))
        self._subcells: CellGrid | None = None  # allocated on first use
        self.dense = False  # the pass the next call takes without a hint: sub-cells (True) or pairs
        engine = current_engine()
        arch = engine.arch if engine is not None else "cpu"
        self._dense_at, self._sparse_at = SUBCELL_OCCUPANCY.get(arch, SUBCELL_OCCUPANCY["cpu"])
        self.slot_grid = model_grid

    def _occupancy(self, mean_degree: float) -> float:
        """Mean agents per sub-cell of a swarm of that mean degree (sub-cells of side 0.98 R / sqrt(dim))."""
        dim = self.model_grid.geometry.dim
        ball = math.pi if dim == 2 else 4.0 * math.pi / 3.0
        return (mean_degree + 1.0) * (0.98 / math.sqrt(dim)) ** dim / ball

    def compute(self, mean_degree: float | None = None) -> tuple[int, int]:
        """The number of components and the largest one's size, for the model grid's current build."""
        if mean_degree is not None:
            self.dense = self._occupancy(mean_degree) >= self._dense_at
        if not self.takes_pairs():
            return self._by_subcells()
        return self._by_pairs()

    def takes_pairs(self) -> bool:
        """Whether :meth:`compute` without a hint takes the pairs pass (else the sub-cells')."""
        return not (self.dense and self.model_grid.n > SUBCELL_MIN_AGENTS)

    def compute_with_degrees(self, radius: float, degree: ti.Ndarray) -> tuple[int, int]:
        """The pairs pass (whatever the density) that also counts each agent's neighbours within `radius` into
        `degree` (agent order, itself excluded), as tflock.metrics' degree pass counts them."""
        return self._by_pairs(radius, degree)

    def _by_pairs(self, degree_radius: float | None = None, degree: ti.Ndarray | None = None) -> tuple[int, int]:
        grid, g = self.model_grid, self.model_grid.geometry
        if degree is None:
            _pair_union(grid.n, self.radius**2, grid.box, g.cells_per_side, g.n_buckets, self.strict, g.boundary,
                        g.dim, grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, self.parent, self.pairs)
        else:
            _pair_union_degrees(grid.n, degree_radius, self.radius**2, grid.box, g.cells_per_side, g.n_buckets,
                                self.strict, g.boundary, g.dim, grid.start, grid.mixed, grid.pos_sorted,
                                grid.coords_sorted, grid.id_sorted, self.parent, self.pairs, degree)
        _pair_sizes(grid.n, self.parent, self.size, self.result)
        clusters, largest, _ = (int(v) for v in self.result.to_numpy())
        self.slot_grid = grid
        edges = total(self.pairs, grid.n)
        self.dense = self._occupancy(2.0 * edges / grid.n) >= self._dense_at
        return clusters, largest

    def _by_subcells(self) -> tuple[int, int]:
        model_grid = self.model_grid
        if self._subcells is None:
            self._allocate_subcells()
        grid = self._subcells
        grid.build(model_grid.pos_sorted, self._model_slots)
        g = grid.geometry
        if self._offsets_for != g.cell_size:
            table = half_stencil(g.dim, g.cell_size, self.radius)
            self._offsets = ti.ndarray(ti.i32, table.shape)
            self._offsets.from_numpy(table)
            self._offsets_for = g.cell_size
        r2, box, boundary = self.radius**2, model_grid.box, grid.boundary
        _premerge(g.total_buckets, r2, box, self.strict, boundary, g.dim, grid.start, grid.pos_sorted, self.parent,
                  self.lower, self.upper, self.merged)
        wide = boundary != PERIODIC or g.cells_per_side > 2 * (2 * (int(self.radius // g.cell_size) + 1) + 1)
        _join_buckets(g.total_buckets, r2, box, g.cells_per_side, g.n_buckets, int(wide), self.strict, boundary,
                      g.boundary, g.dim, self._offsets, grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted,
                      self.parent, self.lower, self.upper, self.merged)
        _sizes(model_grid.n, g.total_buckets, grid.start, self.parent, self.merged, self.size, self.result)
        clusters, largest, occupied = (int(v) for v in self.result.to_numpy())
        self.slot_grid = grid
        self.dense = model_grid.n / max(1, occupied) >= self._sparse_at
        return clusters, largest

    def _allocate_subcells(self) -> None:
        model_grid = self.model_grid
        g = model_grid.geometry
        code = model_grid.boundary  # the space's boundary, whatever the model grid's layout
        boundary = next(name for name, c in BOUNDARIES.items() if c == code)
        # open space: cells over the swarm's bounding box where they fit (no hash collisions), as the model grids of
        # one replica do
        self._subcells = CellGrid(model_grid.n, g.dim, boundary, model_grid.box, 0.98 * self.radius / math.sqrt(g.dim),
                                  model_grid.real, model_grid.replicas, at_most=True,
                                  bounded=code == OPEN and model_grid.replicas == 1)
        self._offsets: ti.Ndarray | None = None  # half_stencil of the cells of side _offsets_for
        self._offsets_for = -1.0
        buckets = self._subcells.counts.shape[0]  # a bounded grid's buckets, whatever the layout of a build
        ftype = ti.f32 if model_grid.real == np.float32 else ti.f64
        self.lower = ti.ndarray(ftype, (g.dim, buckets))
        self.upper = ti.ndarray(ftype, (g.dim, buckets))
        self.merged = ti.ndarray(ti.i32, buckets)
