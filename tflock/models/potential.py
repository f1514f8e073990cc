"""Tanner-Jadbabaie-Pappas potential-field flocking (DESIGN.md section 3.3; papers/001).

Double integrators (eq. 1) r_i' = v_i, v_i' = u_i steered by the control law (eq. 3)

    u_i = - sum_{j in N_i} (v_i - v_j) - sum_{j in N_i} grad_{r_i} V(|r_ij|),

with the potential of Definition 2, V(r) = d^2 / r^2 + ln(r^2) (minimum at the desired distance d, infinite at 0),
whose gradient is grad_{r_i} V(|r_ij|) = 2 (|r_ij|^2 - d^2) / |r_ij|^4 r_ij, r_ij = r_i - r_j.

- switching topology (section 5): N_i = {j : |r_ij| < R}, d < R; the saturated U(r) = V(min(r, R)) makes the force
  vanish beyond R. Neighbours come from an open-space cell grid laid over the swarm's bounding box (hashed when a
  straggler spreads that box too thin; :class:`tflock.neighbors.CellGrid`), the state is kept in cell order
  (``ids`` names the agent at each element), as in the Vicsek model. On the CPU a step takes runs of cells 8
  agents at a time (:func:`_step_lanes`); GPU arches keep the hashed grid (the layout over the bounding box has
  not run on one yet) and visit each agent's stencil alone.
- fixed topology (section 4): a connected graph (:mod:`tflock.models.potential_graphs`) in CSR form, neighbours
  regardless of distance; the state stays in agent order.

Integration: semi-implicit (symplectic) Euler with a fixed dt, one neighbour pass per step:
v(t + dt) = v(t) + dt u(r(t), v(t)), r(t + dt) = r(t) + dt v(t + dt).
Initial state (section 6): :func:`tflock.models.potential_graphs.initial_state`.

Lyapunov functions: W = 1/2 sum_i (V_i + |v_i|^2) (eq. 5) for a fixed graph; for switching Q (eq. 10) less its
constant part: Q - N (N - 1) / 2 V(R) = 1/2 sum |v_i|^2 + sum_{pairs, |r_ij| < R} (V(|r_ij|) - V(R)), which is
local. Both must not increase (dW/dt = -v^T (L x I) v, eq. 8 and 12) beyond the integration error.
"""


import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, one_thread, task_at
from tflock.engine import EngineInfo
from tflock.field import VECTORS
from tflock.frame import ColorLegend, Frame, WorldSpec, arrow_length, color_table, look_up
from tflock.lane_graph import (
    NO_LABEL,
    LaneComponents,
    block_roots,
    count_roots,
    fold_label,
    join_candidate,
    lowest_lane,
    settle_block,
    stripe_range,
)
from tflock.metrics import EXACT_PAIRS_MAX, NeighbourGraph
from tflock.models.base import GridModel, Lyapunov
from tflock.models.potential_graphs import fixed_graph_edges, initial_state, to_csr
from tflock.models.potential_params import PotentialParams
from tflock.neighbors import (
    BOUNDED,
    LANES,
    CellGrid,
    bounded_layout,
    build_grid,
    cut_runs,
    drawn_rank,
    load_cell,
    load_vec,
    run_at,
    run_spans,
    same_cell,
    span_agents,
    span_count,
    stencil_span,
)
from tflock.reductions import BLOCK, n_blocks, scratch, total
from tflock.space import OPEN
from tflock.taichi_host import host_array, host_view, small_host_view

#: a swarm of at most this many agents runs all the steps of an advance() in one single-threaded launch (a fixed
#: graph's, and a switching one's on the CPU), and its lane-wise metrics pass in two launches
FUSED_MAX_N = 4096
#: agents up to which :func:`_exact_nearest` (all n^2 pairs) runs on the calling thread: at 256 agents 88 against
#: 162 us on the thread pool of 2 cores, at 1024 agents 1335 against 1104 us
EXACT_NEAREST_ONE_THREAD = 256
#: per-agent series (valency_i, speed_i; the paper's Figs. 6-8) are recorded up to this many agents
PER_AGENT_MAX = 20
#: lambda_2 of the graph Laplacian (numpy.linalg.eigvalsh) is computed up to this many agents
LAMBDA2_MAX = 1000

#: slow to fast: blue, sky, green, yellow, red; every stop bright enough to see on the viewer's dark background
_SPEED_RAMP = np.array([[96, 110, 255], [0, 190, 255], [40, 215, 110], [240, 215, 40], [255, 80, 60]], dtype=np.float64)


def _speed_palette(levels: int) -> np.ndarray:
    """The ramp at `levels` evenly spaced points of [0, 1], (levels, 3) uint8."""
    t = np.linspace(0.0, 1.0, levels) * (len(_SPEED_RAMP) - 1)
    k = np.minimum(t.astype(np.int64), len(_SPEED_RAMP) - 2)
    f = (t - k)[:, None]
    return np.rint(_SPEED_RAMP[k] * (1 - f) + _SPEED_RAMP[k + 1] * f).astype(np.uint8)


_SPEED_LEVELS = 1024  # finer than a colour channel's 256 levels along the ramp's longest leg
_SPEED_PALETTE = color_table(_speed_palette(_SPEED_LEVELS))


def speed_colors(speed: np.ndarray, scale: float) -> np.ndarray:
    """(M, 3) uint8: speed / scale in [0, 1] on a ramp from blue (slow) over green and yellow to red (fast), looked
    up in a table of 1024 levels, within one level of each channel of the ramp itself (one gather, no per-agent
    maths)."""
    t = np.clip(np.asarray(speed, dtype=np.float32) * np.float32(1.0 / scale), 0.0, 1.0)
    return look_up(_SPEED_PALETTE, np.rint(t * np.float32(_SPEED_LEVELS - 1)).astype(np.int64))


@ti.func
def _pair_acceleration(p, v, q, w, d2):
    """Agent j's term of u_i (eq. 3): (v_j - v_i) - grad_{r_i} V, with q - p = r_j - r_i = -r_ij."""
    dvec = q - p
    r2 = dvec.norm_sqr()
    return (w - v) + 2.0 * (r2 - d2) / (r2 * r2) * dvec


@ti.kernel
def _velocity_blocks(n: ti.i32, dim: ti.template(), vel: ti.types.ndarray(), partial: ti.types.ndarray()):
    """For each block of BLOCK agents: every velocity component's max (partial[b, a]) and min (partial[b, dim + a]),
    and the sum of |v_i|^2 (partial[b, 2 dim]); the blocks are reduced in NumPy, the same whatever the threads."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            lo = blk * BLOCK
            hi = ti.min(n, lo + BLOCK)
            squares = 0.0
            for a in ti.static(range(dim)):
                big = vel[a, lo]
                small = vel[a, lo]
                for i in range(lo, hi):
                    big = ti.max(big, vel[a, i])
                    small = ti.min(small, vel[a, i])
                    squares += vel[a, i] * vel[a, i]
                partial[blk, a] = big
                partial[blk, dim + a] = small
            partial[blk, 2 * dim] = squares


@ti.kernel
def _pair_blocks(n: ti.i32, valency: ti.types.ndarray(), energy: ti.types.ndarray(), nearest: ti.types.ndarray(),
                 partial: ti.types.ndarray()):
    """Per block of BLOCK agents, in float64: the valencies' sum, smallest and largest, the energies' sum and the
    smallest nearest distance (partial[b, 0..4]); the blocks are reduced in NumPy, the same whatever the threads."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            lo = blk * BLOCK
            count = 0
            fewest = valency[lo]
            most = valency[lo]
            pot = ti.cast(0.0, ti.f64)
            near = ti.cast(nearest[lo], ti.f64)
            for i in range(lo, ti.min(n, lo + BLOCK)):
                count += valency[i]
                fewest = ti.min(fewest, valency[i])
                most = ti.max(most, valency[i])
                pot += ti.cast(energy[i], ti.f64)
                near = ti.min(near, ti.cast(nearest[i], ti.f64))
            partial[blk, 0] = ti.cast(count, ti.f64)
            partial[blk, 1] = ti.cast(fewest, ti.f64)
            partial[blk, 2] = ti.cast(most, ti.f64)
            partial[blk, 3] = pot
            partial[blk, 4] = near


#: columns of :func:`_velocity_stats`' partials: sums of v (dim), |v|, |v|^2, v / |v| (dim), |v - mean|, then the
#: largest |v|, smallest |v| and largest |v - mean|
def _velocity_columns(dim: int) -> int:
    return 2 * dim + 6


