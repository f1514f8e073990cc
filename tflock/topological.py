"""Topological neighbours: the k agents nearest to each agent (Ballerini et al. 2008), found on the cell grid.

Ballerini et al. (PNAS 105, 1232, 2008) found that a starling in a flock interacts with a fixed number of its
nearest neighbours (six to seven), whatever their distance. :func:`nearest` finds them for every agent of a built
:class:`~tflock.neighbors.CellGrid` by growing rings of cells: ring r holds the cells at Chebyshev distance r from
the agent's cell. An agent not yet met lies in a cell at ring r + 1 or beyond, so it is at least (r + m) h away,
where h is the cell side and m the agent's least distance to a face of its own cell in units of h; once the k-th
nearest candidate met so far is closer than that, the k nearest are certain. Otherwise the next ring is searched,
until every cell (of the agent's replica) has been visited: in a periodic box, offsets are taken modulo the box so
that no cell is met twice; in open space, where cells are hashed, until every other agent of its replica was met.

Candidates are ordered by (squared distance, agent id): equal distances are resolved by the smaller id, so the
neighbours do not depend on the order in which cells are visited or on the thread count. Distances follow the
boundary: minimum image in a periodic box.

The cell side is chosen from the mean density (:func:`cell_side`): in a uniform swarm the k-th neighbour then lies
within the first ring for most agents, and a search visits about ``3^d`` cells of a few agents each.

:func:`find_nearest` is the entry point. On the CPU in a 2D periodic or reflecting box (:func:`lane_wise`) it takes
the agents ``WIDTH`` at a time (:func:`_nearest_lanes`): a block of a run of cells shares the run's stencil, which
holds each agent's rings 0 and 1, every lane keeps its own k-best list, and the lanes whose k-th nearest is not
certain after ring 1 are searched again by the rings above (:func:`_redo`). The neighbours, their order and the
rings are those of :func:`nearest`, which searches open space, 3D and GPU arches.
"""

import math

import numpy as np
import taichi as ti

from tflock.engine import current_engine
from tflock.neighbors import (
    CellGrid,
    bucket_of_cell,
    load_cell,
    load_vec,
    run_at,
    run_spans,
    run_wraps,
    same_cell,
    span_agents,
)
from tflock.space import OPEN, PERIODIC, REFLECTING, displacement

#: cell side / the distance within which a uniform swarm of the mean density holds k agents on average (see
#: :func:`cell_side`); set by timing the search at N = 1e6 and k = 6 and 7 (docs/performance.md)
CELL_FACTOR = 1.25
#: the same for the lane-wise search (:func:`find_nearest`), set by timing it at N = 1e6 and k = 6: wider cells put
#: more candidates in a run's stencil, narrower ones leave more lanes to search again
LANE_CELL_FACTOR = 1.4
#: the k-th candidate is certain only when closer than the bound by this relative margin (rounding of squared
#: distances may put an agent just beyond the bound just below it)
CERTAIN_MARGIN = 1e-4
#: id of an empty entry in the k-best list: larger than every agent id
NO_AGENT = 2**31 - 1
#: agents the lane-wise search takes at a time (the blocks of a run of cells; see :func:`_nearest_lanes`): 8 whatever
#: LANES, since LLVM took minutes to compile its k-best lists 16 lanes wide
WIDTH = 8


def cell_side(n: int, k: int, dim: int, box: float, lanes: bool = False) -> float:
    """Cell side for n agents in a box of side `box` (open space: the initial square or cube) with k neighbours:
    CELL_FACTOR (`lanes`: LANE_CELL_FACTOR, for a grid :func:`find_nearest` searches lane-wise) times the radius of
    the disc (sphere) that holds k agents at the mean density."""
    density = n / box**dim
    reach = math.sqrt(k / (math.pi * density)) if dim == 2 else (3 * k / (4 * math.pi * density)) ** (1 / 3)
    return (LANE_CELL_FACTOR if lanes else CELL_FACTOR) * reach


def lane_wise(boundary: int, dim: int) -> bool:
    """Whether :func:`find_nearest` searches a grid of this boundary code and dimension lane-wise: a 2D box
    (periodic or reflecting) on the CPU."""
    engine = current_engine()
    return boundary in (PERIODIC, REFLECTING) and dim == 2 and engine is not None and engine.arch == "cpu"


@ti.func
def _before(d2a, ida, d2b, idb):
    """Whether candidate (d2a, ida) comes before (d2b, idb): nearer, or as near with a smaller id."""
    return (d2a < d2b) | ((d2a == d2b) & (ida < idb))


