"""Uniform cell grid for O(N) fixed-radius neighbour search (DESIGN.md section 2).

Agents are counting-sorted by cell: atomic counts, an exclusive prefix sum written here (Taichi's
``PrefixSumExecutor`` does not run on the CPU backend), a scatter, and then each cell's slice is put in agent id
order (an insertion sort on the CPU, ranks computed in parallel on a GPU) so that the order of neighbours, and
hence every floating-point sum over them, does not depend on thread timing. A query visits the 3^d cells around
an agent's cell.

- periodic / reflecting box: cells of side >= R tile the box (at most ``4 n`` cells); periodic cell indices wrap,
  and a box with fewer than 3 cells per side visits each distinct cell once.
- open space: cells of side R are hashed into a table of about 2n buckets; a bucket may hold several cells, so a
  query keeps only agents whose cell coordinates equal the visited cell (no double counting, no box assumed).
  The build marks the buckets that hold more than one cell (``mixed``): a bucket of one cell is kept or skipped
  whole after one test, and only the agents of a mixed bucket are tested one by one.
- open space, ``bounded`` grids: each build first takes the bounding box of the agents' cells and, when a cube of
  cells over it fits in the hash table's buckets, stores those same cells row-major from its lower corner instead
  of hashing them (layout ``BOUNDED``, queried as a reflecting box is). Neighbouring cells are then neighbours in
  memory and a stencil row is one span, as in a box; a swarm spread too thin for that (stragglers far out) falls
  back to the hash. The cells, and the order in which a query meets them and their agents, are the hash's (the
  two layouts' kernels are compiled apart, though, and fast math may round their sums differently).
- periodic box, ``bounded`` grids: a swarm that fills a small part of a large torus (the formation model's, around
  its virtual agent) would get the box's capped tiling of few, wide cells. Each build instead takes the agents'
  positions relative to one of them (minimum image), and when the window of side-R cells over them fits in the
  tiling's buckets (at least ``WINDOW_MIN_BUCKETS``) and leaves more than R of the torus outside it (so no pair
  meets through the edge in a way the window cannot see), stores those cells row-major (layout ``WINDOW``, queried
  as a reflecting box is, distances by minimum image); otherwise it keeps the tiling.
- replicas: a batch of independent copies of a system (agent id = replica * agents_per_replica + local id)
  shares one grid; the replica is an extra cell coordinate, so no query ever crosses into another replica.
  Each replica's cells are laid out as a lone system's would be, which keeps every neighbour sum in the same
  order as in a run of that replica alone (bit-identical results).

Models loop over neighbours themselves, with the helpers below, inside their own kernels:

    for s in range(n):                      # agents in cell order
        c = load_cell(coords_sorted, s, dim)   # cell coordinates and replica
        for o in range(ti.static(span_count(boundary, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, dim)
            for k in range(begin, end):
                if check:   # open space, a bucket shared by several cells: is k really in `cell`?
                    same = same_cell(coords_sorted, k, cell, boundary, dim)

Kernels compute loop-invariant values inside their parallel loops (the compiler hoists them), never between two
top-level loops: Taichi's CUDA backend keeps such values in a global buffer and stored them misaligned at f64
(CUDA_ERROR_MISALIGNED_ADDRESS).
"""


import functools
import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, one_thread, spread_shift, spread_task, task_at
from tflock.engine import current_engine, host_lanes
from tflock.space import OPEN, PERIODIC, WINDOW, boundary_code, displacement

_HASH = (73856093, 19349663, 83492791)
SCAN_BLOCK = 1024  # buckets per block of the grid build's prefix sum
#: layout code of a bounded open-space grid (see CellGrid): not a boundary (its displacement is the plain difference)
BOUNDED = 3
#: a frame of at most this many drawn agents finds its edges from all their pairs on one CPU thread, where a grid's
#: launches cost more (see DrawnEdges)
ALL_PAIRS_ROWS = 128
#: buckets a periodic box's window grid may use at least (see CellGrid)
WINDOW_MIN_BUCKETS = 4096
#: agents a lane-wise CPU kernel treats together, 8 or 16 float32 lanes for this CPU (see :func:`host_lanes` and
#: :meth:`CellGrid.runs`)
LANES = host_lanes()


@dataclass(frozen=True)
class GridGeometry:
    """Cell layout: side length, cells per side (box modes), buckets of one replica (what kernels take as
    ``n_buckets``), buckets of the whole grid, and agents per replica."""

    dim: int
    boundary: int
    cell_size: float
    cells_per_side: int
    n_buckets: int
    total_buckets: int
    agents_per_replica: int

    def __post_init__(self) -> None:
        if self.boundary == OPEN and self.n_buckets & (self.n_buckets - 1):  # bucket_of_cell masks the hash
            raise ValueError(f"an open-space grid needs a power of two of buckets, got {self.n_buckets}")