@ti.func
def _group_velocities(vel: ti.template(), i0, width, valid, dim: ti.template(), masked: ti.template()):
    """The velocities of the ``LANES`` agents from i0 in float64, (dim, LANES); `masked`: 0 past the first `width`
    (read no further)."""
    if ti.static(masked):
        return ti.Matrix([[ti.select(valid[q], ti.cast(vel[a, i0 + ti.min(q, width - 1)], ti.f64), 0.0)
                           for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
    return ti.Matrix([[ti.cast(vel[a, i0 + q], ti.f64) for q in ti.static(range(LANES))]
                      for a in ti.static(range(dim))])


@ti.func
def _velocity_group(acc, vel: ti.template(), i0, width, c, dim: ti.template(), with_mismatch: ti.template(),
                    masked: ti.template()):
    """:func:`_velocity_stats`' lane-wise sums and extremes `acc` (rows: see there) with the ``LANES`` agents from
    i0 added, one a lane; `masked`: only the first `width` of them (a block's last group; the other lanes count
    nothing). The full groups take no mask, which keeps their loop in vector registers."""
    valid = ti.Vector([q for q in ti.static(range(LANES))]) < width
    v = _group_velocities(vel, i0, width, valid, dim, masked)
    out = acc
    if ti.static(with_mismatch):  # rows: sum |v - c|, largest |v - c|
        gap = ti.Vector([0.0] * LANES, dt=ti.f64)
        for a in ti.static(range(dim)):
            d = ti.Vector([v[a, q] for q in ti.static(range(LANES))]) - c[a]
            gap += d * d
        gap = ti.sqrt(gap)
        if ti.static(masked):
            gap = ti.select(valid, gap, 0.0)
        for q in ti.static(range(LANES)):
            out[0, q] += gap[q]
            out[1, q] = ti.max(out[1, q], gap[q])
    else:  # rows: sum v (dim), sum |v|, sum |v|^2, sum v / |v| (dim), largest |v|, smallest |v|
        sq = ti.Vector([0.0] * LANES, dt=ti.f64)
        for a in ti.static(range(dim)):
            sq += ti.Vector([v[a, q] * v[a, q] for q in ti.static(range(LANES))])
        speed = ti.sqrt(sq)
        per = 1.0 / ti.select(speed > 0, speed, 1.0)  # (v is 0 where the speed is)
        slowest = speed
        if ti.static(masked):
            slowest = ti.select(valid, speed, math.inf)
        for q in ti.static(range(LANES)):
            for a in ti.static(range(dim)):
                out[a, q] += v[a, q]
                out[dim + 2 + a, q] += v[a, q] * per[q]
            out[dim, q] += speed[q]
            out[dim + 1, q] += sq[q]
            out[2 * dim + 2, q] = ti.max(out[2 * dim + 2, q], speed[q])
            out[2 * dim + 3, q] = ti.min(out[2 * dim + 3, q], slowest[q])
    return out


@ti.func
def _lanes(acc, row: ti.template()):
    """Row `row` of a lane-wise accumulator, as a vector over the lanes."""
    return ti.Vector([acc[row, q] for q in ti.static(range(LANES))])


@ti.kernel
def _velocity_stats(n: ti.i32, dim: ti.template(), vel: ti.types.ndarray(), centre: ti.types.ndarray(),
                    with_mismatch: ti.template(), partial: ti.types.ndarray()):
    """Per block of BLOCK agents, in float64 (see :func:`_velocity_columns`): the sums, extremes and unit
    headings of the velocities; with `with_mismatch`, only |v_i - centre| (centre: the mean velocity, from a first
    launch whose columns it leaves as they are). ``LANES`` agents at a time (:func:`_velocity_group`), each lane
    summing its own agents, the lanes added at the block's end (a loop over single agents stays scalar: LLVM does
    not vectorise its float64 max and min). The blocks are added in NumPy: the same whatever the threads."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            lo = blk * BLOCK
            width = ti.min(n, lo + BLOCK) - lo
            rows = ti.static(2 if with_mismatch else 2 * dim + 4)
            slow = ti.static(-1 if with_mismatch else 2 * dim + 3)  # the row of minima, which start at infinity
            acc = ti.Matrix([[math.inf if r == slow else 0.0] * LANES for r in ti.static(range(rows))], dt=ti.f64)
            c = ti.Vector([centre[a] for a in ti.static(range(dim))], dt=ti.f64)
            full = width // LANES
            for k in range(full):
                acc = _velocity_group(acc, vel, lo + k * LANES, LANES, c, dim, with_mismatch, False)
            if width > full * LANES:
                acc = _velocity_group(acc, vel, lo + full * LANES, width - full * LANES, c, dim, with_mismatch, True)
            if ti.static(with_mismatch):
                partial[blk, 2 * dim + 2] = _lanes(acc, 0).sum()
                partial[blk, 2 * dim + 5] = _lanes(acc, 1).max()
            else:
                for r in ti.static(range(2 * dim + 2)):  # the sums: columns in the rows' order
                    partial[blk, r] = _lanes(acc, r).sum()
                partial[blk, 2 * dim + 3] = _lanes(acc, 2 * dim + 2).max()
                partial[blk, 2 * dim + 4] = _lanes(acc, 2 * dim + 3).min()


@ti.func
def _gather_velocities(n, dim: ti.template(), order: ti.template(), vel: ti.template(), vel_sorted: ti.template()):
    """Velocities in cell order: contiguous reads in the neighbour loops."""
    for s in range(n):
        e = order[s]
        for a in ti.static(range(dim)):
            vel_sorted[a, s] = vel[a, e]


@ti.kernel
def _sort_velocities(n: ti.i32, dim: ti.template(), order: ti.types.ndarray(), vel: ti.types.ndarray(),
                     vel_sorted: ti.types.ndarray()):
    _gather_velocities(n, dim, order, vel, vel_sorted)


@ti.kernel
def _step_switching(n: ti.i32, r2cut: float, d2: float, dt: float, dim: ti.template(), layout: ti.template(),
                    nc: ti.i32, n_buckets: ti.i32, start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                    id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                    vel_sorted: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(),
                    ids: ti.types.ndarray()):
    """One step, each agent's stencil visited alone (3D, GPU arches, and the hashed layout)."""
    for s in range(n):  # new state written at slot s: the arrangement becomes this step's cell order
        p = load_vec(pos_sorted, s, dim)
        v = load_vec(vel_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        u = ti.Vector([0.0] * dim)
        for o in range(ti.static(span_count(layout, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, layout, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, layout, dim)
            for k in range(begin, end):
                q = load_vec(pos_sorted, k, dim)
                r2 = (q - p).norm_sqr()
                inside = r2 < r2cut and k != s
                if check:
                    inside = inside and same_cell(coords_sorted, k, cell, layout, dim) == 1
                q = ti.select(k != s, q, p + 1.0)  # itself: any finite term (not added), no 0 / 0
                u += ti.select(inside, _pair_acceleration(p, v, q, load_vec(vel_sorted, k, dim), d2), 0.0)
        v_new = v + dt * u
        p_new = p + dt * v_new
        for a in ti.static(range(dim)):
            vel[a, s] = v_new[a]
            pos[a, s] = p_new[a]
        ids[s] = id_sorted[s]


@ti.func
def _accelerations(begin, end, ids, p, v, u, r2cut, d2, dim: ti.template(), id_sorted: ti.template(),
                   pos_sorted: ti.template(), vel_sorted: ti.template()):
    """Add the terms of u_i (eq. 3) of the candidates [begin, end) within R to each lane's sums: p, v, u are
    (dim, LANES) matrices, a column an agent, `ids` its agent ids. A lane tells itself from the others by id, a
    32-bit compare with one broadcast load, where the slot (the loop's 64-bit index) takes two compares and a pack.
    An exit that never fires keeps LLVM's loop vectoriser off this loop, as in the Vicsek model's lane-wise sums
    (vectorised across candidates too, the loop is slower)."""
    u, _ = _counted_accelerations(begin, end, ids, p, v, u, ti.Vector([0] * LANES), r2cut, d2, dim, id_sorted,
                                  pos_sorted, vel_sorted, False)
    return u


@ti.func
def _counted_accelerations(begin, end, ids, p, v, u, count, r2cut, d2, dim: ti.template(), id_sorted: ti.template(),
                           pos_sorted: ti.template(), vel_sorted: ti.template(), counted: ti.template()):
    """:func:`_accelerations`, and where `counted` each lane's candidates within R added to `count` (its valency
    |N_i|, in the loop that tests them for the accelerations anyway)."""
    for k in range(begin, end):
        j = id_sorted[k]
        if j < 0:  # never: ids count from 0
            break
        d = ti.Matrix([[pos_sorted[a, k] - p[a, q] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
        r2 = ti.Vector([d[0, q] * d[0, q] for q in ti.static(range(LANES))])
        # (the squared distances as _lane_r2 sums them: one helper giving both the offsets and the distances made
        # LLVM permute the lanes' masks in this loop, 5 % slower in the metrics step's sums)
        for a in ti.static(range(1, dim)):  # summed in the order of the per-agent kernel's norm_sqr
            r2 += ti.Vector([d[a, q] * d[a, q] for q in ti.static(range(LANES))])
        inside = (r2 < r2cut) & (ids != j)
        coef = 2.0 * (r2 - d2) / (r2 * r2)  # itself: 0 / 0, never added
        for a in ti.static(range(dim)):
            for q in ti.static(range(LANES)):
                u[a, q] += ti.select(inside[q], (vel_sorted[a, k] - v[a, q]) + coef[q] * d[a, q], 0.0)
        if ti.static(counted):
            count += ti.select(inside, 1, 0)
    return u, count


@ti.func
def _lanes_step(total_buckets, nc, r2cut, d2, dt, dim: ti.template(), layout: ti.template(), start: ti.template(),
                run_end: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(), vel_sorted: ti.template(),
                pos: ti.template(), vel: ti.template(), ids: ti.template(), draw: ti.template(), bits: ti.template(),
                word_rank: ti.template(), drawn: ti.template()):
    """One step on the CPU, ``LANES`` agents at a time: the agents of each run of cells (:meth:`CellGrid.runs`)
    against every candidate of the run's 3^(dim - 1) x (width + 2) cells, then the move (as
    :func:`_step_switching`, term for term and in the same order: a run's wider window only adds candidates beyond
    R, which are not added). With `draw`, the drawn agents' frame rows too: ``drawn[0]`` positions, ``drawn[1]``
    velocities, row r for the agent of rank r (:func:`drawn_rank`); a compiled variant of its own, since a run-time
    flag would slow every step, drawn or not."""
    for b in range(total_buckets):
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        for block in range((a1 - a0 + LANES - 1) // LANES):
            i0 = a0 + block * LANES
            s = ti.Vector([ti.min(i0 + k, a1 - 1) for k in ti.static(range(LANES))])
            p = ti.Matrix([[pos_sorted[a, s[q]] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
            v = ti.Matrix([[vel_sorted[a, s[q]] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
            u = p * 0.0
            lane_ids = ti.Vector([id_sorted[s[q]] for q in ti.static(range(LANES))])
            for r in range(ti.static(3 ** (dim - 1))):
                begin, end, _, _ = run_spans(row, x0, x1, r, nc, start, layout, dim)
                u = _accelerations(begin, end, lane_ids, p, v, u, r2cut, d2, dim, id_sorted, pos_sorted, vel_sorted)
            v += dt * u
            p += dt * v
            for k in ti.static(range(LANES)):
                if i0 + k < a1:
                    for a in ti.static(range(dim)):
                        vel[a, i0 + k] = v[a, k]
                        pos[a, i0 + k] = p[a, k]
                    ids[i0 + k] = id_sorted[i0 + k]
            if ti.static(draw):
                for k in ti.static(range(LANES)):
                    r = drawn_rank(lane_ids[k], bits, word_rank)
                    if i0 + k < a1 and r >= 0:
                        for a in ti.static(range(dim)):
                            drawn[0, r, a] = p[a, k]
                            drawn[1, r, a] = v[a, k]


@ti.kernel
def _step_lanes(total_buckets: ti.i32, nc: ti.i32, r2cut: float, d2: float, dt: float, dim: ti.template(),
                layout: ti.template(), start: ti.types.ndarray(), run_end: ti.types.ndarray(),
                id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), vel_sorted: ti.types.ndarray(),
                pos: ti.types.ndarray(), vel: ti.types.ndarray(), ids: ti.types.ndarray(), draw: ti.template(),
                bits: ti.types.ndarray(), word_rank: ti.types.ndarray(), drawn: ti.types.ndarray()):
    _lanes_step(total_buckets, nc, r2cut, d2, dt, dim, layout, start, run_end, id_sorted, pos_sorted, vel_sorted, pos,
                vel, ids, draw, bits, word_rank, drawn)


@ti.func
def _fixed_agent(i, d2, dt, dim: ti.template(), offsets: ti.template(), neighbours: ti.template(),
                 pos: ti.template(), vel: ti.template(), pos_out: ti.template(), vel_out: ti.template()):
    """Agent i's semi-implicit Euler step on the fixed graph (eq. 3): from (pos, vel) into (pos_out, vel_out)."""
    p = load_vec(pos, i, dim)
    v = load_vec(vel, i, dim)
    u = ti.Vector([0.0] * dim)
    for k in range(offsets[i], offsets[i + 1]):
        j = neighbours[k]
        u += _pair_acceleration(p, v, load_vec(pos, j, dim), load_vec(vel, j, dim), d2)
    v_new = v + dt * u
    p_new = p + dt * v_new
    for a in ti.static(range(dim)):
        vel_out[a, i] = v_new[a]
        pos_out[a, i] = p_new[a]


@ti.kernel
def _step_fixed(n: ti.i32, d2: float, dt: float, dim: ti.template(), offsets: ti.types.ndarray(),
                neighbours: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(),
                pos_out: ti.types.ndarray(), vel_out: ti.types.ndarray()):
    for i in range(n):
        _fixed_agent(i, d2, dt, dim, offsets, neighbours, pos, vel, pos_out, vel_out)


@ti.kernel
def _steps_fixed(steps: ti.i32, n: ti.i32, d2: float, dt: float, dim: ti.template(), offsets: ti.types.ndarray(),
                 neighbours: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(),
                 pos_out: ti.types.ndarray(), vel_out: ti.types.ndarray()):
    """`steps` steps of :func:`_step_fixed` in one launch, on one thread (a small swarm: a launch costs more than
    its arithmetic): even steps go from (pos, vel) to (pos_out, vel_out), odd steps back, so after an odd number
    of steps the new state is in the `_out` arrays, as after as many single steps that swap the buffers."""
    ti.loop_config(serialize=True)
    for step in range(steps):
        if step % 2 == 0:
            for i in range(n):
                _fixed_agent(i, d2, dt, dim, offsets, neighbours, pos, vel, pos_out, vel_out)
        else:
            for i in range(n):
                _fixed_agent(i, d2, dt, dim, offsets, neighbours, pos_out, vel_out, pos, vel)


@ti.kernel
def _grid_pairs(n: ti.i32, r2cut: float, d2: float, v_cut: float, dim: ti.template(), layout: ti.template(),
                nc: ti.i32, n_buckets: ti.i32, start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                valency: ti.types.ndarray(), energy: ti.types.ndarray(), nearest: ti.types.ndarray()):
    """Per agent (agent order): valency |N_i| (|r_ij| < R), half its saturated potential 1/2 sum (V - V(R)) and
    the distance to its nearest agent, capped at R."""
    for s in range(n):
        p = load_vec(pos_sorted, s, dim)
        c = load_cell(coords_sorted, s, dim)
        count = 0
        pot = 0.0
        near = r2cut
        for o in range(ti.static(span_count(layout, dim))):
            lo, hi, cell = stencil_span(c, o, nc, n_buckets, layout, dim)
            begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, layout, dim)
            for k in range(begin, end):
                r2 = (load_vec(pos_sorted, k, dim) - p).norm_sqr()
                other = (check == 0 or same_cell(coords_sorted, k, cell, layout, dim) == 1) and k != s
                if other and r2 < r2cut:
                    count += 1
                    pot += d2 / r2 + ti.log(r2) - v_cut
                    near = ti.min(near, r2)
        i = id_sorted[s]
        valency[i] = count
        energy[i] = 0.5 * pot
        nearest[i] = ti.sqrt(near)


#: the metrics pass takes the log of its product of r^2 / R^2 once it falls below this (2^-511): a stencil row's
#: factors (one per neighbour in it) could underflow it only below 2^-1022, more than 255 neighbours at d = R / 2
PRODUCT_FLOOR = 2.0**-511


@ti.func
def _lane_r2(k, p, dim: ti.template(), pos_sorted: ti.template()):
    """Squared distances from candidate k to the ``LANES`` agents p (dim, LANES), summed as the per-agent kernel's
    norm_sqr sums them (and :func:`_accelerations`)."""
    d = ti.Matrix([[pos_sorted[a, k] - p[a, q] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
    r2 = ti.Vector([d[0, q] * d[0, q] for q in ti.static(range(LANES))])
    for a in ti.static(range(1, dim)):
        r2 += ti.Vector([d[a, q] * d[a, q] for q in ti.static(range(LANES))])
    return r2


# The metrics' sums over a span of candidates, for LANES agents at once (p: (dim, LANES), a column an agent with id
# ids[q]), in the components pass's loops, not in _accelerations': one loop carrying the accelerations and all these
# sums ran several times slower than the loops apart (the valencies alone ride in it, _counted_accelerations). Each
# loop has an exit that never fires, which keeps LLVM's loop vectoriser off it, as in _accelerations.

@ti.func
def _pair_terms(r2, inside, count, pot, product, near, inv_r2cut, d2, v_cut):
    """Add one pair per lane where `inside` to the lanes' pair sums: their count, the saturated potential's
    d^2 / r^2 - V(R) terms, the float64 product of r^2 / R^2 (each factor in (0, 1), a product by 1 / R^2,
    `inv_r2cut`: a float64 division per candidate would cost more than the rest of the loop; the potential's
    logarithms are summed as the log of the product, which :func:`_pair_potentials` takes) and the nearest squared
    distance."""
    count += ti.select(inside, 1, 0)
    near = ti.select(inside, ti.min(near, r2), near)
    pot += ti.select(inside, d2 / r2 - v_cut, 0.0)  # itself: 0 / 0, never added
    product *= ti.select(inside, ti.cast(r2, ti.f64) * inv_r2cut, 1.0)
    return count, pot, product, near


@ti.func
def _pair_sums(begin, end, ids, p, label, other, count, pot, product, near, r2cut, inv_r2cut, d2, v_cut,
               dim: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(), parent: ti.template(),
               labelled: ti.template()):
    """:func:`_pair_terms` of the candidates [begin, end) within R; where `labelled` (candidates in the stripe before
    the block, settled) each also folds its set label into the lanes it is near (the components,
    :mod:`tflock.lane_graph`)."""
    for k in range(begin, end):
        j = id_sorted[k]
        if j < 0:  # never: ids count from 0
            break
        r2 = _lane_r2(k, p, dim, pos_sorted)
        inside = (r2 < r2cut) & (ids != j)
        if ti.static(labelled):
            label, other = fold_label(label, other, inside, parent[k])
        count, pot, product, near = _pair_terms(r2, inside, count, pot, product, near, inv_r2cut, d2, v_cut)
    return label, other, count, pot, product, near


@ti.func
def _block_pairs(i0, i1, ids, p, count, pot, product, near, r2cut, inv_r2cut, d2, v_cut, dim: ti.template(),
                 id_sorted: ti.template(), pos_sorted: ti.template()):
    """The block's own pairs (slots [i0, i1)), as the candidate loops test them: per lane, the bit mask of the lanes
    within R of it, itself included (:func:`tflock.lane_graph.settle_block`), and :func:`_pair_terms` of the lanes
    within R before it in the block (each pair once, at its later lane). A loop over the block's agents, not
    LANES unrolled steps: a block holds 6 to 7 agents on average in a sparse swarm."""
    inmask = ti.Vector([1 << q for q in ti.static(range(LANES))])
    slots = ti.Vector([i0 + q for q in ti.static(range(LANES))])
    for k in range(i0, i1):
        j = id_sorted[k]
        if j < 0:  # never: ids count from 0 (an exit that keeps LLVM's loop vectoriser off, as in _accelerations)
            break
        r2 = _lane_r2(k, p, dim, pos_sorted)
        inside = (r2 < r2cut) & (ids != j)
        inmask |= ti.select(inside, 1 << (k - i0), 0)
        count, pot, product, near = _pair_terms(r2, inside & (slots > k) & (slots < i1), count, pot, product, near,
                                                inv_r2cut, d2, v_cut)
    return inmask, count, pot, product, near


@ti.kernel
def _step_sums_lanes(total_buckets: ti.i32, nc: ti.i32, r2cut: float, d2: float, dim: ti.template(),
                     layout: ti.template(), start: ti.types.ndarray(), run_end: ti.types.ndarray(),
                     id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), vel_sorted: ti.types.ndarray(),
                     accel: ti.types.ndarray(), valency: ti.types.ndarray(), serial: ti.template()):
    """The next step's neighbour pass, run for a state whose metrics are taken (as :func:`_step_lanes` takes the
    agents): each agent's u_i (eq. 3) into ``accel`` (slot order; :func:`_move` then makes the step, bit for bit as
    :func:`_step_lanes`) and its valency |N_i| (slot order too: written where the agent is, not scattered by id),
    counted in the same loop. `serial`: on the calling thread (a small swarm, :func:`tflock.cpu_tasks.one_thread`)."""
    ti.loop_config(serialize=serial)
    for b in range(total_buckets):
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        for block in range((a1 - a0 + LANES - 1) // LANES):
            i0 = a0 + block * LANES
            slots = ti.Vector([ti.min(i0 + k, a1 - 1) for k in ti.static(range(LANES))])
            p = ti.Matrix([[pos_sorted[a, slots[q]] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
            v = ti.Matrix([[vel_sorted[a, slots[q]] for q in ti.static(range(LANES))] for a in ti.static(range(dim))])
            u = p * 0.0
            ids = ti.Vector([id_sorted[slots[q]] for q in ti.static(range(LANES))])
            count = ti.Vector([0] * LANES)
            for r in range(ti.static(3 ** (dim - 1))):
                begin, end, _, _ = run_spans(row, x0, x1, r, nc, start, layout, dim)
                u, count = _counted_accelerations(begin, end, ids, p, v, u, count, r2cut, d2, dim, id_sorted,
                                                  pos_sorted, vel_sorted, True)
            for q in ti.static(range(LANES)):
                if i0 + q < a1:
                    for a in ti.static(range(dim)):
                        accel[a, i0 + q] = u[a, q]
                    valency[i0 + q] = count[q]


@ti.func
def _pair_potentials(count, pot, product, logs, r2cut):
    """Per lane, its pairs' saturated potential sum (V - V(R)) from :func:`_pair_terms`' sums: the d^2 / r^2 - V(R)
    terms plus the log of each r^2, the logs of the products (`logs` those taken so far, `product` the rest) and
    count log R^2 (one logarithm per agent, a call to libm each: not one per pair)."""
    logs += ti.log(product)
    return pot + ti.cast(logs + ti.cast(count, ti.f64) * ti.log(ti.cast(r2cut, ti.f64)), float)  # the run's type


@ti.func
def _stripe_components(j, n_stripes, layers, layer_buckets, nc, r2cut, d2, v_cut, dim: ti.template(),
                       layout: ti.template(), start: ti.template(), run_end: ti.template(), id_sorted: ti.template(),
                       pos_sorted: ti.template(), parent: ti.template(), size: ti.template(),
                       energy: ti.template(), nearest: ti.template()):
    """Stripe j's part of :func:`_components_lanes`."""
    inv_r2cut = 1.0 / ti.cast(r2cut, ti.f64)
    b_lo, b_hi, s_lo, _ = stripe_range(j, n_stripes, layers, layer_buckets, start)
    for b in range(b_lo, b_hi):
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        for block in range((a1 - a0 + LANES - 1) // LANES):
            i0 = a0 + block * LANES
            i1 = ti.min(i0 + LANES, a1)
            slots = ti.Vector([ti.min(i0 + k, a1 - 1) for k in ti.static(range(LANES))])
            p = ti.Matrix([[pos_sorted[a, slots[q]] for q in ti.static(range(LANES))]
                           for a in ti.static(range(dim))])
            ids = ti.Vector([id_sorted[slots[q]] for q in ti.static(range(LANES))])
            label = ti.Vector([NO_LABEL] * LANES)
            other = ti.Vector([NO_LABEL] * LANES)
            count = ti.Vector([0] * LANES)
            pot = ti.Vector([0.0] * LANES)
            logs = ti.Vector([0.0] * LANES, dt=ti.f64)
            product = ti.Vector([1.0] * LANES, dt=ti.f64)
            near = ti.Vector([r2cut] * LANES)
            for r in range(ti.static(3 ** (dim - 1))):  # the candidates before the block
                begin, end, _, _ = run_spans(row, x0, x1, r, nc, start, layout, dim)
                label, other, count, pot, product, near = _pair_sums(  # the earlier stripes' candidates
                    begin, ti.min(end, s_lo), ids, p, label, other, count, pot, product, near, r2cut, inv_r2cut, d2,
                    v_cut, dim, id_sorted, pos_sorted, parent, False)
                label, other, count, pot, product, near = _pair_sums(  # this stripe's, settled: their labels too
                    ti.max(begin, s_lo), ti.min(end, i0), ids, p, label, other, count, pot, product, near, r2cut,
                    inv_r2cut, d2, v_cut, dim, id_sorted, pos_sorted, parent, True)
                if (product < PRODUCT_FLOOR).any():  # its log, before the next span's factors could underflow it
                    logs += ti.log(product)
                    product = ti.Vector([1.0] * LANES, dt=ti.f64)
            inmask, count, pot, product, near = _block_pairs(i0, i1, ids, p, count, pot, product, near, r2cut,
                                                             inv_r2cut, d2, v_cut, dim, id_sorted, pos_sorted)
            pot = _pair_potentials(count, pot, product, logs, r2cut)
            for q in ti.static(range(LANES)):
                if i0 + q < a1:
                    energy[i0 + q] = pot[q]
                    nearest[i0 + q] = ti.sqrt(near[q])
            roots, recheck = block_roots(i1 - i0, label, other, parent, size)
            while recheck != 0:  # lanes near candidates of two sets: join each near candidate's set
                q = lowest_lane(recheck)
                here = load_vec(pos_sorted, i0 + q, dim)
                root = -1
                for r in range(ti.static(3 ** (dim - 1))):
                    begin, end, _, _ = run_spans(row, x0, x1, r, nc, start, layout, dim)
                    for k in range(ti.max(begin, s_lo), ti.min(end, i0)):
                        if (load_vec(pos_sorted, k, dim) - here).norm_sqr() < r2cut:
                            root = join_candidate(root, k, parent, size)
                roots[q] = root
                recheck &= recheck - 1
            settle_block(i0, i1 - i0, roots, inmask, parent, size, True)


@ti.kernel
def _components_lanes(n_stripes: ti.i32, layers: ti.i32, layer_buckets: ti.i32, nc: ti.i32, r2cut: float, d2: float,
                      v_cut: float, dim: ti.template(), layout: ti.template(), start: ti.types.ndarray(),
                      run_end: ti.types.ndarray(), id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
                      parent: ti.types.ndarray(), size: ti.types.ndarray(), energy: ti.types.ndarray(),
                      nearest: ti.types.ndarray()):
    """The components of the graph |r_ij| < R in ``parent``, ``LANES`` agents at a time (stripes of layers, a stripe
    a task, see :mod:`tflock.lane_graph`; its ``finish`` completes them), and per agent (at its grid slot) the pairs
    within R it makes with the agents at smaller grid slots, each pair once: their saturated potential
    sum (V - V(R)) in ``energy`` (whose total is the potential energy) and the nearest of them in ``nearest``
    (capped at R; the smallest over all agents is the nearest pair's). A block's candidates before it are all in
    its stencil's spans (the earlier stripes' for the pair sums only, its own stripe's also for the labels), and
    its own pairs in :func:`_block_pairs`."""
    for t in range(n_stripes * TASK_STRIDE):  # a stripe a task (tflock.cpu_tasks)
        j = task_at(t)
        if j >= 0:
            _stripe_components(j, n_stripes, layers, layer_buckets, nc, r2cut, d2, v_cut, dim, layout, start,
                               run_end, id_sorted, pos_sorted, parent, size, energy, nearest)


@ti.kernel
def _small_components(n: ti.i32, layers: ti.i32, layer_buckets: ti.i32, nc: ti.i32, r2cut: float, d2: float,
                      v_cut: float, dim: ti.template(), order: ti.types.ndarray(), vel: ti.types.ndarray(),
                      vel_sorted: ti.types.ndarray(), start: ti.types.ndarray(), run_end: ti.types.ndarray(),
                      id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), parent: ti.types.ndarray(),
                      size: ti.types.ndarray(), energy: ti.types.ndarray(), nearest: ti.types.ndarray(),
                      result: ti.types.ndarray()):
    """A small swarm's part of the lane-wise metrics pass before its sums (:func:`_step_sums_lanes`), in one launch
    on one thread (a launch costs more than its arithmetic): the velocities in cell order
    (:func:`_gather_velocities`) and :func:`_components_lanes` as one stripe, counted
    (:func:`tflock.lane_graph.count_roots`: result = components, agents in the largest)."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        _gather_velocities(n, dim, order, vel, vel_sorted)
        _stripe_components(0, 1, layers, layer_buckets, nc, r2cut, d2, v_cut, dim, BOUNDED, start, run_end,
                           id_sorted, pos_sorted, parent, size, energy, nearest)
        count_roots(n, parent, size, result)


@ti.func
def _move_all(n, dt, dim: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(),
              vel_sorted: ti.template(), accel: ti.template(), pos: ti.template(), vel: ti.template(),
              ids: ti.template(), draw: ti.template(), bits: ti.template(), word_rank: ti.template(),
              drawn: ti.template()):
    """The move of :func:`_step_lanes` from the accelerations :func:`_step_sums_lanes` left (slot order), with
    the drawn agents' frame rows where `draw`."""
    for s in range(n):
        v = load_vec(vel_sorted, s, dim)
        p = load_vec(pos_sorted, s, dim)
        v += dt * load_vec(accel, s, dim)
        p += dt * v
        for a in ti.static(range(dim)):
            vel[a, s] = v[a]
            pos[a, s] = p[a]
        ids[s] = id_sorted[s]
        if ti.static(draw):
            r = drawn_rank(id_sorted[s], bits, word_rank)
            if r >= 0:
                for a in ti.static(range(dim)):
                    drawn[0, r, a] = p[a]
                    drawn[1, r, a] = v[a]


@ti.kernel
def _move(n: ti.i32, dt: float, dim: ti.template(), id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
          vel_sorted: ti.types.ndarray(), accel: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(),
          ids: ti.types.ndarray(), draw: ti.template(), bits: ti.types.ndarray(), word_rank: ti.types.ndarray(),
          drawn: ti.types.ndarray()):
    _move_all(n, dt, dim, id_sorted, pos_sorted, vel_sorted, accel, pos, vel, ids, draw, bits, word_rank, drawn)


@ti.kernel
def _lane_steps(steps: ti.i32, ready: ti.i32, side0: ti.i32, max_side: ti.i32, draw: ti.i32, n: ti.i32, box: float,
                cell_size: float, r2cut: float, d2: float, dt: float, dim: ti.template(), coords: ti.types.ndarray(),
                bucket: ti.types.ndarray(), counts: ti.types.ndarray(), start: ti.types.ndarray(),
                order: ti.types.ndarray(), slot_of: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
                coords_sorted: ti.types.ndarray(), id_sorted: ti.types.ndarray(), mixed: ti.types.ndarray(),
                block_start: ti.types.ndarray(), bounds: ti.types.ndarray(), anchor: ti.types.ndarray(),
                by_rank: ti.template(), run_end: ti.types.ndarray(), vel_sorted: ti.types.ndarray(),
                accel: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(), ids: ti.types.ndarray(),
                bits: ti.types.ndarray(), word_rank: ti.types.ndarray(), drawn: ti.types.ndarray(),
                done: ti.types.ndarray()):
    """Up to `steps` lane-wise steps of the switching topology in one launch, on one thread (a small swarm: a
    launch costs more than its arithmetic): each the bounded grid's layout and build
    (:func:`tflock.neighbors.bounded_layout`, :func:`tflock.neighbors.build_grid`, :func:`tflock.neighbors.cut_runs`),
    :func:`_gather_velocities` and :func:`_lanes_step`, the bodies of the step's own launches, so every step
    computes what they compute, bit for bit. It stops before a step whose swarm spreads beyond a bounded layout (the
    host's step then hashes the cells). For the first step, `ready` says what is done already: 1 the grid is built
    (bounded, `side0` cells a side), 2 the accelerations are summed too (by the metrics pass: the step is
    :func:`_move_all`). After the steps it builds the grid of the state they made. ``done``: the steps made, the
    builds, and the final grid's cells a side (0: not built). With `draw` and every step made, the drawn agents'
    frame rows of the final state."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        made = 0
        builds = 0
        side = side0
        built = ready  # 0 nothing, 1 the grid of the current state, 2 and its accelerations
        if ready == 1:  # a grid the host built: its runs may not be cut yet
            cut_runs(side ** (dim - 1), side, start, run_end)
        stop = 0
        while stop == 0:
            if built == 0:
                side = bounded_layout(n, dim, box, cell_size, max_side, BOUNDED, pos, bounds, anchor)
                if side > 0:
                    cells = side**dim
                    build_grid(pos, ids, n, n, box, cell_size, side, cells, cells, BOUNDED, dim, coords, bucket,
                               counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed,
                               block_start, bounds, anchor, by_rank)
                    cut_runs(cells // side, side, start, run_end)
                    builds += 1
                    built = 1
            if built == 0 or made == steps:
                stop = 1
            else:
                if built == 2:
                    _move_all(n, dt, dim, id_sorted, pos_sorted, vel_sorted, accel, pos, vel, ids, False, bits,
                              word_rank, drawn)
                else:
                    _gather_velocities(n, dim, order, vel, vel_sorted)
                    _lanes_step(side**dim, side, r2cut, d2, dt, dim, BOUNDED, start, run_end, id_sorted, pos_sorted,
                                vel_sorted, pos, vel, ids, False, bits, word_rank, drawn)
                made += 1
                built = 0
        done[0] = made
        done[1] = builds
        done[2] = ti.select(built == 1, side, 0)
        if draw != 0 and made == steps:
            for s in range(n):
                r = drawn_rank(ids[s], bits, word_rank)
                if r >= 0:
                    for a in ti.static(range(dim)):
                        drawn[0, r, a] = pos[a, s]
                        drawn[1, r, a] = vel[a, s]


@ti.kernel
def _csr_energy(n: ti.i32, d2: float, dim: ti.template(), offsets: ti.types.ndarray(),
                neighbours: ti.types.ndarray(), pos: ti.types.ndarray(), energy: ti.types.ndarray(),
                serial: ti.template()):
    """Half of each agent's potential V_i = sum_{j in N_i} V(|r_ij|) (eq. 4), agent order; `serial` as in
    :func:`_step_sums_lanes`."""
    ti.loop_config(serialize=serial)
    for i in range(n):
        p = load_vec(pos, i, dim)
        pot = 0.0
        for k in range(offsets[i], offsets[i + 1]):
            r2 = (load_vec(pos, neighbours[k], dim) - p).norm_sqr()
            pot += d2 / r2 + ti.log(r2)
        energy[i] = 0.5 * pot


@ti.kernel
def _exact_nearest(n: ti.i32, dim: ti.template(), pos: ti.types.ndarray(), nearest: ti.types.ndarray(),
                   serial: ti.template()):
    """Distance from each element's agent to its nearest other agent, all pairs (small n); `serial` as in
    :func:`_step_sums_lanes`."""
    ti.loop_config(serialize=serial)
    for e in range(n):
        p = load_vec(pos, e, dim)
        near = math.inf
        for k in range(n):
            if k != e:
                near = ti.min(near, (load_vec(pos, k, dim) - p).norm_sqr())
        nearest[e] = ti.sqrt(near)


@ti.kernel
def _gather(m: ti.i32, n: ti.i32, dim: ti.template(), agents: ti.types.ndarray(), ids: ti.types.ndarray(),
            where: ti.types.ndarray(), pos: ti.types.ndarray(), vel: ti.types.ndarray(), out: ti.types.ndarray()):
    """Rows (x, v) of agents[:m], whatever the arrangement of the state arrays."""
    for e in range(n):
        where[ids[e]] = e
    for r in range(m):
        e = where[agents[r]]
        for a in ti.static(range(dim)):
            out[r, a] = pos[a, e]
            out[r, dim + a] = vel[a, e]


@ti.kernel
def _drawn_gather(m: ti.i32, dim: ti.template(), slot: ti.types.ndarray(), order: ti.types.ndarray(),
                  pos_sorted: ti.types.ndarray(), vel: ti.types.ndarray(), out: ti.types.ndarray()):
    """Rows of the drawn agents from their grid slots (:meth:`SubsetDrawing.locate`): ``out[0]`` positions,
    ``out[1]`` velocities, as the lane-wise step writes them for a frame ``draw_next`` announced."""
    for r in range(m):
        s = slot[r]
        e = order[s]
        for a in ti.static(range(dim)):
            out[0, r, a] = pos_sorted[a, s]
            out[1, r, a] = vel[a, e]


def velocity_stats(vel: np.ndarray) -> dict[str, float]:
    """:meth:`Potential._velocity_stats` of velocities (dim, n) in float64, as the kernels compute them: the
    mismatch |v_i - mean v| (mean and max), the mean speed, the speed spread max - min |v_i|, the polarization
    |mean of v_i / |v_i|| (agents at rest left out of the sum, not of the mean) and the kinetic energy."""
    v = np.asarray(vel, dtype=np.float64)
    n = v.shape[1]
    squares = (v * v).sum(axis=0)
    speed = np.sqrt(squares)
    moving = speed > 0
    heading = (v[:, moving] / speed[moving]).sum(axis=1) / n
    gap = np.sqrt(((v - v.mean(axis=1, keepdims=True)) ** 2).sum(axis=0))
    return {
        "velocity_mismatch_mean": float(gap.mean()),
        "velocity_mismatch_max": float(gap.max()),
        "speed_mean": float(speed.mean()),
        "speed_spread": float(speed.max() - speed.min()),
        "polarization": float(np.sqrt((heading * heading).sum())),
        "kinetic_energy": 0.5 * float(squares.sum()),
    }


class _NextStep:
    """The accelerations u_i (eq. 3) of the next step, slot order, that the lane-wise metrics pass computed, and
    ``summed``, the (step, grid build) they are for (None: none). Derived data, which checkpoints leave out."""

    def __init__(self, accel: ti.Ndarray) -> None:
        self.accel = accel
        self.summed: tuple[int, int] | None = None


class Potential(GridModel):
    """Potential-field flocking of double integrators, fixed or switching topology, 2D or 3D (see the module)."""

    name = "potential"

    def __init__(self, params: PotentialParams, seed: int, engine: EngineInfo) -> None:
        super().__init__(params, seed, engine)
        n, dim, real = params.n, params.dim, engine.real
        self.dt = params.dt
        self.dim = dim
        self.switching = params.topology == "switching"
        if not self.switching:  # the frames draw the fixed graph's edges, whatever their length (_fixed_edges)
            self.edges_description = "edges of the fixed interaction graph among the drawn agents"
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = ti.ndarray(ftype, (dim, n))  # component-major, as every kernel array
        self.vel = ti.ndarray(ftype, (dim, n))
        self.ids = ti.ndarray(ti.i32, n)
        self.scratch = ti.ndarray(ftype, (dim, n))  # velocities in cell order, or the fixed step's new velocities
        self.pos_next = ti.ndarray(ftype, (dim, n) if not self.switching else (dim, 1))
        self._where = ti.ndarray(ti.i32, n)
        self.valency = ti.ndarray(ti.i32, n)
        self.energy = ti.ndarray(ftype, n)
        self.nearest = ti.ndarray(ftype, n)
        # the bounded layout runs on the CPU only: GPU arches keep the hash, checked there on an H100
        self.grid = CellGrid(n, dim, "open", params.box, params.radius, real, bounded=engine.arch == "cpu")
        self.lane_wise = engine.arch == "cpu" and self.switching  # see _step_lanes
        self.graph = NeighbourGraph(self.grid, strict=True)  # N_i: |r_ij| < R
        # the lane-wise metrics pass: the components it finds, and the next step's accelerations it computes
        self.components = LaneComponents(self.grid, engine.threads) if self.lane_wise else None
        self._next_step = _NextStep(ti.ndarray(ftype, (dim, n if self.lane_wise else 1)))
        self._grid_step = -1
        # what a launch of _lane_steps made: steps, builds, grid side (host memory, which the CPU kernel writes;
        # not an ndarray: checkpoints keep the model's ndarrays, and this is no state)
        self._fused_done = np.zeros(3, dtype=np.int32)
        if not self.switching:
            self.edges = fixed_graph_edges(n, params.graph, seed, params.graph_p, params.graph_file)
            offsets, neighbours = to_csr(n, self.edges)
            self.offsets_np, self.neighbours_np = offsets, neighbours
            self.offsets = ti.ndarray(ti.i32, n + 1)
            self.neighbours = ti.ndarray(ti.i32, max(1, len(neighbours)))
            self.offsets.from_numpy(offsets)
            if len(neighbours):
                self.neighbours.from_numpy(neighbours)
            self.valency_np = np.diff(offsets).astype(np.int32)  # the fixed graph's, agent order
            self.valency.from_numpy(self.valency_np)
            m = n if n > EXACT_PAIRS_MAX else 1  # the grid finds the nearest agents of a large fixed-graph swarm
            self._grid_valency = ti.ndarray(ti.i32, m)
            self._grid_energy = ti.ndarray(ftype, m)
        self.metric_descriptions = self._describe()
        self.set_state(initial_state(n, dim, params.box, params.speed, params.min_separation, seed), 0)

    def _describe(self) -> dict[str, str]:
        p = self.params
        lyapunov = ("W", "Lyapunov function W = kinetic + potential energy (eq. 5)") if not self.switching else (
            "Q", "Lyapunov function Q (eq. 10) less its constant N (N - 1) / 2 V(R)")
        capped = "" if p.n <= EXACT_PAIRS_MAX else ", capped at R"
        out = {
            "velocity_mismatch_mean": "mean |v_i - mean v|",
            "velocity_mismatch_max": "max |v_i - mean v|",
            "speed_mean": "mean speed |v_i|",
            "speed_spread": "speed spread max |v_i| - min |v_i|",
            "polarization": "polarization |mean v_i / |v_i||",
            "kinetic_energy": "kinetic energy 1/2 sum |v_i|^2",
            "potential_energy": "potential energy: sum over edges V(|r_ij|)" if not self.switching
            else "potential energy: sum over pairs |r_ij| < R of V(|r_ij|) - V(R)",
            lyapunov[0]: lyapunov[1],
            "min_distance": "minimum pairwise distance" + capped,
            "valency_mean": "mean valency (neighbour count)",
            "valency_min": "min valency",
            "valency_max": "max valency",
            "components": "connected components of the interaction graph",
            "connected": "1 when the interaction graph is connected",
        }
        if p.n <= LAMBDA2_MAX:
            out["lambda2"] = f"algebraic connectivity lambda_2 of the graph Laplacian (every {p.lambda2_every} steps)"
        if p.n <= PER_AGENT_MAX:
            out.update({f"valency_{i}": f"valency of agent {i}" for i in range(p.n)})
            out.update({f"speed_{i}": f"speed of agent {i}" for i in range(p.n)})
        return out

    # ------------------------------------------------------------------------------------------------------
    # State.

    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state: ``x`` and ``v``, (n, dim) in agent order."""
        real = self.engine.real
        self.pos.from_numpy(np.ascontiguousarray(np.asarray(state["x"]).T, dtype=real))
        self.vel.from_numpy(np.ascontiguousarray(np.asarray(state["v"]).T, dtype=real))
        self.ids.from_numpy(np.arange(self.params.n, dtype=np.int32))
        self.step_index = step
        self.invalidate()
        self._lambda2_step = -1  # step of the last lambda_2 (plain numbers: checkpoints keep them)
        self._lambda2_value = 0.0

    def invalidate(self) -> None:
        super().invalidate()
        # the step whose pair arrays `valency`, `energy`, `nearest` hold, and whether they are in grid slot order (the
        # lane-wise pass's) rather than agent order (a tuple: checkpoints leave it out)
        self._pairs_step: tuple[int, ...] = (-1,)
        self._totals: tuple[float, ...] | None = None  # _pair_totals() of those energies
        self._components_found: tuple[int, int] | None = None  # (step, components) where the pairs' pass found them
        self._next_step.summed = None

    def state(self) -> dict[str, np.ndarray]:
        ids = self.ids.to_numpy()
        x = np.empty((self.params.n, self.dim), dtype=self.engine.real)
        v = np.empty_like(x)
        x[ids] = self.pos.to_numpy().T
        v[ids] = self.vel.to_numpy().T
        return {"x": x, "v": v}

    def advance(self, steps: int) -> None:
        """Run `steps` steps: with at most :data:`FUSED_MAX_N` agents all of them in one launch (a fixed graph:
        :func:`_steps_fixed`; switching, on the CPU: :func:`_lane_steps`, up to a step whose swarm no bounded grid
        holds), else one step (a few launches) at a time."""
        p = self.params
        if not self.switching and steps > 1 and p.n <= FUSED_MAX_N:
            _steps_fixed(steps, p.n, p.desired_distance**2, p.dt, self.dim, self.offsets, self.neighbours, self.pos,
                         self.vel, self.pos_next, self.scratch)
            if steps % 2:
                self.pos, self.pos_next = self.pos_next, self.pos
                self.vel, self.scratch = self.scratch, self.vel
            self.step_index += steps
            return
        if self.lane_wise and steps > 0 and p.n <= FUSED_MAX_N:
            steps -= self._lane_steps(steps)
        for _ in range(steps):
            self._one_step()

    def _one_step(self) -> None:
        p, grid = self.params, self.grid
        d2 = p.desired_distance**2
        if self.switching:
            self._ensure_grid()
            g = grid.geometry  # this build's layout: bounded or hashed
            if self._next_step.summed == (self.step_index, grid.builds):  # summed by the metrics pass
                _move(p.n, p.dt, self.dim, grid.id_sorted, grid.pos_sorted, self.scratch, self._next_step.accel,
                      self.pos, self.vel, self.ids, *self._draw_arguments(2, self.dim))
                self.step_index += 1
                return
            _sort_velocities(p.n, self.dim, grid.order, self.vel, self.scratch)
            if self.lane_wise and g.boundary == BOUNDED:
                _step_lanes(g.total_buckets, g.cells_per_side, p.radius**2, d2, p.dt, self.dim, g.boundary,
                            grid.start, grid.runs(), grid.id_sorted, grid.pos_sorted, self.scratch, self.pos,
                            self.vel, self.ids, *self._draw_arguments(2, self.dim))
            else:
                _step_switching(p.n, p.radius**2, d2, p.dt, self.dim, g.boundary, g.cells_per_side,
                                g.n_buckets, grid.start, grid.mixed, grid.id_sorted, grid.pos_sorted,
                                grid.coords_sorted, self.scratch, self.pos, self.vel, self.ids)
        else:
            _step_fixed(p.n, d2, p.dt, self.dim, self.offsets, self.neighbours, self.pos, self.vel,
                        self.pos_next, self.scratch)
            self.pos, self.pos_next = self.pos_next, self.pos
            self.vel, self.scratch = self.scratch, self.vel
        self.step_index += 1

    def _ensure_grid(self) -> None:
        """The grid of the current state: a small swarm's (lane-wise, on the CPU) from :func:`_lane_steps` with no
        step, the launch that builds it between steps, where a bounded grid holds the swarm; else the host's build.
        Both give the same grid; the launch's kernel is the one the steps load anyway, and the host's build takes
        three kernels of its own."""
        if self._grid_step != self.step_index and self.lane_wise and self.params.n <= FUSED_MAX_N:
            self._lane_steps(0)
        super()._ensure_grid()

    def _lane_steps(self, steps: int) -> int:
        """Up to `steps` lane-wise steps in one launch of :func:`_lane_steps`, from the grid and the accelerations
        ready for the current state (built by a frame, summed by the metrics pass), and the grid of the state they
        make; the number made (fewer where the swarm spread beyond a bounded grid). With steps = 0, only that
        grid's build (where not built yet)."""
        p, grid = self.params, self.grid
        t0, ready = self.step_index, 0
        if self._grid_step == t0 and grid.geometry.boundary == BOUNDED:
            ready = 2 if self._next_step.summed == (t0, grid.builds) else 1
        if steps:
            draw, bits, word_rank, drawn = self._draw_arguments(2, self.dim, made=t0 + steps)
        else:  # rows a step wrote for this state stay
            draw, bits, word_rank, drawn = self._no_draw_arguments(2, self.dim)
        _lane_steps(steps, ready, grid.geometry.cells_per_side, grid.max_side, int(draw), p.n, p.box, grid.radius,
                    p.radius**2, p.desired_distance**2, p.dt, self.dim, grid.coords, grid.bucket, grid.counts,
                    grid.start, grid.order, grid.slot_of, grid.pos_sorted, grid.coords_sorted, grid.id_sorted,
                    grid.mixed, grid.block_start, grid.bounds, grid.anchor, grid.rank_sort, grid.run_buffer(),
                    self.scratch, self._next_step.accel, self.pos, self.vel, self.ids, bits, word_rank, drawn,
                    self._fused_done)
        made, builds, side = (int(x) for x in self._fused_done)
        grid.count_bounded_builds(builds, side)
        if made < steps:  # the frame rows were not written: the host's steps take over
            self._drawn = None
        self.step_index = t0 + made
        self._grid_step = self.step_index if side else -1
        return made

    # ------------------------------------------------------------------------------------------------------
    # Metrics.

    def adjacency(self) -> np.ndarray:
        """Boolean adjacency matrix of the current interaction graph (small n)."""
        n = self.params.n
        if not self.switching:
            a = np.zeros((n, n), dtype=bool)
            a[self.edges[:, 0], self.edges[:, 1]] = True
            return a | a.T
        x = self.state()["x"].astype(np.float64)
        a = ((x[:, None, :] - x[None, :, :]) ** 2).sum(axis=2) < self.params.radius**2
        np.fill_diagonal(a, False)
        return a

    def _lambda2_now(self, components: float) -> float:
        """lambda_2 of the graph Laplacian, recomputed every ``lambda2_every`` steps: 0 exactly for a graph of more
        than one component (the multiplicity of the eigenvalue 0 is the number of components, which the metrics
        count exactly), else from NumPy's eigvalsh, O(N^3)."""
        step, every = self.step_index, self.params.lambda2_every
        last = self._lambda2_step
        stale = last < 0 or (self.switching and (step % every == 0 or step < last))
        if stale:  # a fixed graph's lambda_2 never changes
            self._lambda2_value = 0.0
            if components == 1.0 and self.params.n > 1:
                a = self.adjacency().astype(np.float64)
                self._lambda2_value = float(np.linalg.eigvalsh(np.diag(a.sum(axis=1)) - a)[1])
            self._lambda2_step = step
        return self._lambda2_value

    def _grid_pairs(self, valency: ti.Ndarray, energy: ti.Ndarray) -> None:
        """Valency, half the saturated potential and the nearest distance of each agent, from the grid."""
        p, g, grid = self.params, self.grid.geometry, self.grid
        d2 = p.desired_distance**2
        _grid_pairs(p.n, p.radius**2, d2, self._v_cut(), self.dim, g.boundary, g.cells_per_side, g.n_buckets,
                    grid.start, grid.mixed, grid.id_sorted, grid.pos_sorted, grid.coords_sorted, valency, energy,
                    self.nearest)

    def _pair_energies(self) -> None:
        """Each agent's share of the pair potentials in ``energy`` (half of each of its pairs; on the lane-wise pass
        its pairs with agents at smaller grid slots: the same total) and, switching, ``valency`` and ``nearest``, once
        per step: the stability guard and the metrics share them. The lane-wise pass writes them at each agent's
        grid slot (contiguous stores, not scattered by agent id); their totals do not depend on the order, and
        :meth:`_agent_valency` puts the valencies in agent order."""
        if self._pairs_step[0] == self.step_index:
            return
        in_slots = False
        if self.switching:
            self._ensure_grid()
            g = self.grid.geometry
            in_slots = self.lane_wise and g.boundary == BOUNDED
            if in_slots:  # with the next step's sums and the components
                self._lane_pairs()
            else:
                self._grid_pairs(self.valency, self.energy)
        else:
            p = self.params
            _csr_energy(p.n, p.desired_distance**2, self.dim, self.offsets, self.neighbours, self.pos, self.energy,
                        one_thread(self.neighbours.shape[0]))  # its work: the graph's edges
        self._pairs_step = (self.step_index, in_slots)
        self._totals = None

    def _agent_valency(self) -> np.ndarray:
        """Each agent's valency |N_i|, agent order, from the pair arrays of this step (:meth:`_pair_energies`)."""
        n = self.params.n
        if not self.switching:
            return self.valency_np
        valency = host_array(self.valency)[:n]
        if not self._pairs_step[1]:
            return valency
        by_agent = np.empty_like(valency)
        by_agent[host_array(self.grid.id_sorted)[:n]] = valency
        return by_agent

    def _lane_pairs(self) -> None:
        """The lane-wise metrics pass (:func:`_step_sums_lanes`): the next step's accelerations, each agent's
        valency, energy and nearest distance (at its grid slot), and the components, counted here."""
        p, grid, found = self.params, self.grid, self.components
        g = grid.geometry
        d2, r2cut = p.desired_distance**2, p.radius**2
        if p.n <= FUSED_MAX_N:  # the velocities in cell order and the components (one stripe, counted): one launch
            layer_buckets = g.cells_per_side ** (self.dim - 1)
            _small_components(p.n, g.total_buckets // layer_buckets, layer_buckets, g.cells_per_side, r2cut, d2,
                              self._v_cut(), self.dim, grid.order, self.vel, self.scratch, grid.start, grid.runs(),
                              grid.id_sorted, grid.pos_sorted, found.parent, found.size, self.energy, self.nearest,
                              found.result)
            self._sum_pairs(r2cut, d2)
            self._components_found = (self.step_index, int(found.result[0]))
            return
        _sort_velocities(p.n, self.dim, grid.order, self.vel, self.scratch)
        self._sum_pairs(r2cut, d2)
        self._components_found = (self.step_index, self._components_pass()[0])

    def _v_cut(self) -> float:
        """V(R) = d^2 / R^2 + log R^2, the pair potential at the cutoff R, which the pair sums subtract (Q of eq. 10
        less its constant)."""
        p = self.params
        return p.desired_distance**2 / p.radius**2 + math.log(p.radius**2)

    def _components_pass(self) -> tuple[int, int]:
        """:func:`_components_lanes` on the grid (each agent's energy and nearest distance at its grid slot, the
        components of |r_ij| < R), and the components counted: (components, agents in the largest)."""
        p, grid, found = self.params, self.grid, self.components
        g = grid.geometry
        d2, r2cut = p.desired_distance**2, p.radius**2
        _components_lanes(*found.stripes(), g.cells_per_side, r2cut, d2, self._v_cut(), self.dim,
                          g.boundary, grid.start, grid.runs(), grid.id_sorted, grid.pos_sorted, found.parent,
                          found.size, self.energy, self.nearest)
        return found.finish(r2cut, p.box, OPEN, strict=True)

    def _sum_pairs(self, r2cut: float, d2: float) -> None:
        """:func:`_step_sums_lanes` on the grid, the velocities in cell order in ``scratch``."""
        grid = self.grid
        g = grid.geometry
        _step_sums_lanes(g.total_buckets, g.cells_per_side, r2cut, d2, self.dim, g.boundary, grid.start, grid.runs(),
                         grid.id_sorted, grid.pos_sorted, self.scratch, self._next_step.accel, self.valency,
                         one_thread(grid.n))
        self._next_step.summed = (self.step_index, grid.builds)

    def lyapunov(self) -> Lyapunov:
        """W (eq. 5) on a fixed graph, Q (eq. 10) less its constant N (N - 1) / 2 V(R) when switching: kinetic
        energy 1/2 sum |v_i|^2 and the pair potentials. Both must not increase (eqs. 8 and 12) but by the
        integration error."""
        self._pair_energies()
        v = host_view(self.vel)  # the sum in the run's precision, no temporary: close enough for a 100 % slack
        squares = float(np.einsum("ij,ij->", v, v)) if v is not None else self.kernel_velocity_stats()[2]
        potential = self._pair_totals()[3] if self.switching else total(self.energy, self.params.n)
        return Lyapunov("Q" if self.switching else "W", 0.5 * squares, potential)

    def _pair_totals(self) -> tuple[float, ...]:
        """What the metrics and the guard read of a switching run's per-agent pair arrays, once per step's arrays:
        the valencies' sum, smallest and largest, the potential energy (the energies' total) and the smallest nearest
        distance. NumPy's on a small swarm's host memory (a launch costs more); above, one pass of
        :func:`_pair_blocks` (NumPy's reductions took a pass each, on one core)."""
        n = self.params.n
        valency = small_host_view(self.valency, n)
        if valency is not None:
            valency, nearest = valency[:n], host_view(self.nearest)[:n]
            return (float(valency.sum()), float(valency.min()), float(valency.max()), total(self.energy, n),
                    float(nearest.min()))
        if self._totals is None:
            partial = scratch((n_blocks(n), 5), ti.f64)
            _pair_blocks(n, self.valency, self.energy, self.nearest, partial)
            blocks = partial.to_numpy()
            self._totals = (float(blocks[:, 0].sum()), float(blocks[:, 1].min()), float(blocks[:, 2].max()),
                            float(blocks[:, 3].sum()), float(blocks[:, 4].min()))
        return self._totals

    def step_spread(self) -> tuple[float, float]:
        """dt max_a (max_i v_ia - min_i v_ia), at most the largest relative displacement of two agents in a step,
        and the desired distance d, the length over which the potential changes (Definition 2)."""
        v = host_view(self.vel)
        big, small = (v.max(axis=1), v.min(axis=1)) if v is not None else self.kernel_velocity_stats()[:2]
        return self.params.dt * float((big - small).max()), self.params.desired_distance

    def kernel_velocity_stats(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Each velocity component's max and min over the agents, and sum_i |v_i|^2, from a kernel's block
        partials: the stability guard's numbers on GPU arches (the CPU reads the ndarray's memory in NumPy)."""
        n, dim = self.params.n, self.dim
        partial = scratch((n_blocks(n), 2 * dim + 1), self.vel.dtype)
        _velocity_blocks(n, dim, self.vel, partial)
        partial = partial.to_numpy().astype(np.float64)
        return partial[:, :dim].max(axis=0), partial[:, dim:2 * dim].min(axis=0), float(partial[:, 2 * dim].sum())

    def _velocity_stats(self) -> dict[str, float]:
        """Velocity mismatch, speeds, polarization and kinetic energy over all agents, from two kernel launches
        (the mean velocity, then the mismatch against it) and their block partials: no copy of the velocities; a
        small swarm's in NumPy on the velocities' host memory (:func:`velocity_stats`)."""
        n, dim = self.params.n, self.dim
        v = small_host_view(self.vel, n)
        if v is not None:
            return velocity_stats(v)
        partial = scratch((n_blocks(n), _velocity_columns(dim)), ti.f64)
        centre = scratch((dim,), ti.f64)
        _velocity_stats(n, dim, self.vel, centre, False, partial)
        sums = partial.to_numpy()
        centre.from_numpy(sums[:, :dim].sum(axis=0) / n)
        _velocity_stats(n, dim, self.vel, centre, True, partial)
        blocks = partial.to_numpy()
        sums = blocks.sum(axis=0)
        heading = sums[dim + 2: 2 * dim + 2] / n
        return {
            "velocity_mismatch_mean": float(sums[2 * dim + 2] / n),
            "velocity_mismatch_max": float(blocks[:, 2 * dim + 5].max()),
            "speed_mean": float(sums[dim] / n),
            "speed_spread": float(blocks[:, 2 * dim + 3].max() - blocks[:, 2 * dim + 4].min()),
            "polarization": float(np.sqrt((heading * heading).sum())),
            "kinetic_energy": 0.5 * float(sums[dim + 1]),
        }

    def _nearest_exact(self) -> bool:
        """Whether ``nearest``'s smallest distance is the exact minimum over all pairs: switching, each agent's
        nearest distance capped at R comes from the grid, and a value under the cap is a pair within R, which the grid
        sees; so is the closest pair of all, then. Else (every agent alone) only all pairs tell."""
        if not self.switching:
            return False
        cap = np.sqrt(np.asarray(self.params.radius**2, dtype=self.engine.real))  # the kernels' sqrt(R^2)
        return bool(host_array(self.nearest).min() < cap)

    def metrics(self) -> dict[str, float]:
        p = self.params
        n = p.n
        self._pair_energies()
        components = 1.0  # a fixed graph: validated connected
        if not self.switching:
            if n > EXACT_PAIRS_MAX:  # the R-graph's valency and energy beside the fixed graph's; else no grid
                self._ensure_grid()
                self._grid_pairs(self._grid_valency, self._grid_energy)
        if n <= EXACT_PAIRS_MAX and not self._nearest_exact():
            _exact_nearest(n, self.dim, self.pos, self.nearest, one_thread(n, EXACT_NEAREST_ONE_THREAD))
            self._totals = None  # (nearest rewritten)
        if self.switching:
            valencies, fewest, most, potential, nearest = self._pair_totals()
            found = self._components_found
            if found is not None and found[0] == self.step_index:  # by _pair_energies' pass
                components = float(found[1])
            else:
                components = float(self.graph.components(p.radius, p.box, valencies / n)[0])
        else:
            valency = self.valency_np
            valencies, fewest, most = float(valency.sum()), float(valency.min()), float(valency.max())
            potential, nearest = total(self.energy, n), float(host_array(self.nearest).min())
        stats = self._velocity_stats()
        out = {
            **stats,
            "potential_energy": potential,
            "W": stats["kinetic_energy"] + potential,
            "Q": stats["kinetic_energy"] + potential,
            "min_distance": nearest if n > 1 else 0.0,
            "valency_mean": valencies / n,
            "valency_min": fewest,
            "valency_max": most,
            "components": components,
            "connected": float(components == 1.0),
        }
        if n <= LAMBDA2_MAX:
            out["lambda2"] = self._lambda2_now(components)
        if n <= PER_AGENT_MAX:
            ids = self.ids.to_numpy()
            agent_speed = np.empty(n)
            agent_speed[ids] = np.sqrt((self.vel.to_numpy().astype(np.float64) ** 2).sum(axis=0))
            valency = self._agent_valency()
            out.update({f"valency_{i}": float(valency[i]) for i in range(n)})
            out.update({f"speed_{i}": float(agent_speed[i]) for i in range(n)})
        return {name: out[name] for name in self.metric_descriptions}

    # ------------------------------------------------------------------------------------------------------
    # Drawing.

    def _rows(self, agents: np.ndarray) -> np.ndarray:
        """(m, 2 dim) rows x, v of the given agents."""
        m, n = len(agents), self.params.n
        x = small_host_view(self.pos, n)
        if x is not None:  # a small swarm's rows in NumPy on the arrays' host memory: no launch
            where = np.empty(n, dtype=np.int64)
            where[host_view(self.ids)[:n]] = np.arange(n)
            e = where[np.asarray(agents, dtype=np.int64)]
            return np.concatenate([x[:, e], host_view(self.vel)[:, e]]).T.astype(np.float64)
        out = np.zeros((m, 2 * self.dim), dtype=self.engine.real)  # NumPy arrays: no copy kernels on the CPU
        if m:
            _gather(m, n, self.dim, np.ascontiguousarray(agents, dtype=np.int32), self.ids, self._where,
                    self.pos, self.vel, out)
        return out.astype(np.float64)

    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """Agents coloured by speed, velocity arrows, and the interaction graph's edges among the drawn agents (the
        fixed graph, or the current switching one)."""
        p, dim = self.params, self.dim
        grid = None
        if self.switching:  # the drawing's grid, built for the edges, gives the rows too
            drawing = self.drawing(selected)
            grid = self.grid
            drawn = self._rows_written(drawing)  # by the lane-wise step, for a frame draw_next announced
            if drawn is None:
                drawn = np.zeros((2, len(selected), dim), dtype=self.engine.real)
                if len(selected):
                    drawing.locate()
                    _drawn_gather(len(selected), dim, drawing.slot, self.grid.order, self.grid.pos_sorted, self.vel,
                                  drawn)
            pos, vel = drawn[0], drawn[1]
            edges = self._edges_among(pos, max_edges, p.radius)
        else:
            rows = self._rows(selected)
            pos, vel = rows[:, :dim], rows[:, dim:]
            edges = self._fixed_edges(selected, pos, max_edges)
        with np.errstate(over="ignore", invalid="ignore"):  # an f64 run on its way to a fault exceeds float32 first
            return Frame(
                positions=np.asarray(pos, dtype=np.float32),
                directions=np.asarray(vel / p.speed, dtype=np.float32),
                arrow_length=arrow_length(p.box, len(selected), dim, spread=pos),  # open space
                colors=speed_colors(np.sqrt((vel * vel).sum(axis=1)), p.speed),
                edges=np.asarray(edges, dtype=np.float32),
                ids=selected,
                fields=self._field_images(field_size, self.pos, self.vel, VECTORS, grid),
            )

    @property
    def color_legend(self) -> ColorLegend:
        """The speed ramp's colours at five speeds from 0 to the initial speed bound (faster agents: its end)."""
        speed = self.params.speed
        stops = np.linspace(0.0, speed, 5)
        colors = speed_colors(stops, speed)
        labels = [f"|v| = {v:.3g}" for v in stops[:-1]] + [f"|v| >= {speed:.3g}"]
        return ColorLegend("agents: speed |v|", entries=tuple(
            (label, (int(c[0]), int(c[1]), int(c[2]))) for label, c in zip(labels, colors, strict=True)))

    def _fixed_edges(self, selected: np.ndarray, pos: np.ndarray, max_edges: int) -> np.ndarray:
        """Edges of the fixed graph among the drawn agents: the graph induced on the first K of them (in id order),
        K as large as max_edges allows, as the switching topology's :class:`~tflock.neighbors.DrawnEdges`."""
        rank = np.full(self.params.n, -1, dtype=np.int64)
        rank[selected] = np.arange(len(selected))
        ra, rb = rank[self.edges[:, 0]], rank[self.edges[:, 1]]
        keep = (ra >= 0) & (rb >= 0)
        ra, rb = ra[keep], rb[keep]
        later = np.maximum(ra, rb)  # an edge belongs to its later row, as DrawnEdges counts them
        order = np.lexsort((np.minimum(ra, rb), later))
        ra, rb, later = ra[order], rb[order], later[order]
        per_row = np.bincount(later, minlength=len(selected)).cumsum() if len(later) else np.zeros(0, np.int64)
        rows = int(np.searchsorted(per_row, max_edges, side="right"))
        count = int(per_row[rows - 1]) if rows else 0
        ra, rb = ra[:count], rb[:count]
        return np.stack([pos[np.maximum(ra, rb)], pos[np.minimum(ra, rb)]], axis=1).reshape(-1, 2, self.dim)

    def world(self) -> WorldSpec:
        return WorldSpec(dim=self.dim, boundary="open", box=self.params.box, dt=self.dt)