@ti.func
def _offer(d2, j, slot, best_d, best_id, best_slot, k: ti.template()):
    """Insert candidate (d2, agent j at `slot`) into the sorted k-best lists if it belongs there (the last entry
    drops out); branch-free, so the k entries stay in registers."""
    if _before(d2, j, best_d[k - 1], best_id[k - 1]):
        carry_d, carry_id, carry_slot = d2, j, slot
        for e in ti.static(range(k)):
            swap = _before(carry_d, carry_id, best_d[e], best_id[e])
            old_d, old_id, old_slot = best_d[e], best_id[e], best_slot[e]
            best_d[e] = ti.select(swap, carry_d, old_d)
            best_id[e] = ti.select(swap, carry_id, old_id)
            best_slot[e] = ti.select(swap, carry_slot, old_slot)
            carry_d = ti.select(swap, old_d, carry_d)
            carry_id = ti.select(swap, old_id, carry_id)
            carry_slot = ti.select(swap, old_slot, carry_slot)
    return best_d, best_id, best_slot


@ti.func
def _row_span(c, r, row, seg, nc, boundary: ti.template(), dim: ti.template()):
    """Span `seg` (0 or 1) of row `row` of ring r around cell c in a box layout, as a bucket range [lo, hi) (empty
    when lo == hi). A row fixes the offsets of the axes other than x; a row on the ring's rim is the whole x range
    [-r, r] (seg 1: its part wrapped round a periodic edge), an inner row the two cells x = -r (seg 0) and x = +r
    (seg 1). Periodic offsets of each axis stay in [-(nc // 2), (nc - 1) // 2], reflecting ones inside the box."""
    side = 2 * r + 1
    b = c[dim]  # the replica's block of buckets
    ok = True
    rim = r == 0
    for a in ti.static(range(dim - 1, 0, -1)):  # row-major: the last axis varies slowest
        o = (row // side ** (a - 1)) % side - r
        if ti.abs(o) == r:
            rim = True
        t = c[a] + o
        if ti.static(boundary == PERIODIC):
            if o < -(nc // 2) or o > (nc - 1) // 2:
                ok = False
            t = (t % nc + nc) % nc
        elif t < 0 or t >= nc:
            ok = False
        b = b * nc + t
    b *= nc
    lo_o = -r
    hi_o = r
    if ti.static(boundary == PERIODIC):
        lo_o = ti.max(lo_o, -(nc // 2))
        hi_o = ti.min(hi_o, (nc - 1) // 2)
    else:
        lo_o = ti.max(lo_o, -c[0])
        hi_o = ti.min(hi_o, nc - 1 - c[0])
    x0 = 0
    x1 = -1  # inclusive cell range in x, empty by default
    if ok:
        if rim:
            x0, x1 = c[0] + lo_o, c[0] + hi_o
            if ti.static(boundary == PERIODIC):
                if x0 < 0:  # [x0, x1] wraps left: [0, x1] then [x0 + nc, nc - 1]
                    x0, x1 = ti.select(seg == 0, 0, x0 + nc), ti.select(seg == 0, x1, nc - 1)
                elif x1 >= nc:  # wraps right: [x0, nc - 1] then [0, x1 - nc]
                    x0, x1 = ti.select(seg == 0, x0, 0), ti.select(seg == 0, nc - 1, x1 - nc)
                elif seg == 1:
                    x1 = x0 - 1
            elif seg == 1:
                x1 = x0 - 1
        else:
            o = ti.select(seg == 0, -r, r)
            if lo_o <= o and o <= hi_o:
                x0 = c[0] + o
                if ti.static(boundary == PERIODIC):
                    x0 = (x0 % nc + nc) % nc
                x1 = x0
    lo = 0  # an empty span reads start[0] only: a row outside the box has no valid bucket
    hi = 0
    if x1 >= x0:
        lo = b + x0
        hi = b + x1 + 1
    return lo, hi


@ti.func
def _margin(p, c, cell, boundary: ti.template(), dim: ti.template()):
    """The least distance from position p to a face of its cell c, in cells (at most 0.5)."""
    margin = 0.5
    for a in ti.static(range(dim)):
        f = p[a] / cell - c[a]
        if ti.static(boundary == OPEN):
            f = p[a] / cell - ti.floor(p[a] / cell)
        margin = ti.min(margin, ti.min(f, 1.0 - f))
    return ti.max(margin, 0.0)


@ti.func
def _last_ring(c, nc, boundary: ti.template(), dim: ti.template()):
    """The last ring around cell c with cells in it (box layouts): every cell of the replica is visited by then."""
    last = 0
    if ti.static(boundary == PERIODIC):
        last = nc // 2
    elif ti.static(boundary != OPEN):
        for a in ti.static(range(dim)):
            last = ti.max(last, ti.max(c[a], nc - 1 - c[a]))
    return last


@ti.func
def _search(s, per_replica, box, cell, nc, n_buckets, k: ti.template(), boundary: ti.template(), dim: ti.template(),
            start: ti.template(), mixed: ti.template(), pos_sorted: ti.template(), coords_sorted: ti.template(),
            id_sorted: ti.template(), nbr: ti.template(), rings: ti.template()):
    """The k nearest of the agent at slot s by growing rings of cells (the module's search): ``nbr[:, s]`` and
    ``rings[s]``."""
    p = load_vec(pos_sorted, s, dim)
    c = load_cell(coords_sorted, s, dim)
    margin = _margin(p, c, cell, boundary, dim)
    last = _last_ring(c, nc, boundary, dim)
    best_d = ti.Vector([math.inf] * k)
    best_id = ti.Vector([NO_AGENT] * k, dt=ti.i32)
    best_slot = ti.Vector([-1] * k, dt=ti.i32)
    seen = 0
    r = 0
    done = False
    while not done:
        if ti.static(boundary == OPEN):  # each cell of the ring is hashed on its own
            side = 2 * r + 1
            for q in range(side**dim):
                cell_c = c
                rim = False
                for a in ti.static(range(dim)):
                    o = (q // side**a) % side - r
                    cell_c[a] = c[a] + o
                    if ti.abs(o) == r:
                        rim = True
                if rim:
                    lo = bucket_of_cell(cell_c, nc, n_buckets, boundary, dim)
                    begin, end, check = span_agents(lo, lo + 1, cell_c, start, mixed, coords_sorted, boundary, dim)
                    for kk in range(begin, end):
                        if kk != s and (check == 0 or same_cell(coords_sorted, kk, cell_c, boundary, dim) == 1):
                            d = displacement(p, load_vec(pos_sorted, kk, dim), box, boundary)
                            seen += 1
                            best_d, best_id, best_slot = _offer(d.norm_sqr(), id_sorted[kk], kk, best_d, best_id,
                                                                best_slot, k)
        else:
            for q in range(2 * (2 * r + 1) ** (dim - 1)):
                lo, hi = _row_span(c, r, q // 2, q % 2, nc, boundary, dim)
                for kk in range(start[lo], start[hi]):
                    if kk != s:
                        d = displacement(p, load_vec(pos_sorted, kk, dim), box, boundary)
                        seen += 1
                        best_d, best_id, best_slot = _offer(d.norm_sqr(), id_sorted[kk], kk, best_d, best_id,
                                                            best_slot, k)
        bound = (r + margin) * cell
        if seen >= k and best_d[k - 1] < bound * bound * (1.0 - CERTAIN_MARGIN):
            done = True
        if ti.static(boundary == OPEN):
            if seen >= per_replica - 1:
                done = True
        elif r >= last:
            done = True
        r += 1
    for e in ti.static(range(k)):
        nbr[e, s] = best_slot[e]
    rings[s] = r


@ti.kernel
def nearest(n: ti.i32, per_replica: ti.i32, box: float, cell: float, nc: ti.i32, n_buckets: ti.i32,
            k: ti.template(), boundary: ti.template(), dim: ti.template(), start: ti.types.ndarray(),
            mixed: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
            id_sorted: ti.types.ndarray(), nbr: ti.types.ndarray(), rings: ti.types.ndarray()):
    """``nbr[e, s]``: the grid slot of the e-th nearest agent to the agent at slot s (e = 0 the nearest), for
    every slot of a grid whose cells have side `cell` (``nc`` per side in a box); ``rings[s]``: the rings its search
    visited (for the benchmarks and tests). One agent at a time: any layout and arch."""
    for s in range(n):
        _search(s, per_replica, box, cell, nc, n_buckets, k, boundary, dim, start, mixed, pos_sorted, coords_sorted,
                id_sorted, nbr, rings)


@ti.func
def _offer_lanes(begin, end, p, me, best_d, best_id, best_slot, box, pos_sorted: ti.template(),
                 id_sorted: ti.template(), k: ti.template(), minimum_image: ti.template(), packed: ti.template(),
                 dim: ti.template()):
    """Offer the candidates at slots [begin, end) to each lane's k-best list (lane q: the agent at slot me[q] and
    position p[:, q]), a lane's own slot excepted; branch-free, one sorted list per lane. `packed` (f32): an entry's
    squared distance and id are one 64-bit key in ``best_d`` (see :func:`_pack`), ``best_id`` is unused."""
    metric = ti.static(PERIODIC if minimum_image else REFLECTING)  # REFLECTING: the plain difference
    for kk in range(begin, end):
        j = id_sorted[kk]
        for q in ti.static(range(WIDTH)):
            d = displacement(p[0, q], pos_sorted[0, kk], box, metric)
            d2 = d * d
            for a in ti.static(range(1, dim)):
                d = displacement(p[a, q], pos_sorted[a, kk], box, metric)
                d2 = d2 + d * d
            own = me[q] == kk
            cd = ti.select(own, math.inf, d2)
            cid = ti.select(own, NO_AGENT, j)
            lt = _precedes(cd, cid, best_d, best_id, q, k, packed)
            if ti.static(packed):
                best_d = _shift_in(best_d, lt, _pack(cd, cid), q, k)
            else:
                best_d = _shift_in(best_d, lt, cd, q, k)
                best_id = _shift_in(best_id, lt, cid, q, k)
            best_slot = _shift_in(best_slot, lt, kk, q, k)
    return best_d, best_id, best_slot


@ti.func
def _precedes(d2, j, best_d, best_id, q, k: ti.template(), packed: ti.template()):
    """Per entry e of column q of the lists: whether candidate (d2, agent j) comes before it."""
    lt = ti.Vector([0] * k, dt=ti.i32)
    if ti.static(packed):
        key = _pack(d2, j)
        for e in ti.static(range(k)):
            lt[e] = key < best_d[e, q]
    else:
        for e in ti.static(range(k)):
            lt[e] = _before(d2, j, best_d[e, q], best_id[e, q])
    return lt


@ti.func
def _shift_in(best, lt, value, q, k: ti.template()):
    """Column q of a (k, WIDTH) sorted list with `value` put in where the candidate belongs (``lt[e]``: it comes
    before entry e): entry e takes it where it comes before entry e but not before entry e - 1, entry e - 1 where it
    comes before both. Every new entry reads the old list only (no chain through the list, which LLVM's vectoriser
    would leave scalar)."""
    for e in ti.static(range(k - 1, -1, -1)):
        if ti.static(e == 0):
            best[e, q] = ti.select(lt[e], value, best[e, q])
        else:
            best[e, q] = ti.select(lt[e], ti.select(lt[e - 1], best[e - 1, q], value), best[e, q])
    return best


@ti.func
def _empty_lists(k: ti.template(), packed: ti.template()):
    """``best_d``, ``best_id``, ``best_slot`` of k empty entries for each lane (see :func:`_offer_lanes`)."""
    best_id = ti.Matrix([[NO_AGENT] * WIDTH for _ in ti.static(range(k))], dt=ti.i32)
    best_slot = ti.Matrix([[-1] * WIDTH for _ in ti.static(range(k))], dt=ti.i32)
    if ti.static(packed):
        return ti.Matrix([[_pack(math.inf, NO_AGENT)] * WIDTH for _ in ti.static(range(k))], dt=ti.i64), best_id, \
            best_slot
    else:
        return ti.Matrix([[math.inf] * WIDTH for _ in ti.static(range(k))]), best_id, best_slot


@ti.func
def _pack(d2, j):
    """One 64-bit integer whose order is that of (float32 squared distance d2 >= 0, agent id j): the bits of a
    non-negative float32 are ordered as its values."""
    return (ti.cast(ti.bit_cast(ti.cast(d2, ti.f32), ti.i32), ti.i64) << 32) | ti.cast(j, ti.i64)


@ti.func
def _distance(entry, packed: ti.template()):
    """The squared distance of a ``best_d`` entry: itself, or the float32 of a :func:`_pack` key."""
    if ti.static(packed):
        return ti.bit_cast(ti.cast(entry >> 32, ti.i32), ti.f32)
    else:
        return entry


@ti.kernel
def _nearest_lanes(total_buckets: ti.i32, box: float, cell: float, nc: ti.i32, k: ti.template(),
                   boundary: ti.template(), packed: ti.template(), dim: ti.template(), start: ti.types.ndarray(),
                   run_end: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                   id_sorted: ti.types.ndarray(), nbr: ti.types.ndarray(), rings: ti.types.ndarray()):
    """:func:`nearest` for a box grid on the CPU, ``WIDTH`` agents at a time: the agents of a run of cells
    (:meth:`~tflock.neighbors.CellGrid.runs`), in blocks of WIDTH, share the run's 3^d stencil of cells, which holds
    every agent's rings 0 and 1, and each lane keeps its own k-best list (`packed`: as :func:`_pack` keys, for f32).
    A lane whose k-th nearest is then certain (within the bound ring 1 gives) has its k nearest; the others (a few
    per cent in a uniform swarm) get ``rings[s] = 0``, and :func:`_redo` searches them again by :func:`nearest`'s
    rings from scratch. The lists, the bound and the order are the scalar search's, so the neighbours and ``rings``
    are the same as :func:`nearest`'s."""
    for b in range(total_buckets):
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        wraps = run_wraps(row, x0, x1, nc, boundary)
        for block in range((a1 - a0 + WIDTH - 1) // WIDTH):
            i0 = a0 + block * WIDTH
            p = ti.Matrix([[pos_sorted[a, ti.min(i0 + q, a1 - 1)] for q in ti.static(range(WIDTH))]
                           for a in ti.static(range(dim))])
            me = ti.Vector([ti.min(i0 + q, a1 - 1) for q in ti.static(range(WIDTH))], dt=ti.i32)
            best_d, best_id, best_slot = _empty_lists(k, packed)
            for r in range(ti.static(3 ** (dim - 1))):
                b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, boundary, dim)
                for h in range(2):
                    begin = ti.select(h == 0, b0, b1)
                    end = ti.select(h == 0, e0, e1)
                    if wraps:
                        best_d, best_id, best_slot = _offer_lanes(begin, end, p, me, best_d, best_id, best_slot, box,
                                                                  pos_sorted, id_sorted, k, True, packed, dim)
                    else:
                        best_d, best_id, best_slot = _offer_lanes(begin, end, p, me, best_d, best_id, best_slot, box,
                                                                  pos_sorted, id_sorted, k, False, packed, dim)
            for q in ti.static(range(WIDTH)):
                s = i0 + q
                if s < a1:
                    c = load_cell(coords_sorted, s, dim)
                    margin = _margin(load_vec(pos_sorted, s, dim), c, cell, boundary, dim)
                    last = _last_ring(c, nc, boundary, dim)
                    kth = _distance(best_d[k - 1, q], packed)
                    bound = (0 + margin) * cell
                    first = last == 0 or kth < bound * bound * (1.0 - CERTAIN_MARGIN)  # ring 0 would do
                    bound = (1 + margin) * cell
                    rings[s] = 0  # not certain: searched again by _redo
                    if last <= 1 or kth < bound * bound * (1.0 - CERTAIN_MARGIN):
                        for e in ti.static(range(k)):
                            nbr[e, s] = best_slot[e, q]
                        rings[s] = ti.select(first, 1, 2)


@ti.kernel
def _redo(n: ti.i32, per_replica: ti.i32, box: float, cell: float, nc: ti.i32, n_buckets: ti.i32,
          k: ti.template(), boundary: ti.template(), dim: ti.template(), start: ti.types.ndarray(),
          mixed: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
          id_sorted: ti.types.ndarray(), nbr: ti.types.ndarray(), rings: ti.types.ndarray()):
    """:func:`nearest` for the slots :func:`_nearest_lanes` left uncertain (``rings[s] == 0``)."""
    for s in range(n):
        if rings[s] == 0:
            _search(s, per_replica, box, cell, nc, n_buckets, k, boundary, dim, start, mixed, pos_sorted,
                    coords_sorted, id_sorted, nbr, rings)


def find_nearest(grid: CellGrid, k: int, box: float, nbr: ti.Ndarray, rings: ti.Ndarray) -> None:
    """``nbr[e, s]``, ``rings[s]`` of :func:`nearest` for every slot of a built `grid` whose cells have the side
    :func:`cell_side` gives: lane-wise (:func:`_nearest_lanes`) where :func:`lane_wise` says so, else one agent at
    a time (:func:`nearest`). Both give the same neighbours in the same order, and the same rings."""
    g = grid.geometry
    if lane_wise(g.boundary, g.dim):
        engine = current_engine()
        packed = bool(np.dtype(grid.real) == np.float32 and engine is not None and engine.precision == "f32")
        _nearest_lanes(g.total_buckets, box, g.cell_size, g.cells_per_side, k, g.boundary, packed, g.dim,
                       grid.start, grid.runs(), grid.pos_sorted, grid.coords_sorted, grid.id_sorted, nbr, rings)
        _redo(grid.n, g.agents_per_replica, box, g.cell_size, g.cells_per_side, g.n_buckets, k, g.boundary, g.dim,
              grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, grid.id_sorted, nbr, rings)
    else:
        nearest(grid.n, g.agents_per_replica, box, g.cell_size, g.cells_per_side, g.n_buckets, k, g.boundary, g.dim,
                grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted, grid.id_sorted, nbr, rings)