def grid_geometry(n: int, dim: int, boundary: str, box: float, radius: float, replicas: int = 1,
                  at_most: bool = False) -> GridGeometry:
    """Choose cells of side >= radius (``at_most``: <= radius, unless the cap on the number of cells makes them
    larger): a tiling of the box, or a hash table of ~2n buckets in open space, for each replica of
    n / replicas agents as for a lone system of that size."""
    code = boundary_code(boundary)
    per_replica = n // replicas
    if code == OPEN:
        n_buckets = 1 << max(4, math.ceil(math.log2(2 * per_replica)))
        return GridGeometry(dim, code, float(radius), 0, n_buckets, replicas * n_buckets, per_replica)
    per_side = max(1, math.ceil(box / radius) if at_most else int(box // radius))
    cap = max(64, 4 * per_replica)
    if per_side**dim > cap:
        per_side = max(1, int(cap ** (1.0 / dim)))
    return GridGeometry(dim, code, box / per_side, per_side, per_side**dim, replicas * per_side**dim, per_replica)


@ti.func
def cell_coords(p, origin, anchor, box, cell_size, nc, boundary: ti.template()):
    """Integer cell coordinates of position p (clamped into the grid for box layouts). Open space's cells are
    floor(p / R); a bounded grid counts them from `origin`, the lowest cell of its bounding box; a window grid
    takes p relative to `anchor` (minimum image in the periodic box of side `box`) first."""
    c = ti.Vector([0] * p.n, dt=ti.i32)
    if ti.static(boundary == OPEN):
        c = ti.cast(ti.floor(p / cell_size), ti.i32)
    elif ti.static(boundary == BOUNDED or boundary == WINDOW):
        q = p
        if ti.static(boundary == WINDOW):
            q = displacement(anchor, p, box, PERIODIC)
        # clamped: were this kernel and the bounds' pass to round a quotient apart, a cell one past the bounds moves
        # onto the edge, still next to every cell within R of it
        c = ti.math.clamp(ti.cast(ti.floor(q / cell_size), ti.i32) - origin, 0, nc - 1)
    else:  # coordinates are >= 0: truncation is the floor, and cheaper
        c = ti.math.clamp(ti.cast(p / cell_size, ti.i32), 0, nc - 1)
    return c


@ti.func
def bucket_of_cell(c, nc, n_buckets, boundary: ti.template(), dim: ti.template()):
    """Bucket index of cell c = (cell coordinates, replica) among the grid's buckets: the replica's block of
    `n_buckets`, then row-major in a box or a spatial hash in open space."""
    b = 0
    if ti.static(boundary == OPEN):
        h = ti.u32(0)
        for k in ti.static(range(dim)):
            h ^= ti.cast(c[k], ti.u32) * ti.u32(_HASH[k])
        # n_buckets is a power of two in open space (grid_geometry): the mask is h % n_buckets without a division
        b = c[dim] * n_buckets + ti.cast(h & ti.u32(n_buckets - 1), ti.i32)
    else:
        b = c[dim]
        for k in ti.static(range(dim)):
            b = b * nc + c[dim - 1 - k]
    return b


def span_count(boundary: int, dim: int) -> int:
    """Number of bucket spans a query visits: 2 per stencil row in a box, one per cell (3^dim) in open space.

    Kernels loop over spans at run time with a constant bound, ``for o in range(ti.static(span_count(...)))``:
    unrolling 18-27 spans in 3D made kernels take minutes to compile.
    """
    return 3**dim if boundary == OPEN else 2 * 3 ** (dim - 1)


@ti.func
def stencil_span(c, o, nc, n_buckets, boundary: ti.template(), dim: ti.template()):
    """The o-th span of buckets [lo, hi) around cell c (cell coordinates, then replica), and the cell it stands
    for (open space). Spans stay inside c's replica.

    In a box, buckets are row-major, so the cells x-1..x+1 of a stencil row are one contiguous span of sorted
    agents (a single loop with no per-cell overhead); at a periodic edge the row wraps into a second span.
    Periodic rows and columns wrap; a box with fewer than 3 cells per side visits each distinct cell once;
    reflecting boxes skip rows outside. In open space every span is one hashed cell, filtered by
    :func:`same_cell`. An empty span has lo == hi.
    """
    cell = c
    lo = 0
    hi = 0
    if ti.static(boundary == OPEN):
        for k in ti.static(range(dim)):
            cell[k] = c[k] + (o // ti.static(3**k)) % 3 - 1
        lo = bucket_of_cell(cell, nc, n_buckets, boundary, dim)
        hi = lo + 1
    else:
        row = o // 2  # divisions by constants only: cheap, and folded away where a loop is unrolled
        seg = o % 2
        ok = True
        b = c[dim]  # the replica's block of buckets
        for k in ti.static(range(dim - 1, 0, -1)):  # row-major: the last axis varies slowest
            off = (row // ti.static(3 ** (k - 1))) % 3 - 1
            t = c[k] + off
            if ti.static(boundary == PERIODIC):
                if nc < 3 and (off < 0 or off >= nc):
                    ok = False
                if t < 0:
                    t += nc
                elif t >= nc:
                    t -= nc
            elif t < 0 or t >= nc:
                ok = False
            b = b * nc + t
        b *= nc
        x0 = c[0] - 1
        x1 = c[0] + 2  # exclusive
        first = seg == 0
        if ti.static(boundary == PERIODIC):
            if nc < 3:
                x0, x1 = 0, nc
            elif x0 < 0:  # wraps left: [0, 2) then [nc - 1, nc)
                x0, x1 = ti.select(first, 0, nc - 1), ti.select(first, 2, nc)
                first = True
            elif x1 > nc:  # wraps right: [nc - 2, nc) then [0, 1)
                x0, x1 = ti.select(first, nc - 2, 0), ti.select(first, nc, 1)
                first = True
        else:
            x0 = ti.max(x0, 0)
            x1 = ti.min(x1, nc)
        if ok and first:
            lo = b + x0
            hi = b + x1
    return lo, hi, cell


@ti.func
def same_cell(coords_sorted: ti.template(), k, cell, boundary: ti.template(), dim: ti.template()):
    """1 when sorted agent k lies in `cell`, replica included (always 1 in a box, where a bucket is one cell)."""
    same = 1
    if ti.static(boundary == OPEN):
        for d in ti.static(range(dim + 1)):
            same &= ti.select(coords_sorted[d, k] == cell[d], 1, 0)
    return same


@ti.func
def span_agents(lo, hi, cell, start: ti.template(), mixed: ti.template(), coords_sorted: ti.template(),
                boundary: ti.template(), dim: ti.template()):
    """The sorted agents [begin, end) of the span [lo, hi) that :func:`stencil_span` gave for `cell`, and
    ``check``: 1 when each of them must still pass :func:`same_cell`.

    In a box every bucket is one cell (check = 0). In open space a bucket that holds one cell is that cell's (one
    test of its first agent keeps it whole) or another's (skipped); only a bucket ``mixed`` by a hash collision
    needs the test per agent, which costs about as much as the distance test it guards.
    """
    begin = start[lo]
    end = start[hi]
    check = 0
    if ti.static(boundary == OPEN):
        if begin < end:
            if mixed[lo] == 1:
                check = 1
            elif same_cell(coords_sorted, begin, cell, boundary, dim) == 0:
                end = begin
    return begin, end, check


@ti.func
def load_vec(arr: ti.template(), i, dim: ti.template()):
    """Column i of a component-major (dim, n) ndarray as a Taichi vector.

    Component-major arrays keep each coordinate contiguous, which lets LLVM vectorise the neighbour loops (with
    (n, dim) rows it does not).
    """
    return ti.Vector([arr[d, i] for d in ti.static(range(dim))])


@ti.func
def load_cell(coords: ti.template(), i, dim: ti.template()):
    """Column i of a grid's (dim + 1, n) cell array: the cell coordinates and, last, the replica."""
    return ti.Vector([coords[d, i] for d in ti.static(range(dim + 1))], dt=ti.i32)


@ti.func
def _cell_and_bucket(p, i, per_replica, bounds: ti.template(), anchor: ti.template(), box, cell_size, nc, n_buckets,
                     boundary: ti.template(), dim: ti.template()):
    """The cell (coordinates, then replica) and the bucket a build puts agent i at position p in."""
    corner = ti.Vector([bounds[0, d] for d in ti.static(range(dim))], dt=ti.i32)  # a bounded grid's origin
    local = cell_coords(p, corner, load_vec(anchor, 0, dim), box, cell_size, nc, boundary)
    c = ti.Vector([0] * (dim + 1), dt=ti.i32)
    for d in ti.static(range(dim)):
        c[d] = local[d]
    c[dim] = i // per_replica
    return c, bucket_of_cell(c, nc, n_buckets, boundary, dim)


@ti.func
def build_grid(pos: ti.template(), ids: ti.template(), n, per_replica, box, cell_size, nc, n_buckets, total_buckets,
               boundary: ti.template(), dim: ti.template(), coords: ti.template(), bucket: ti.template(),
               counts: ti.template(), start: ti.template(), order: ti.template(), slot_of: ti.template(),
               pos_sorted: ti.template(), coords_sorted: ti.template(), id_sorted: ti.template(),
               mixed: ti.template(), block_start: ti.template(), bounds: ti.template(), anchor: ti.template(),
               by_rank: ti.template()):
    """One build of the grid (see :meth:`CellGrid.build`, which launches it as :func:`_build`; a model's kernel may
    call it inside its own loop over steps, see :meth:`CellGrid.build_arguments`): count agents per bucket, scan
    the counts, scatter, put each bucket's agents in id order, gather the sorted arrays."""
    for b in range(total_buckets):
        counts[b] = 0
    for e in range(n):
        c, b = _cell_and_bucket(load_vec(pos, e, dim), ids[e], per_replica, bounds, anchor, box, cell_size, nc,
                                n_buckets, boundary, dim)
        for d in ti.static(range(dim + 1)):
            coords[d, e] = c[d]
        bucket[e] = b
        ti.atomic_add(counts[b], 1)
    # exclusive scan of the counts into start[0 .. total_buckets], in blocks of SCAN_BLOCK buckets: block sums in
    # parallel, a serial scan of the few block sums, then each block's scan in parallel (a serial scan of every
    # bucket would run on one GPU thread)
    for k in range(total_buckets // SCAN_BLOCK + 1):
        total = 0
        for b in range(k * SCAN_BLOCK, ti.min((k + 1) * SCAN_BLOCK, total_buckets)):
            total += counts[b]
        block_start[k] = total
    ti.loop_config(serialize=True)
    for k in range(total_buckets // SCAN_BLOCK + 1):
        last = total_buckets // SCAN_BLOCK + 1  # the spare last element holds the running sum
        if k == 0:
            block_start[last] = 0
        total = block_start[k]
        block_start[k] = block_start[last]
        block_start[last] += total
    for k in range(total_buckets // SCAN_BLOCK + 1):
        total = block_start[k]
        for b in range(k * SCAN_BLOCK, ti.min((k + 1) * SCAN_BLOCK, total_buckets + 1)):
            start[b] = total
            if b < total_buckets:
                count = counts[b]
                counts[b] = total  # from here on the bucket's scatter cursor
                total += count
    # within a bucket the scatter's order depends on thread timing; agents are then put in id order (a
    # deterministic neighbour order)
    if ti.static(by_rank):  # GPU: each agent's rank among its bucket's ids places it, all agents in parallel
        for e in range(n):
            slot_of[ti.atomic_add(counts[bucket[e]], 1)] = e  # scratch until the last loop
        for s in range(n):
            e = slot_of[s]
            b = bucket[e]
            key = ids[e]
            rank = 0
            for k in range(start[b], start[b + 1]):
                rank += ti.select(ids[slot_of[k]] < key, 1, 0)
            order[start[b] + rank] = e
    else:  # CPU: insertion sort of each bucket, nearly sorted already when the state keeps the last cell order
        for e in range(n):
            order[ti.atomic_add(counts[bucket[e]], 1)] = e
        for b in range(total_buckets):
            lo = start[b]
            for k in range(lo + 1, start[b + 1]):
                v = order[k]
                key = ids[v]
                m = k
                while m > lo:  # Taichi's `and` evaluates both sides: order[m - 1] is read only while m > lo
                    if ids[order[m - 1]] <= key:
                        break
                    order[m] = order[m - 1]
                    m -= 1
                order[m] = v
    for s in range(n):
        e = order[s]
        id_sorted[s] = ids[e]
        for d in ti.static(range(dim)):
            pos_sorted[d, s] = pos[d, e]
        for d in ti.static(range(dim + 1)):
            coords_sorted[d, s] = coords[d, e]
    if ti.static(boundary == OPEN):
        for b in range(total_buckets):  # 1 when the bucket holds agents of more than one cell
            first = start[b]
            flag = 0
            if first < start[b + 1]:
                cell = load_cell(coords_sorted, first, dim)
                for k in range(first + 1, start[b + 1]):
                    flag |= 1 - same_cell(coords_sorted, k, cell, boundary, dim)
            mixed[b] = flag


@ti.kernel
def _build(pos: ti.types.ndarray(), ids: ti.types.ndarray(), n: ti.i32, per_replica: ti.i32, box: float,
           cell_size: float, nc: ti.i32, n_buckets: ti.i32, total_buckets: ti.i32, boundary: ti.template(),
           dim: ti.template(),
           coords: ti.types.ndarray(), bucket: ti.types.ndarray(), counts: ti.types.ndarray(),
           start: ti.types.ndarray(), order: ti.types.ndarray(), slot_of: ti.types.ndarray(),
           pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), id_sorted: ti.types.ndarray(),
           mixed: ti.types.ndarray(), block_start: ti.types.ndarray(), bounds: ti.types.ndarray(),
           anchor: ti.types.ndarray(), by_rank: ti.template(), serial: ti.template()):
    """:func:`build_grid`; with `serial` on the calling thread (a small swarm: :func:`tflock.cpu_tasks.one_thread`)."""
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for _ in range(1):
            build_grid(pos, ids, n, per_replica, box, cell_size, nc, n_buckets, total_buckets, boundary, dim, coords,
                       bucket, counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed,
                       block_start, bounds, anchor, by_rank)
    else:
        build_grid(pos, ids, n, per_replica, box, cell_size, nc, n_buckets, total_buckets, boundary, dim, coords,
                   bucket, counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed, block_start,
                   bounds, anchor, by_rank)


@ti.func
def _window_cell(p, anchor, box, cell_size, layout: ti.template()):
    """Cell of p before a bounded (open space) or window (periodic box) grid's origin is subtracted."""
    q = p
    if ti.static(layout == WINDOW):
        q = displacement(anchor, p, box, PERIODIC)
    return cell_coords(q, 0, anchor, box, cell_size, 0, OPEN)


@ti.kernel
def _cell_bounds(n: ti.i32, dim: ti.template(), box: float, cell_size: float, layout: ti.template(),
                 pos: ti.types.ndarray(), partial: ti.types.ndarray(), bounds: ti.types.ndarray(),
                 anchor: ti.types.ndarray()):
    """The bounding box of n agents' cells, as :func:`cell_coords` computes them for `layout` with no origin: open
    space's floor(p / R) (BOUNDED), or the same of the minimum-image position relative to the first agent, which
    becomes the `anchor` (WINDOW). bounds[0] is its lowest cell, bounds[1] its highest. Block extrema in parallel,
    then a serial pass over the blocks (no atomics on one shared address)."""
    for t in range(partial.shape[1] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            a = load_vec(pos, 0, dim)
            lo = _window_cell(load_vec(pos, blk * SCAN_BLOCK, dim), a, box, cell_size, layout)
            hi = lo
            for e in range(blk * SCAN_BLOCK + 1, ti.min(n, (blk + 1) * SCAN_BLOCK)):
                c = _window_cell(load_vec(pos, e, dim), a, box, cell_size, layout)
                lo = ti.min(lo, c)
                hi = ti.max(hi, c)
            for d in ti.static(range(dim)):
                partial[d, blk] = lo[d]
                partial[dim + d, blk] = hi[d]
    ti.loop_config(serialize=True)
    for d in range(dim):
        anchor[d, 0] = pos[d, 0]
        lo = partial[d, 0]
        hi = partial[dim + d, 0]
        for blk in range(1, partial.shape[1]):
            lo = ti.min(lo, partial[d, blk])
            hi = ti.max(hi, partial[dim + d, blk])
        bounds[0, d] = lo
        bounds[1, d] = hi


@ti.func
def bounded_layout(n, dim: ti.template(), box, cell_size, max_side, layout: ti.template(), pos: ti.template(),
                   bounds: ti.template(), anchor: ti.template()):
    """A bounded grid's layout of n agents' positions, found on one thread inside a model's kernel as
    :meth:`CellGrid._layout` finds it: the bounding box of their cells into `bounds` (bounds[0], the lowest cell, is
    the grid's origin for :func:`build_grid`) and its cells a side, or 0 where the box is more than `max_side` cells
    a side (the layout then falls back to the hash or the tiling, which such a kernel does not build). BOUNDED (open
    space): cells floor(p / R). WINDOW (a periodic box): the cells of the minimum-image positions relative to the
    first agent, which becomes the `anchor`; `max_side` is then :meth:`CellGrid.max_window_side`, and a window
    anchored at a position that is not finite never fits."""
    first = load_vec(pos, 0, dim)
    lo = _window_cell(first, first, box, cell_size, layout)
    hi = lo
    for e in range(1, n):
        c = _window_cell(load_vec(pos, e, dim), first, box, cell_size, layout)
        lo = ti.min(lo, c)
        hi = ti.max(hi, c)
    side = ti.i64(0)
    for d in ti.static(range(dim)):
        bounds[0, d] = lo[d]
        bounds[1, d] = hi[d]
        side = ti.max(side, ti.cast(hi[d], ti.i64) - ti.cast(lo[d], ti.i64) + 1)
    fits = (side >= 1) & (side <= max_side)
    if ti.static(layout == WINDOW):
        for d in ti.static(range(dim)):
            anchor[d, 0] = first[d]
            fits &= not (ti.math.isnan(first[d]) or ti.math.isinf(first[d]))
    return ti.select(fits, ti.cast(side, ti.i32), 0)


@ti.func
def cut_runs(rows, nc, start: ti.template(), run_end: ti.template()):
    """Cut every row of a box grid into runs of consecutive cells (see :meth:`CellGrid.runs`, which launches it as
    :func:`_runs`): one pass along each row, a cell joining the open run while the agents fit in the lanes."""
    for row in range(rows):
        cut_row(row, nc, start, run_end)


@ti.func
def cut_row(row, nc, start: ti.template(), run_end: ti.template()):
    """:func:`cut_runs` for one row."""
    base = row * nc
    if start[base] == start[base + nc]:  # an empty row (most of a sparse swarm's tiling): no run starts
        for x in range(nc):
            run_end[base + x] = -1
    else:
        y = row % nc  # this row within its replica, and the rows beside it (circularly), found once a row
        sides = ti.Vector([row - y + ti.select(y == 0, nc - 1, y - 1), row, row - y + ti.select(y == nc - 1, 0, y + 1)])
        begin = -1  # first cell of the open run (-1: none)
        agents = 0
        below = start[base]
        for x in range(nc):
            above = start[base + x + 1]
            here = above - below
            below = above
            join = begin >= 0 and agents + here <= LANES
            if join and here == 0:  # an empty cell widens the window by column x + 1: only if that is sparse
                column = 0
                if x + 1 < nc:
                    for r in ti.static(range(3)):
                        column += start[sides[r] * nc + x + 2] - start[sides[r] * nc + x + 1]
                join = column <= LANES
            run_end[base + x] = -1
            if join:
                agents += here
            else:
                if begin >= 0:
                    run_end[base + begin] = x
                begin = ti.select(here > 0, x, -1)
                agents = here
        if begin >= 0:
            run_end[base + begin] = nc


@ti.kernel
def _runs(rows: ti.i32, nc: ti.i32, shift: ti.i32, start: ti.types.ndarray(), run_end: ti.types.ndarray()):
    """:func:`cut_runs`, a row a task spread over the threads (tflock.cpu_tasks.spread_shift)."""
    for t in range(rows << shift):
        row = spread_task(t, shift)
        if row >= 0:
            cut_row(row, nc, start, run_end)


@ti.func
def run_at(b, nc, start: ti.template(), run_end: ti.template()):
    """The run of cells that starts at bucket b (see :meth:`CellGrid.runs`): its grid row, its columns [x0, x1) in
    that row and its sorted agents [a0, a1); a0 == a1 (and row, x0 are 0) where no run starts at b. Lane-wise
    kernels take the agents ``LANES`` at a time, ``for block in range((a1 - a0 + LANES - 1) // LANES)``."""
    x1 = run_end[b]
    row = 0
    x0 = 0
    a0 = start[b]
    a1 = a0
    if x1 >= 0:  # (an integer division only where a run starts: most buckets of a sparse swarm hold none)
        row = b // nc
        x0 = b - row * nc
        a1 = start[row * nc + x1]
    return row, x0, x1, a0, a1


@ti.func
def run_spans(row, x0, x1, r, nc, start: ti.template(), boundary: ti.template(), dim: ti.template()):
    """Row r of the stencil of the run of cells [x0, x1) in grid row `row` of a box grid: at most two spans of
    sorted agents [b0, e0), [b1, e1) (empty ones have b == e). The stencil has 3^(dim - 1) rows, r's base-3 digits
    giving the offsets -1, 0, +1 along y, then z.

    The cells x0 - 1 .. x1 of a row are contiguous; a periodic row wraps into a second span at an edge and is
    visited once whole when the window covers it; a box with fewer than 3 rows visits each distinct row once, as
    :func:`stencil_span` does. A reflecting box skips rows outside and clips the window.
    """
    ok = True
    shift = 0  # from `row` to the stencil's row, in rows
    stride = 1
    for k in ti.static(range(1, dim)):
        off = (r // ti.static(3 ** (k - 1))) % 3 - 1
        c = row // stride  # (stride 1 at k = 1: no division)
        if c >= nc:  # a later replica's row, or z in 3D; the first replica's y needs no division
            c %= nc
        t = c + off
        if ti.static(boundary == PERIODIC):
            if nc < 3 and (off < 0 or off >= nc):
                ok = False
            t = ti.select(t < 0, t + nc, ti.select(t >= nc, t - nc, t))  # t in [-1, nc]: (t + nc) % nc
        elif t < 0 or t >= nc:
            ok = False
        shift += (t - c) * stride
        stride *= nc
    base = (row + shift) * nc
    lo = x0 - 1
    hi = x1 + 1
    b0 = 0
    e0 = 0
    b1 = 0
    e1 = 0
    if ok:
        if ti.static(boundary == PERIODIC):
            if hi - lo >= nc:
                b0, e0 = start[base], start[base + nc]
            elif lo < 0:
                b0, e0 = start[base], start[base + hi]
                b1, e1 = start[base + nc - 1], start[base + nc]
            elif hi > nc:
                b0, e0 = start[base + lo], start[base + nc]
                b1, e1 = start[base], start[base + hi - nc]
            else:
                b0, e0 = start[base + lo], start[base + hi]
        else:
            b0, e0 = start[base + ti.max(lo, 0)], start[base + ti.min(hi, nc)]
    return b0, e0, b1, e1


@ti.func
def run_wraps(row, x0, x1, nc, boundary: ti.template()):
    """Whether the stencil of a run crosses a periodic edge. If not, the plain difference of two positions in it
    is already the minimum image: the run's window spans at most nc - 1 cells, so two agents in it are less than
    box - R apart along each axis, and a pair the direct difference puts further than R apart is as far through
    the boundary. A window grid's cells may lie across the box's edge anywhere: its runs ask
    :func:`window_run_wraps`, which knows where the window lies."""
    ti.static_assert(boundary != WINDOW, "a window grid's runs: window_run_wraps")
    wraps = False
    if ti.static(boundary == PERIODIC):
        if x1 >= 0:  # a run (no division for an empty bucket)
            y = row % nc
            wraps = x0 == 0 or x1 == nc or y == 0 or y == nc - 1
    return wraps


@ti.func
def window_run_wraps(row, x0, x1, nc, cell_size, box, bounds: ti.template(), anchor: ti.template()):
    """:func:`run_wraps` for a 2D window grid (layout ``WINDOW``, one replica), from where its cells lie in the box.
    Window cell c holds the agents whose minimum-image position relative to the `anchor` is in
    [(bounds[0] + c) R, (bounds[0] + c + 1) R), R = `cell_size`, so the stencil of the run (cells x0 - 1 .. x1 by
    y - 1 .. y + 1), widened by a cell either way for rounding and for agents clamped onto the window's edge, holds
    raw positions in the rectangle computed here. When that rectangle lies inside [0, box)^2 and is less than
    box / 2 wide, any two positions in it are less than box / 2 apart along each axis: their plain difference is
    then what :func:`tflock.space.displacement` returns for the periodic box, bit for bit (it shifts only beyond
    box / 2). A swarm away from the torus's edges thus skips the minimum image in most runs."""
    wraps = False
    if x1 >= 0:  # a run (no division for an empty bucket)
        y = row % nc
        lo = ti.Vector([x0 - 2, y - 2])
        hi = ti.Vector([x1 + 2, y + 3])
        for d in ti.static(range(2)):
            a = anchor[d, 0] + (bounds[0, d] + lo[d]) * cell_size
            b = anchor[d, 0] + (bounds[0, d] + hi[d]) * cell_size
            if a < 0 or b > box or b - a >= 0.5 * box:
                wraps = True
    return wraps


@ti.func
def lanes(arr: ti.template(), row: ti.template(), i0, last, width: ti.template()):
    """Elements i0 .. i0 + width - 1 of row `row` of a component-major ndarray as a vector, indices clamped to
    `last` (lanes past it repeat the last element: compute with them, but do not store their results)."""
    return ti.Vector([arr[row, ti.min(i0 + k, last)] for k in ti.static(range(width))])


class CellGrid:
    """Cell-sorted view of n agents' positions, rebuilt with :meth:`build` whenever positions change.

    Models may keep their state in any arrangement of the agents (tflock's models keep it in the cell order of
    the previous step, so this build reads and writes nearly sequentially); ``ids`` names the agent stored at
    each element. After a build: ``order[s]`` is the element at sorted slot s, ``id_sorted[s]`` its agent id,
    and ``pos_sorted`` / ``coords_sorted`` (cell coordinates, then replica) are in slot order; :meth:`slots`
    gives the slot of each agent. With ``replicas`` > 1 the n agents are that many independent systems of
    n / replicas agents each (agent id = replica * n / replicas + local id) that never see each other.

    ``at_most``: cells of side at most `radius` in a box (see :func:`grid_geometry`), for sub-cell grids.

    ``bounded`` (open space or periodic box, one replica): each build stores the cells row-major over the agents'
    bounding box (open space) or window (periodic box) when they fit, else keeps the hash or the tiling (see the
    module); ``geometry`` is then the layout of the last build, so kernels read it after building. A batch of
    replicas keeps the hash: a lone run must give the batch's numbers bit for bit, and kernels compiled
    for two layouts may round differently (Vicsek and adaptive, which run batches, keep the hash for that reason).
    """

    def __init__(self, n: int, dim: int, boundary: str, box: float, radius: float, real: type,
                 replicas: int = 1, rank_sort: bool | None = None, bounded: bool = False,
                 at_most: bool = False) -> None:
        if n % replicas:
            raise ValueError(f"{n} agents do not split into {replicas} equal replicas")
        self.n = n
        self.real = real
        self.replicas = replicas
        self.radius = radius
        self.box = box
        self.geometry = grid_geometry(n, dim, boundary, box, radius, replicas, at_most)
        self.fallback = self.geometry  # a bounded grid's hash or tiling
        self.boundary = self.geometry.boundary  # the space's boundary code (``geometry`` holds the layout's)
        g = self.geometry
        self.bounded = bounded and g.boundary in (OPEN, PERIODIC) and replicas == 1
        # buckets the arrays hold: the layout's, and for a window at least WINDOW_MIN_BUCKETS (the capped tiling of
        # a small swarm in a large torus can have fewer buckets than the window needs cells)
        self._capacity = g.total_buckets
        if self.bounded and g.boundary == PERIODIC:
            self._capacity = max(g.total_buckets, WINDOW_MIN_BUCKETS)
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.coords = ti.ndarray(ti.i32, (dim + 1, n))
        self.bucket = ti.ndarray(ti.i32, n)
        self.counts = ti.ndarray(ti.i32, self._capacity)
        self.start = ti.ndarray(ti.i32, self._capacity + 1)
        self.order = ti.ndarray(ti.i32, n)
        self.slot_of = ti.ndarray(ti.i32, n)  # see slots(); the GPU build's scratch
        self._slots_build = -1  # the build whose slots slot_of holds
        self.id_sorted = ti.ndarray(ti.i32, n)
        self.pos_sorted = ti.ndarray(ftype, (dim, n))
        self.coords_sorted = ti.ndarray(ti.i32, (dim + 1, n))
        # open space: 1 for a bucket that holds more than one cell (see span_agents); unused in a box
        self.mixed = ti.ndarray(ti.i32, g.total_buckets if g.boundary == OPEN else 1)
        self.block_start = ti.ndarray(ti.i32, self._capacity // SCAN_BLOCK + 2)  # the build's block offsets
        self.run_end: ti.Ndarray | None = None  # see runs(); allocated on first use (CPU lane-wise kernels only)
        self._runs_build = -1  # the build whose runs run_end holds
        # a bounded grid's bounding box of cells (bounds[0], its lowest cell, is the origin of its cell coordinates;
        # zeros, unused, for other layouts), the block extrema that give it, and a window's anchor
        self.bounds = ti.ndarray(ti.i32, (2, dim))
        self.anchor = ti.ndarray(ftype, (dim, 1))
        self._bound_blocks = ti.ndarray(ti.i32, (2 * dim, (n + SCAN_BLOCK - 1) // SCAN_BLOCK if self.bounded else 1))
        # how a bucket's agents are put in id order: ranks in parallel (GPU) or an insertion sort (CPU); both give
        # the same grid, `rank_sort` picks one (default: by the engine's arch)
        engine = current_engine()
        self.rank_sort = (engine is not None and engine.arch != "cpu") if rank_sort is None else rank_sort
        self.builds = 0  # how many builds so far: data derived from a build (slots, runs, drawn slots) names it

    def build(self, pos: ti.Ndarray, ids: ti.Ndarray) -> None:
        """Sort agents by cell: `pos` is a component-major (dim, n) ndarray, `ids` the agent at each element."""
        if self.bounded:
            self.geometry = self._layout(pos)
        _build(pos, ids, *self.build_arguments(), one_thread(self.n))
        self.builds += 1

    def build_arguments(self) -> tuple:
        """The arguments of :func:`build_grid` after `pos` and `ids`, for the current layout: for a model's kernel
        that builds the grid itself, inside its own loop over steps (then :meth:`count_builds` says so)."""
        g = self.geometry
        return (self.n, g.agents_per_replica, self.box, g.cell_size, g.cells_per_side, g.n_buckets, g.total_buckets,
                g.boundary, g.dim, self.coords, self.bucket, self.counts, self.start, self.order, self.slot_of,
                self.pos_sorted, self.coords_sorted, self.id_sorted, self.mixed, self.block_start, self.bounds,
                self.anchor, self.rank_sort)

    def count_builds(self, builds: int, runs: bool = True) -> None:
        """Count `builds` builds a model's kernel made with :func:`build_grid` (a grid of fixed layout), each followed
        by :func:`cut_runs` into :meth:`run_buffer` (the runs there are then the last build's) where `runs`."""
        if self.bounded:
            raise ValueError("a bounded grid's layout is chosen on the host at each build")
        self.builds += builds
        if runs:
            self._runs_build = self.builds

    @functools.cached_property
    def max_side(self) -> int:
        """The most cells a side a bounded layout may have: its buckets must fit the arrays."""
        dim = self.fallback.dim
        side = int(round(self._capacity ** (1.0 / dim)))
        while side**dim > self._capacity:
            side -= 1
        while (side + 1) ** dim <= self._capacity:
            side += 1
        return side

    def count_bounded_builds(self, builds: int, per_side: int, fallback: bool = False) -> None:
        """Count `builds` builds of a bounded grid (open space) or window grid (periodic box) that a model's kernel
        made itself (:func:`bounded_layout`, :func:`build_grid`); `per_side` > 0: the last of them is of that many
        cells a side and its runs were cut (:func:`cut_runs`) into :meth:`run_buffer`; else with `fallback` the
        last one took the fallback layout (its runs not cut), else the grid holds none of them."""
        self.builds += builds
        if fallback and not per_side:
            self.geometry = self.fallback
        if per_side:
            h = self.fallback
            layout = WINDOW if h.boundary == PERIODIC else BOUNDED
            self.geometry = GridGeometry(h.dim, layout, self.radius, per_side, per_side**h.dim, per_side**h.dim,
                                         self.n)
            self._runs_build = self.builds

    @functools.cached_property
    def max_window_side(self) -> int:
        """The most cells a side a window layout (periodic box) may have: within :attr:`max_side`, and leaving at
        least R, and a margin of one cell for rounding, of the torus outside it."""
        return min(self.max_side, int(self.box / self.radius) - 2)

    def _layout(self, pos: ti.Ndarray) -> GridGeometry:
        """A bounded grid's layout for these positions: side-R cells over the cube on their bounding box (open
        space) or window (periodic box), stored row-major, or the fallback when they are too many for its buckets (a
        straggler far out; positions beyond the range of integer cell coordinates, or not finite, give nonsense
        bounds that always are) or, in a periodic box, when the window leaves less than R (and a margin of one
        cell for rounding) of the torus outside it."""
        h = self.fallback
        layout = WINDOW if h.boundary == PERIODIC else BOUNDED
        _cell_bounds(self.n, h.dim, self.box, self.radius, layout, pos, self._bound_blocks, self.bounds, self.anchor)
        lo, hi = self.bounds.to_numpy().astype(np.int64)
        per_side = int(np.max(hi - lo)) + 1
        widest = self.max_window_side if layout == WINDOW else self.max_side
        if per_side < 1 or per_side > widest:  # the rule bounded_layout applies in a model's kernel
            return h
        # a window needs a finite anchor too (were it not, every agent's cell would be the same nonsense)
        if layout == WINDOW and not np.isfinite(self.anchor.to_numpy()).all():
            return h
        return GridGeometry(h.dim, layout, self.radius, per_side, per_side**h.dim, per_side**h.dim, self.n)

    def slots(self) -> ti.Ndarray:
        """The slot of each agent (``slot_of[agent]``) in the last build, filled on first use after it.

        Only metrics and drawn frames look agents up by id; filling it in every build would scatter one write
        per agent over the whole array, a sizeable part of a build.
        """
        if self._slots_build != self.builds:
            _fill_slots(self.n, self.id_sorted, self.slot_of)
            self._slots_build = self.builds
        return self.slot_of

    def runs(self) -> ti.Ndarray:
        """Runs of cells for lane-wise kernels (box and bounded grids), computed on first use after a build.

        Each row is cut into runs of consecutive cells that start at an occupied cell and hold at most ``LANES``
        agents together (a fuller cell is a run of its own); ``run_end[b]`` is one past the last cell of the run
        that starts at bucket b (as a column in b's row), -1 where no run starts. A kernel takes a run's agents
        ``LANES`` at a time and visits the run's 3 x (width + 2) cells once for all of them: in a sparse swarm (2
        agents a cell) a run of ~4 cells fills the lanes, which visits half the candidates per agent that
        cell-by-cell lanes would. An empty cell joins a run only if the column it adds to the window is sparse.
        """
        g = self.geometry
        if g.boundary == OPEN:
            raise ValueError("runs need a box or bounded grid (this build hashed its cells)")
        if self._runs_build != self.builds:
            rows = g.total_buckets // g.cells_per_side
            _runs(rows, g.cells_per_side, spread_shift(rows), self.start, self.run_buffer())
            self._runs_build = self.builds
        return self.run_end

    def run_buffer(self) -> ti.Ndarray:
        """``run_end``, allocated on first use, whatever build's runs it holds (see :meth:`runs`)."""
        if self.run_end is None:
            self.run_end = ti.ndarray(ti.i32, self.counts.shape[0])
        return self.run_end


@ti.kernel
def _fill_slots(n: ti.i32, id_sorted: ti.types.ndarray(), slot_of: ti.types.ndarray()):
    for s in range(n):
        slot_of[id_sorted[s]] = s


@ti.func
def drawn_rank(i, bits: ti.template(), word_rank: ti.template()):
    """Row of agent i in a frame (its rank among the drawn agents, which are taken in id order), or -1 when it is
    not drawn; from :class:`SubsetDrawing`'s ``bits`` and ``word_rank``."""
    w = bits[i >> 5]
    b = ti.cast(i & 31, ti.u32)
    rank = -1
    if (w >> b) & ti.u32(1):
        rank = word_rank[i >> 5] + ti.cast(ti.math.popcnt(w & ((ti.u32(1) << b) - ti.u32(1))), ti.i32)
    return rank


@ti.kernel
def _drawn_slots(n: ti.i32, id_sorted: ti.types.ndarray(), bits: ti.types.ndarray(), word_rank: ti.types.ndarray(),
                 slot: ti.types.ndarray()):
    """The slot in the grid of each drawn agent, by one pass over the grid's agents (sequential reads; a
    ``slot_of`` of all agents scatters a write per agent)."""
    for s in range(n):
        r = drawn_rank(id_sorted[s], bits, word_rank)
        if r >= 0:
            slot[r] = s


class SubsetDrawing:
    """Fixed subset of agents drawn every frame: their membership and frame rows (``bits``, ``word_rank``, see
    :func:`drawn_rank`) and their slots in the grid, on the device.

    Index arrays are uploaded once. The drawn agents' slots in the grid (``slot``) come from one pass over the
    grid's agents per build (or a model's own rows pass, which says so with :meth:`located`).
    """

    def __init__(self, grid: CellGrid, selected_ids: np.ndarray) -> None:
        self.grid = grid
        self.selected_ids = np.asarray(selected_ids, dtype=np.int32)
        m = max(1, len(self.selected_ids))
        self.slot = ti.ndarray(ti.i32, m)  # each drawn agent's slot in the grid's build number `_located`
        self._located = -1
        # membership as one bit per agent (it stays in cache during a pass over all agents) and, per 32-agent word,
        # the rank of its first selected agent: see drawn_rank
        words = (grid.n + 31) // 32
        self.bits = ti.ndarray(ti.u32, words)
        self.word_rank = ti.ndarray(ti.i32, words)
        if len(self.selected_ids):
            word = self.selected_ids >> 5
            bits = np.zeros(words, dtype=np.uint32)
            np.bitwise_or.at(bits, word, np.left_shift(np.uint32(1), (self.selected_ids & 31).astype(np.uint32)))
            self.bits.from_numpy(bits)
            self.word_rank.from_numpy(np.concatenate(([0], np.cumsum(np.bincount(word, minlength=words))[:-1]))
                                      .astype(np.int32))

    def located(self) -> None:
        """Say that ``slot`` holds each drawn agent's slot in the grid's current build (a model's frame rows pass
        over the grid's agents can write it for free, see Vicsek's ``_drawn_rows``)."""
        self._located = self.grid.builds

    def locate(self) -> None:
        """Fill ``slot`` for the grid's current build, unless it holds it already."""
        if self._located != self.grid.builds and len(self.selected_ids):
            _drawn_slots(self.grid.n, self.grid.id_sorted, self.bits, self.word_rank, self.slot)
            self.located()


@ti.kernel
def _lower_pairs(rows: ti.i32, n: ti.i32, radius: float, box: float, nc: ti.i32,
                 n_buckets: ti.i32, boundary: ti.template(), dim: ti.template(), start: ti.types.ndarray(),
                 mixed: ti.types.ndarray(), id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
                 coords_sorted: ti.types.ndarray(), counts: ti.types.ndarray(), offsets: ti.types.ndarray(),
                 fill: ti.i32, edges: ti.types.ndarray()):
    """Count (fill = 0) or write (fill = 1, from `offsets`) each row's pairs with the earlier rows within R, for
    rows 0 .. rows - 1 of a grid of n >= rows agents whose ids are the rows (a run-time flag: one kernel for both
    passes).
    An edge goes from the row's position to the earlier row's nearest image (minimum image when periodic).
    The rows are taken in the grid's slot order, so that neighbouring rows' stencils share the cache (in row order
    each row's cells are a random read); each row's edges come out in the same order either way."""
    for s in range(n):
        r = id_sorted[s]
        if r >= rows:  # a row past the pass's (the write pass takes the rows whose edges fit)
            continue
        e = 0
        if fill:
            e = offsets[r]
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        for o in range(ti.static(span_count(boundary, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, dim)
            for k in range(begin, end):
                d = displacement(p, load_vec(pos_sorted, k, dim), box, boundary)
                keep = id_sorted[k] < r and d.norm_sqr() <= radius * radius
                if keep and (check == 0 or same_cell(coords_sorted, k, cell, boundary, dim) == 1):
                    if fill:
                        for a in ti.static(range(dim)):
                            edges[e, 0, a] = p[a]
                            edges[e, 1, a] = p[a] + d[a]
                    e += 1
        if not fill:
            counts[r] = e


@ti.kernel
def _all_pairs(m: ti.i32, radius: float, box: float, max_edges: ti.i32, boundary: ti.template(), dim: ti.template(),
               x: ti.types.ndarray(), edges: ti.types.ndarray(), count: ti.types.ndarray()):
    """:meth:`DrawnEdges.edges` of the rows x[0 .. m) (x: (m, dim)) from all their pairs, on one thread: each row's
    pairs with the earlier rows within R, tested and drawn as :func:`_lower_pairs` does, rows in order, the earlier
    rows in order; only whole rows, while all their edges fit in `max_edges`. count[0]: the edges written."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        e = 0
        r = 1
        while r < m:
            first = e  # the row's first edge: the row is dropped whole if its edges do not all fit
            p = ti.Vector([x[r, a] for a in ti.static(range(dim))])
            for k in range(r):
                d = displacement(p, ti.Vector([x[k, a] for a in ti.static(range(dim))]), box, boundary)
                if d.norm_sqr() <= radius * radius:
                    if e < max_edges:
                        for a in ti.static(range(dim)):
                            edges[e, 0, a] = p[a]
                            edges[e, 1, a] = p[a] + d[a]
                    e += 1
            if e > max_edges:
                e = first
                break
            r += 1
        count[0] = e


class DrawnEdges:
    """Neighbour edges among the drawn agents of a frame: a faithful sample of the R-graph (DESIGN.md section 5).

    The drawn agents are a seeded random subset, taken in id order (their frame rows), so any first K of them are a
    uniform sample spread over the whole swarm. :meth:`edges` draws the graph induced on the first K rows, all of
    its pairs within R, with K as large as `max_edges` allows (all rows when their pairs fit). It finds them on a
    grid of its own over those rows' positions (a frame's drawn agents are few and far between in the model's grid,
    where each query would miss the cache), built over a power of two of rows: about as many as the last frame
    needed, doubled until their pairs reach the cap.
    """

    def __init__(self, dim: int, boundary: str, box: float, radius: float, real: type) -> None:
        self.dim, self.boundary, self.box, self.radius, self.real = dim, boundary, box, radius, real
        self._grids: dict[int, tuple[CellGrid, ti.Ndarray, ti.Ndarray]] = {}
        self._rows_needed = 0  # rows the last frame's edges came from

    def _grid(self, rows: int) -> tuple[CellGrid, ti.Ndarray, ti.Ndarray]:
        if rows not in self._grids:
            ftype = ti.f32 if self.real == np.float32 else ti.f64
            ids = ti.ndarray(ti.i32, rows)
            ids.from_numpy(np.arange(rows, dtype=np.int32))
            self._grids[rows] = (CellGrid(rows, self.dim, self.boundary, self.box, self.radius, self.real),
                                 ti.ndarray(ftype, (self.dim, rows)), ids)
        return self._grids[rows]

    def edges(self, positions: np.ndarray, max_edges: int) -> np.ndarray:
        """Segments (E, 2, dim), E <= max_edges: the pairs within R among the first K of the drawn agents at
        `positions` (M, dim), each once, from the later row to the earlier (the far end by the minimum image, so
        no edge spans a periodic box), rows in order."""
        m = len(positions)
        if m < 2 or max_edges <= 0:
            return np.zeros((0, 2, self.dim), dtype=self.real)
        engine = current_engine()
        if m <= ALL_PAIRS_ROWS and engine is not None and engine.arch == "cpu":  # (a GPU thread alone is slow)
            edges = np.empty((min(max_edges, m * (m - 1) // 2), 2, self.dim), dtype=self.real)
            count = np.zeros(1, dtype=np.int32)
            _all_pairs(m, self.radius, self.box, max_edges, boundary_code(self.boundary), self.dim,
                       np.ascontiguousarray(positions, dtype=self.real), edges, count)
            return edges[: count[0]]
        rows = min(m, 1 << max(8, math.ceil(math.log2(max(1.25 * self._rows_needed, 1.0)))))
        while True:
            grid, pos, ids = self._grid(rows)
            pos.from_numpy(np.ascontiguousarray(np.asarray(positions[:rows], dtype=self.real).T))
            grid.build(pos, ids)
            counts = np.zeros(rows, dtype=np.int32)  # written in place on the CPU (Taichi copies them on a GPU)
            unused_offsets, unused_edges = np.zeros(1, dtype=np.int32), np.zeros((1, 2, self.dim), dtype=self.real)
            args = self._arguments(grid)
            _lower_pairs(rows, *args, counts, unused_offsets, 0, unused_edges)
            total = np.cumsum(counts, dtype=np.int64)
            if total[-1] > max_edges or rows == m:
                break
            rows = min(m, 2 * rows)
        needed = int(np.searchsorted(total, max_edges, side="right"))  # rows whose pairs all fit
        self._rows_needed = needed
        count = int(total[needed - 1]) if needed else 0
        edges = np.zeros((count, 2, self.dim), dtype=self.real)
        if count:
            offsets = np.zeros(needed, dtype=np.int32)
            offsets[1:] = total[: needed - 1]
            _lower_pairs(needed, *args, counts, offsets, 1, edges)
        return edges

    def _arguments(self, grid: CellGrid) -> tuple:
        g = grid.geometry
        return (grid.n, self.radius, self.box, g.cells_per_side, g.n_buckets, g.boundary, g.dim, grid.start,
                grid.mixed, grid.id_sorted, grid.pos_sorted, grid.coords_sorted)
