"""Vicsek family of heading-alignment models (DESIGN.md section 3.1).

One synchronous step t -> t+1 for every agent i:

1. neighbours N_i(t) = {j != i : |x_j - x_i| <= R} from the positions x(t) (minimum image when periodic), or
   with ``neighbours = "topological"`` the k agents nearest to i (Ballerini et al. 2008; ties by the smaller id,
   :mod:`tflock.topological`);
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
4. noise xi ~ U[-eta/2, eta/2] (Vicsek 1995), then headings are wrapped into [0, 2 pi) (003's convention; with
   ``wrap_headings`` false they stay real numbers, after a wall reflection too: the other reading of 003, which
   changes only the rules that use angle values themselves, ``average`` and ``laplacian``); with
   ``noise_type = "vectorial"`` (Gregoire & Chate 2004; Chate et al. 2008, the vector rule only) there is no xi:
   instead a unit vector at angle 2 pi u, weighted by eta (1 + n_i), joins the sum of step 2 before its angle is
   taken, so the noise acts on what the agent perceives rather than on its decision;
5. move x(t+1) = x(t) + v0 (cos, sin) theta_i(t+1) and apply the boundary (reflecting: mirror the position
   and reflect the heading, 003 section 5.2).

Leader (Jadbabaie section 3, eq. 22): agent 0 keeps its heading theta0 and is never updated by the rule or
the noise (only a reflecting wall turns it); followers count it as a neighbour when within R.
Noise for agent i at step t comes from ``u = uniform(seed, t, i, Stream.NOISE)`` (both noise types); initial
positions are uniform in the box and headings uniform in [0, 2 pi), from streams INIT_X, INIT_Y, INIT_HEADING at
step 0. ``dim = 3`` builds :class:`tflock.models.vicsek3d.Vicsek3D` instead.
"""


import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.config import VicsekParams
from tflock.cpu_tasks import TASK_STRIDE, one_thread, task_at
from tflock.engine import EngineInfo
from tflock.fastmath import atan2, cos_sin, opaque_copy, sin_cos
from tflock.field import ANGLES, UNIT_VECTORS
from tflock.frame import HEADING_LEGEND, LEADER_COLOR, ColorLegend, Frame, WorldSpec, angle_colors, arrow_length
from tflock.lane_graph import (
    NO_LABEL,
    LaneComponents,
    block_roots_vectorised,
    candidate_label,
    fold_label,
    join_candidate,
    lowest_lane,
    settle_block,
    span_labels,
    stripe_range,
)
from tflock.metrics import (
    EXACT_PAIRS_MAX,
    SAMPLED_PAIRS,
    NeighbourGraph,
    heading_order,
    orders_and_pairs,
    pairwise_errors,
    replica_pairwise_errors,
)
from tflock.models.base import GridModel
from tflock.neighbors import (
    LANES,
    CellGrid,
    build_grid,
    cut_runs,
    drawn_rank,
    lanes,
    load_cell,
    load_vec,
    run_at,
    run_spans,
    run_wraps,
    same_cell,
    span_agents,
    span_count,
    stencil_span,
)
from tflock.observables import TransitionObservables
from tflock.reductions import BLOCK as SUM_BLOCK
from tflock.reductions import mean, n_blocks, scratch, total
from tflock.reference import wrap_pi as wrap_pi_np
from tflock.rng import Stream, bernoulli_ti, hash_ti, pair_hash_ti, randint_ti, replica_key, uniform_np, uniform_ti
from tflock.space import (
    OPEN,
    PERIODIC,
    REFLECTING,
    boundary_code,
    displacement,
    reflect,
    wrap_periodic,
    wrap_pi,
    wrap_two_pi,
)
from tflock.taichi_host import host_array, host_view, small_host_view
from tflock.topological import cell_side, find_nearest, lane_wise

#: agents :func:`_update` takes at a time: fixed, not LANES, because LLVM fuses multiply-adds in the update's
#: arithmetic differently at each vector width (8 and 16 gave headings 1 ulp apart on an AVX2 host), and the
#: trajectory must not depend on TFLOCK_LANES
UPDATE_WIDTH = 8
RULES = {"vector": 0, "average": 1, "relative": 2, "laplacian": 3}
VECTOR, AVERAGE, RELATIVE, LAPLACIAN = 0, 1, 2, 3
#: what :func:`_neighbour_sums` computes for the vector rule with vectorial noise: the vector sums and the count
VECTOR_COUNTED = 4
#: the lane-wise step runs all the steps between two observations in one launch (:func:`_lane_wise_steps`, on one
#: thread) up to this many agents (replicas together), where launches cost more than the arithmetic
FUSED_MAX_AGENTS = 4096
#: the asynchronous step runs all the steps between two observations in one launch (:func:`_serial_steps`, on one
#: thread) up to this many agents
SERIAL_MAX_AGENTS = 1024
TWO_PI = 2 * math.pi
#: a drawn agent that did not update at this step (asynchrony) takes this share of its colour, the rest of
#: ASYNC_GREY: paler and darker than an updated agent, but with asynchrony most agents are such, and every hue of them
#: stays visible on the viewer's dark background (darkened alone, a blue one was (0, 0, 76): nearly black)
ASYNC_DIM = 0.45
ASYNC_GREY = 110


def dimmed(colors: np.ndarray) -> np.ndarray:
    """The colours (M, 3) uint8 of agents that did not update at this step (:data:`ASYNC_DIM`)."""
    return np.rint(ASYNC_DIM * np.asarray(colors, np.float32) + (1 - ASYNC_DIM) * ASYNC_GREY).astype(np.uint8)


def initial_state(params: VicsekParams, seed: int) -> dict[str, np.ndarray]:
    """Positions uniform in [0, box)^2 and headings uniform in [0, 2 pi) (float64; leader heading theta0)."""
    ids = np.arange(params.n)
    x = np.stack([params.box * uniform_np(seed, 0, ids, Stream.INIT_X),
                  params.box * uniform_np(seed, 0, ids, Stream.INIT_Y)], axis=1)
    theta = TWO_PI * uniform_np(seed, 0, ids, Stream.INIT_HEADING)
    if params.leader.enabled:
        theta[0] = math.radians(params.leader.heading_deg) % TWO_PI
    return {"x": x, "theta": theta}


@ti.kernel
def _step(t: ti.i32, seed: ti.u32, n: ti.i32, per_replica: ti.i32, radius: float, speed: float, noise: float,
          box: float, max_turn: float, inv_g: float, bound: ti.i32,
          rule: ti.template(), boundary: ti.template(), leader: ti.template(), asynchronous: ti.template(),
          vectorial: ti.template(), wrap: ti.template(), nc: ti.i32, n_buckets: ti.i32, start: ti.types.ndarray(),
          mixed: ti.types.ndarray(),
          order: ti.types.ndarray(), id_sorted: ti.types.ndarray(), pos_sorted: ti.types.ndarray(),
          coords_sorted: ti.types.ndarray(),
          payload: ti.types.ndarray(), pos: ti.types.ndarray(), theta: ti.types.ndarray(), ids: ti.types.ndarray(),
          turn: ti.types.ndarray(), updated: ti.types.ndarray(), omega: ti.types.ndarray(),
          hist_pos: ti.types.ndarray(), hist_theta: ti.types.ndarray()):
    _general_step(t, seed, n, per_replica, radius, speed, noise, box, max_turn, inv_g, bound, rule, boundary, leader,
                  asynchronous, vectorial, wrap, nc, n_buckets, start, mixed, order, id_sorted, pos_sorted,
                  coords_sorted, payload, pos, theta, ids, turn, updated, omega, hist_pos, hist_theta)


@ti.kernel
def _serial_steps(steps: ti.i32, t0: ti.i32, ready: ti.i32, draw: ti.i32,
                  n: ti.i32, per_replica: ti.i32, box: float, cell_size: float, nc: ti.i32, n_buckets: ti.i32,
                  total_buckets: ti.i32, layout: ti.template(), dim: ti.template(),
                  coords: ti.types.ndarray(), bucket: ti.types.ndarray(), counts: ti.types.ndarray(),
                  start: ti.types.ndarray(), order: ti.types.ndarray(), slot_of: ti.types.ndarray(),
                  pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                  id_sorted: ti.types.ndarray(), mixed: ti.types.ndarray(), block_start: ti.types.ndarray(),
                  bounds: ti.types.ndarray(), anchor: ti.types.ndarray(), by_rank: ti.template(),
                  seed: ti.u32, radius: float, speed: float, noise: float, max_turn: float, inv_g: float,
                  bound: ti.i32, rule: ti.template(), boundary: ti.template(), leader: ti.template(),
                  asynchronous: ti.template(), vectorial: ti.template(), wrap: ti.template(),
                  payload: ti.types.ndarray(), pos: ti.types.ndarray(), theta: ti.types.ndarray(),
                  ids: ti.types.ndarray(), turn: ti.types.ndarray(), updated: ti.types.ndarray(),
                  omega: ti.types.ndarray(), hist_pos: ti.types.ndarray(), hist_theta: ti.types.ndarray(),
                  bits: ti.types.ndarray(), word_rank: ti.types.ndarray(), drawn: ti.types.ndarray(),
                  slot: ti.types.ndarray()):
    """`steps` steps t0 .. t0 + steps - 1 of :func:`_step` in one launch, on one thread, each after the build of its
    grid (:func:`tflock.neighbors.build_grid`; none before the first with `ready`, the grid of the current positions
    being built already), then the build of the state they make (what the metrics pass and a frame read). With
    `draw`, the drawn agents' frame rows of that state, as :func:`_drawn_rows` writes them. The same launches' bodies
    in the same order: for the runs that take it (``Vicsek._serial``) every step computes what they compute, bit for
    bit."""
    ti.loop_config(serialize=True)
    for step in range(steps + 1):
        if step > 0 or ready == 0:
            build_grid(pos, ids, n, per_replica, box, cell_size, nc, n_buckets, total_buckets, layout, dim, coords,
                       bucket, counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed,
                       block_start, bounds, anchor, by_rank)
        if step < steps:
            _general_step(t0 + step, seed, n, per_replica, radius, speed, noise, box, max_turn, inv_g, bound, rule,
                          boundary, leader, asynchronous, vectorial, wrap, nc, n_buckets, start, mixed, order,
                          id_sorted, pos_sorted, coords_sorted, payload, pos, theta, ids, turn, updated, omega,
                          hist_pos, hist_theta)
        elif draw:
            _write_drawn_rows(n, id_sorted, order, bits, word_rank, pos_sorted, theta, updated, drawn, slot)


@ti.func
def _general_step(t, seed, n, per_replica, radius, speed, noise, box, max_turn, inv_g, bound, rule: ti.template(),
                  boundary: ti.template(), leader: ti.template(), asynchronous: ti.template(),
                  vectorial: ti.template(), wrap: ti.template(), nc, n_buckets, start: ti.template(),
                  mixed: ti.template(), order: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(),
                  coords_sorted: ti.template(), payload: ti.template(), pos: ti.template(), theta: ti.template(),
                  ids: ti.template(), turn: ti.template(), updated: ti.template(), omega: ti.template(),
                  hist_pos: ti.template(), hist_theta: ti.template()):
    """The step of any rule, boundary and update scheme on the cell grid of the current positions (the general
    kernel; see the class)."""
    for s in range(n):  # headings in cell order: contiguous reads in the neighbour loop
        th = theta[order[s]]
        sin_th, cos_th = sin_cos(th)
        payload[0, s] = cos_th
        payload[1, s] = sin_th
        payload[2, s] = th
    for s in range(n):  # new state written at slot s: the arrangement becomes this step's cell order
        r2 = radius * radius
        # an agent is never further than (B - 1) v0 from where it was B - 1 steps ago (slack for rounding)
        reach2 = ((radius + (bound - 1) * speed) * (1.0 + 1e-5)) ** 2
        ring = bound + 1  # the ring holds B + 1 states: slot (t + 1) is written while the B views t-B+1..t are read
        i = id_sorted[s]
        p = load_vec(pos_sorted, s, 2)
        c = load_cell(coords_sorted, s, 2)
        th_i = payload[2, s]
        key, local = replica_key(seed, i, per_replica)
        update = True
        if ti.static(asynchronous):  # 003 Table 1: update with probability 1 / (B - Omega_i + 1)
            update = bernoulli_ti(hash_ti(key, t, local, Stream.UPDATE), bound - omega[i] + 1)
        if ti.static(leader):
            if local == 0:
                update = False  # the leader keeps theta0 (Jadbabaie eq. 22)
        new = th_i
        if update:
            acc_a = 0.0
            acc_b = 0.0
            count = 0.0
            for o in range(ti.static(span_count(boundary, 2))):
                lo, hi, cell = stencil_span(c, o, nc, n_buckets, boundary, 2)
                begin, end, check = span_agents(lo, hi, cell, start, mixed, coords_sorted, boundary, 2)
                for k in range(begin, end):
                    if ti.static(not asynchronous):
                        d = displacement(p, load_vec(pos_sorted, k, 2), box, boundary)
                        w = ti.select(d.norm_sqr() <= r2, 1.0, 0.0) * ti.select(k != s, 1.0, 0.0)
                        if ti.static(boundary == OPEN):
                            if check:
                                w *= same_cell(coords_sorted, k, cell, boundary, 2)
                        if ti.static(rule == VECTOR):
                            acc_a += w * payload[0, k]
                            acc_b += w * payload[1, k]
                        elif ti.static(rule == RELATIVE):
                            acc_a += w * wrap_pi(payload[2, k] - th_i)
                        else:
                            acc_a += w * payload[2, k]
                        count += w
                    else:  # agent j as seen at tau ~ U{t-B+1, ..., t} (003 Assumption 1b)
                        d_now = displacement(p, load_vec(pos_sorted, k, 2), box, boundary)
                        if d_now.norm_sqr() <= reach2 and k != s and (
                                check == 0 or same_cell(coords_sorted, k, cell, boundary, 2) == 1):
                            j = id_sorted[k]
                            delay = randint_ti(pair_hash_ti(key, t, local, j - (i - local), Stream.DELAY), bound)
                            slot = (t - delay + ring) % ring
                            d = displacement(p, ti.Vector([hist_pos[slot, 0, j], hist_pos[slot, 1, j]]), box,
                                             boundary)
                            if d.norm_sqr() <= r2:
                                th_j = hist_theta[slot, j]
                                if ti.static(rule == VECTOR):
                                    sin_j, cos_j = sin_cos(th_j)
                                    acc_a += cos_j
                                    acc_b += sin_j
                                elif ti.static(rule == RELATIVE):
                                    acc_a += wrap_pi(th_j - th_i)
                                else:
                                    acc_a += th_j
                                count += 1.0
            u = uniform_ti(key, t, local, Stream.NOISE)
            xi = noise * (u - 0.5)
            if ti.static(vectorial):  # Gregoire-Chate: a unit vector of weight eta (1 + n_i) joins the sum
                sin_psi, cos_psi = sin_cos(TWO_PI * u)
                acc_a += noise * (1.0 + count) * cos_psi
                acc_b += noise * (1.0 + count) * sin_psi
                xi = 0.0
            phi = 0.0  # desired turn, 003 eqs. (8)-(10)
            if ti.static(rule == VECTOR):
                phi = wrap_pi(atan2(acc_b + payload[1, s], acc_a + payload[0, s]) - th_i)
            elif ti.static(rule == AVERAGE):
                phi = (th_i + acc_a) / (1.0 + count) - th_i
            elif ti.static(rule == RELATIVE):
                phi = acc_a / (1.0 + count)
            else:
                phi = inv_g * (acc_a - count * th_i)
            new = th_i + ti.math.clamp(phi, -max_turn, max_turn) + xi
            if ti.static(wrap):
                new = wrap_two_pi(new)
        sin_new, cos_new = sin_cos(new)
        q = p + speed * ti.Vector([cos_new, sin_new])
        if ti.static(boundary == PERIODIC):
            q = wrap_periodic(q, box)
        elif ti.static(boundary == REFLECTING):
            q, flips = reflect(q, box)
            if flips[0] == 1:
                new = math.pi - new
            if flips[1] == 1:
                new = -new
            if ti.static(wrap):
                new = wrap_two_pi(new)
        pos[0, s] = q[0]
        pos[1, s] = q[1]
        theta[s] = new
        ids[s] = i
        turn[s] = ti.abs(wrap_pi(new - th_i))
        updated[s] = ti.select(update, 1, 0)
        if ti.static(asynchronous):
            omega[i] = ti.select(update, 1, omega[i] + 1)
            nxt = (t + 1) % ring
            hist_pos[nxt, 0, i] = q[0]
            hist_pos[nxt, 1, i] = q[1]
            hist_theta[nxt, i] = new


# The synchronous step on the CPU (box boundaries): three lane-wise kernels that LLVM vectorises. Taichi's general
# kernel above visits each agent's stencil alone, with scalar calls to atan2/sin/cos, which keep LLVM from
# vectorising the update and dominate a step at a few neighbours an agent. Here
# LANES agents of a run of cells share one pass over the run's stencil, each candidate compared with all of them
# at once, and the per-agent update runs UPDATE_WIDTH agents at a time with polynomial trigonometry (tflock.fastmath).


@ti.func
def _sorted_headings(n, order: ti.template(), theta: ti.template(), trig: ti.template(), payload: ti.template()):
    """payload = (cos, sin, theta) of the agents in cell order (``trig`` holds cos and sin of ``theta``)."""
    for s in range(n):
        e = order[s]
        payload[0, s] = trig[0, e]
        payload[1, s] = trig[1, e]
        payload[2, s] = theta[e]


@ti.kernel
def _headings(n: ti.i32, order: ti.types.ndarray(), theta: ti.types.ndarray(), trig: ti.types.ndarray(),
              payload: ti.types.ndarray()):
    """:func:`_sorted_headings` as a launch of its own."""
    _sorted_headings(n, order, theta, trig, payload)


@ti.func
def _accumulate(begin, end, px, py, th, acc_a, acc_b, count, r2, box, pos_sorted: ti.template(),
                payload: ti.template(), rule: ti.template(), minimum_image: ti.template()):
    """Add the candidates [begin, end) within R of each lane's agent (itself included) to its sums."""
    metric = ti.static(PERIODIC if minimum_image else REFLECTING)  # REFLECTING: the plain difference
    for k in range(begin, end):
        xk = pos_sorted[0, k]
        if xk > 2 * box:  # never (positions lie in the box); an exit LLVM's loop vectoriser cannot handle keeps it
            break  # off this loop: it vectorised across k as well for spans over 32 (64 vectors of lane sums)
        dx = displacement(px, xk, box, metric)
        dy = displacement(py, pos_sorted[1, k], box, metric)
        near = dx * dx + dy * dy <= r2
        if ti.static(rule == VECTOR or rule == VECTOR_COUNTED):
            acc_a += ti.select(near, payload[0, k], 0.0)
            acc_b += ti.select(near, payload[1, k], 0.0)
            if ti.static(rule == VECTOR_COUNTED):
                count += ti.select(near, 1.0, 0.0)
        else:
            if ti.static(rule == RELATIVE):
                acc_a += ti.select(near, wrap_pi(payload[2, k] - th), 0.0)
            else:
                acc_a += ti.select(near, payload[2, k], 0.0)
            count += ti.select(near, 1.0, 0.0)
    return acc_a, acc_b, count


@ti.func
def _lane_sums(total_buckets, nc, radius, box, rule: ti.template(), boundary: ti.template(), start: ti.template(),
               run_end: ti.template(), pos_sorted: ti.template(), payload: ti.template(), sums: ti.template()):
    """Per agent (cell order), over N_i and i itself: the rule's sums (``vector``: sum cos, sum sin; ``relative``:
    sum wrap(theta_j - theta_i); others: sum theta_j) and, except for ``vector``, the count 1 + n_i
    (``VECTOR_COUNTED``: the vector rule's sums and the count)."""
    for b in range(total_buckets):
        r2 = radius * radius
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        wraps = run_wraps(row, x0, x1, nc, boundary)
        for block in range((a1 - a0 + LANES - 1) // LANES):
            i0 = a0 + block * LANES
            px = lanes(pos_sorted, 0, i0, a1 - 1, LANES)
            py = lanes(pos_sorted, 1, i0, a1 - 1, LANES)
            th = lanes(payload, 2, i0, a1 - 1, LANES)
            acc_a = ti.Vector([0.0] * LANES)
            acc_b = ti.Vector([0.0] * LANES)
            count = ti.Vector([0.0] * LANES)
            for r in range(3):
                b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, boundary, 2)
                for h in range(2):
                    begin = ti.select(h == 0, b0, b1)
                    end = ti.select(h == 0, e0, e1)
                    if wraps:
                        acc_a, acc_b, count = _accumulate(begin, end, px, py, th, acc_a, acc_b, count, r2, box,
                                                          pos_sorted, payload, rule, True)
                    else:
                        acc_a, acc_b, count = _accumulate(begin, end, px, py, th, acc_a, acc_b, count, r2, box,
                                                          pos_sorted, payload, rule, False)
            for k in ti.static(range(LANES)):
                if i0 + k < a1:
                    sums[0, i0 + k] = acc_a[k]
                    sums[1, i0 + k] = acc_b[k]
                    sums[2, i0 + k] = count[k]


@ti.kernel
def _neighbour_sums(total_buckets: ti.i32, nc: ti.i32, radius: float, box: float, rule: ti.template(),
                    boundary: ti.template(), start: ti.types.ndarray(), run_end: ti.types.ndarray(),
                    pos_sorted: ti.types.ndarray(), payload: ti.types.ndarray(), sums: ti.types.ndarray()):
    """:func:`_lane_sums` as a launch of its own."""
    _lane_sums(total_buckets, nc, radius, box, rule, boundary, start, run_end, pos_sorted, payload, sums)


@ti.kernel
def _list_sums(n: ti.i32, k: ti.template(), rule: ti.template(), nbr: ti.types.ndarray(),
               payload: ti.types.ndarray(), sums: ti.types.ndarray()):
    """The sums of :func:`_neighbour_sums`, count included, over each agent and the k neighbours that
    ``nbr`` lists (:func:`tflock.topological.nearest`: grid slots, nearest first)."""
    for s in range(n):
        th = payload[2, s]
        acc_a = payload[0, s]
        acc_b = payload[1, s]
        if ti.static(rule != VECTOR):
            acc_a = ti.select(rule == RELATIVE, 0.0, th)
            acc_b = 0.0
        for e in ti.static(range(k)):
            o = nbr[e, s]
            if ti.static(rule == VECTOR):
                acc_a += payload[0, o]
                acc_b += payload[1, o]
            elif ti.static(rule == RELATIVE):
                acc_a += wrap_pi(payload[2, o] - th)
            else:
                acc_a += payload[2, o]
        sums[0, s] = acc_a
        sums[1, s] = acc_b
        sums[2, s] = 1.0 + k


@ti.kernel
def _lane_totals(n: ti.i32, payload: ti.types.ndarray(), sums: ti.types.ndarray(), turn: ti.types.ndarray(),
                 updated: ti.types.ndarray(), partial: ti.types.ndarray()):
    """What the lane-wise metrics add up, per block of tflock.metrics' BLOCK agents, in f64: partial[b] = (sum cos
    theta, sum sin theta, sum of the neighbour counts 1 + n_i, their max, sum |dtheta|, agents updated); the blocks
    are fixed, so their sum does not depend on the thread count. One pass over the five arrays, where NumPy took
    five."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            c = ti.f64(0.0)
            s = ti.f64(0.0)
            count = ti.f64(0.0)
            most = ti.f64(0.0)
            turned = ti.f64(0.0)
            moved = 0
            for i in range(blk * SUM_BLOCK, ti.min(n, (blk + 1) * SUM_BLOCK)):
                c += ti.cast(payload[0, i], ti.f64)
                s += ti.cast(payload[1, i], ti.f64)
                k = ti.cast(sums[2, i], ti.f64)
                count += k
                most = ti.max(most, k)
                turned += ti.cast(turn[i], ti.f64)
                moved += updated[i]
            partial[blk, 0] = c
            partial[blk, 1] = s
            partial[blk, 2] = count
            partial[blk, 3] = most
            partial[blk, 4] = turned
            partial[blk, 5] = ti.cast(moved, ti.f64)


PLAIN, BEFORE, BLOCK = 0, 1, 2  # candidates of a stripe's block (see _neighbour_sums_graph)


@ti.func
def _accumulate_graph(begin, end, px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box,
                      pos_sorted: ti.template(), payload: ti.template(), parent: ti.template(), rule: ti.template(),
                      minimum_image: ti.template(), part: ti.template()):
    """:func:`_accumulate` with the count for every rule, and for the components (tflock.lane_graph): candidates
    before the block in the stripe (`part` BEFORE) fold their set label into each near lane's `label`
    (tflock.lane_graph.fold_label), the block's own agents (BLOCK) set their bit in `inmask`. The sums are added as
    :func:`_accumulate` adds them, in the same order."""
    metric = ti.static(PERIODIC if minimum_image else REFLECTING)
    for k in range(begin, end):
        xk = pos_sorted[0, k]
        if xk > 2 * box:  # never; keeps LLVM's loop vectoriser off this loop, as in _accumulate
            break
        dx = displacement(px, xk, box, metric)
        dy = displacement(py, pos_sorted[1, k], box, metric)
        near = dx * dx + dy * dy <= r2
        if ti.static(rule == VECTOR or rule == VECTOR_COUNTED):
            acc_a += ti.select(near, payload[0, k], 0.0)
            acc_b += ti.select(near, payload[1, k], 0.0)
        elif ti.static(rule == RELATIVE):
            acc_a += ti.select(near, wrap_pi(payload[2, k] - th), 0.0)
        else:
            acc_a += ti.select(near, payload[2, k], 0.0)
        count += ti.select(near, 1.0, 0.0)
        if ti.static(part == BEFORE):
            label, other = fold_label(label, other, near, candidate_label(parent, k))
        elif ti.static(part == BLOCK):
            inmask |= ti.select(near, 1 << (k - i0), 0)
    return acc_a, acc_b, count, label, other, inmask


@ti.func
def _stencil_graph(begin, end, s_lo, i0, i1, px, py, th, acc_a, acc_b, count, label, other, inmask, r2, box,
                   pos_sorted: ti.template(), payload: ti.template(), parent: ti.template(), rule: ti.template(),
                   minimum_image: ti.template()):
    """The span [begin, end) in slot order, cut where its candidates stop being in an earlier stripe, before the
    block, in the block [i0, i1) and after it. The candidates before the block fold their labels one by one only
    where they carry several (tflock.lane_graph.span_labels)."""
    acc_a, acc_b, count, label, other, inmask = _accumulate_graph(
        begin, ti.min(end, s_lo), px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box, pos_sorted,
        payload, parent, rule, minimum_image, PLAIN)
    before, after = ti.max(begin, s_lo), ti.min(end, i0)
    first, last = span_labels(parent, before, after)
    if first == last:  # one label: folded once, into the lanes whose count the span raised
        counted = count
        acc_a, acc_b, count, label, other, inmask = _accumulate_graph(
            before, after, px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box, pos_sorted, payload,
            parent, rule, minimum_image, PLAIN)
        label, other = fold_label(label, other, count > counted, first)
    else:
        acc_a, acc_b, count, label, other, inmask = _accumulate_graph(
            before, after, px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box, pos_sorted, payload,
            parent, rule, minimum_image, BEFORE)
    acc_a, acc_b, count, label, other, inmask = _accumulate_graph(
        ti.max(begin, i0), ti.min(end, i1), px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box,
        pos_sorted, payload, parent, rule, minimum_image, BLOCK)
    return _accumulate_graph(ti.max(begin, i1), end, px, py, th, acc_a, acc_b, count, label, other, inmask, i0, r2, box,
                             pos_sorted, payload, parent, rule, minimum_image, PLAIN)


@ti.kernel
def _neighbour_sums_graph(n_stripes: ti.i32, layers: ti.i32, layer_buckets: ti.i32, nc: ti.i32, radius: float,
                          box: float, rule: ti.template(), boundary: ti.template(), start: ti.types.ndarray(),
                          run_end: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), payload: ti.types.ndarray(),
                          sums: ti.types.ndarray(), parent: ti.types.ndarray(), size: ti.types.ndarray(),
                          serial: ti.template()):
    """:func:`_neighbour_sums` for a state whose metrics are taken: the same sums, the count 1 + n_i for every rule
    (the neighbour counts), and the components of the R-graph in ``parent`` (stripes of layers, see
    tflock.lane_graph; LaneComponents.finish completes them). `serial`: on the calling thread (one stripe)."""
    ti.loop_config(serialize=serial)
    for t in range(n_stripes * TASK_STRIDE):  # a stripe a task (tflock.cpu_tasks)
        j = task_at(t)
        if j >= 0:
            r2 = radius * radius
            b_lo, b_hi, s_lo, _ = stripe_range(j, n_stripes, layers, layer_buckets, start)
            for b in range(b_lo, b_hi):
                row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
                wraps = run_wraps(row, x0, x1, nc, boundary)
                for block in range((a1 - a0 + LANES - 1) // LANES):
                    i0 = a0 + block * LANES
                    i1 = ti.min(i0 + LANES, a1)
                    px = lanes(pos_sorted, 0, i0, a1 - 1, LANES)
                    py = lanes(pos_sorted, 1, i0, a1 - 1, LANES)
                    th = lanes(payload, 2, i0, a1 - 1, LANES)
                    acc_a = ti.Vector([0.0] * LANES)
                    acc_b = ti.Vector([0.0] * LANES)
                    count = ti.Vector([0.0] * LANES)
                    label = ti.Vector([NO_LABEL] * LANES)
                    other = ti.Vector([NO_LABEL] * LANES)
                    inmask = ti.Vector([0] * LANES)
                    for r in range(3):
                        b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, boundary, 2)
                        for h in range(2):
                            begin = ti.select(h == 0, b0, b1)
                            end = ti.select(h == 0, e0, e1)
                            if wraps:
                                acc_a, acc_b, count, label, other, inmask = _stencil_graph(
                                    begin, end, s_lo, i0, i1, px, py, th, acc_a, acc_b, count, label, other, inmask, r2,
                                    box, pos_sorted, payload, parent, rule, True)
                            else:
                                acc_a, acc_b, count, label, other, inmask = _stencil_graph(
                                    begin, end, s_lo, i0, i1, px, py, th, acc_a, acc_b, count, label, other, inmask, r2,
                                    box, pos_sorted, payload, parent, rule, False)
                    for k in ti.static(range(LANES)):
                        if i0 + k < a1:
                            sums[0, i0 + k] = acc_a[k]
                            sums[1, i0 + k] = acc_b[k]
                            sums[2, i0 + k] = count[k]
                    roots, recheck = block_roots_vectorised(i1 - i0, label, other, parent, size)
                    while recheck != 0:  # lanes near candidates of two sets: join each near candidate's set
                        q = lowest_lane(recheck)
                        p = ti.Vector([pos_sorted[0, i0 + q], pos_sorted[1, i0 + q]])
                        root = -1
                        for r in range(3):
                            b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, boundary, 2)
                            for h in range(2):
                                first = ti.max(s_lo, ti.select(h == 0, b0, b1))
                                for k in range(first, ti.min(i0, ti.select(h == 0, e0, e1))):
                                    d = displacement(p, ti.Vector([pos_sorted[0, k], pos_sorted[1, k]]), box, boundary)
                                    if d.norm_sqr() <= r2:
                                        root = join_candidate(root, k, parent, size)
                        roots[q] = root
                        recheck &= recheck - 1
                    settle_block(i0, i1 - i0, roots, inmask, parent, size, False)


@ti.func
def _update_lanes(i0, last, tail: ti.template(), t, seed, per_replica, speed, noise, box, max_turn, inv_g,
                  rule: ti.template(), boundary: ti.template(), leader: ti.template(),
                  vectorial: ti.template(), wrap: ti.template(),
                  id_sorted: ti.template(), pos_sorted: ti.template(), payload: ti.template(), sums: ti.template(),
                  pos: ti.template(), theta: ti.template(), trig: ti.template(), ids: ti.template(),
                  turn: ti.template(), updated: ti.template(), draw, bits: ti.template(), word_rank: ti.template(),
                  drawn: ti.template()):
    """Steps 2-5 of the synchronous step for the UPDATE_WIDTH agents at slots i0 .. i0 + UPDATE_WIDTH - 1, from the
    neighbour sums; with `draw`, the drawn agents' frame rows at their ranks (see :func:`drawn_rank` and
    :func:`_drawn_rows`). The `tail` block (the last agents, fewer than UPDATE_WIDTH, up to slot `last`) runs the
    same lanes, its extra lanes reading and writing slot `last` (they compute its values again, bit for bit): every
    agent is computed by the same vector code, whatever its slot, so a batch of replicas gives each agent the bits
    of its lone run (code compiled for one lane may round differently where LLVM fuses multiply-adds)."""
    width = ti.static(UPDATE_WIDTH)
    at = ti.Vector([i0 + k for k in ti.static(range(width))])
    if ti.static(tail):
        at = ti.min(at, last)
    i = ti.Vector([id_sorted[at[k]] for k in ti.static(range(width))])
    th = ti.Vector([payload[2, at[k]] for k in ti.static(range(width))])
    acc_a = ti.Vector([sums[0, at[k]] for k in ti.static(range(width))])
    acc_b = ti.Vector([sums[1, at[k]] for k in ti.static(range(width))])
    count = ti.Vector([sums[2, at[k]] for k in ti.static(range(width))])
    key = ti.Vector([seed] * width, dt=ti.u32)
    local = i
    for k in ti.static(range(width)):  # one replica: its plain keys; one code for lone runs and batches alike
        key[k], local[k] = replica_key(seed, i[k], per_replica)
    u = ti.Vector([uniform_ti(key[k], t, local[k], Stream.NOISE) for k in ti.static(range(width))])
    xi = noise * (u - 0.5)
    if ti.static(vectorial):  # Gregoire-Chate: a unit vector of weight eta (1 + n_i) joins the sum
        sin_psi, cos_psi = sin_cos(TWO_PI * u)
        acc_a += noise * count * cos_psi
        acc_b += noise * count * sin_psi
        xi *= 0.0
    phi = th * 0.0  # desired turn, 003 eqs. (8)-(10)
    if ti.static(rule == VECTOR):
        phi = wrap_pi(atan2(acc_b, acc_a) - th)
    elif ti.static(rule == AVERAGE):
        phi = acc_a / count - th
    elif ti.static(rule == RELATIVE):
        phi = acc_a / count
    else:
        phi = inv_g * (acc_a - count * th)
    update = local >= 0  # synchronous: every agent updates
    if ti.static(leader):
        update = local != 0  # the leader keeps theta0 (Jadbabaie eq. 22)
    # (th + turn) + xi, grouped so: fast math may regroup a sum of three terms, and did so differently where this
    # body is inlined into a loop over steps (_lane_wise_steps); local >= 0, so `opaque` is 0 (unknown to LLVM)
    opaque = ti.select(local < 0, 1, 0)
    new = th + ti.math.clamp(phi, -max_turn, max_turn)
    for k in ti.static(range(width)):
        new[k] = opaque_copy(new[k], opaque[k])
    new += xi
    if ti.static(wrap):
        new = wrap_two_pi(new)
    if ti.static(leader):
        new = ti.select(update, new, th)
    sin_new, cos_new = sin_cos(new)
    qx = ti.Vector([pos_sorted[0, at[k]] for k in ti.static(range(width))]) + speed * cos_new
    qy = ti.Vector([pos_sorted[1, at[k]] for k in ti.static(range(width))]) + speed * sin_new
    if ti.static(boundary == PERIODIC):
        qx = wrap_periodic(qx, box)
        qy = wrap_periodic(qy, box)
    elif ti.static(boundary == REFLECTING):
        qx, flip_x = reflect(qx, box)
        qy, flip_y = reflect(qy, box)
        new = ti.select(flip_x == 1, math.pi - new, new)
        new = ti.select(flip_y == 1, -new, new)
        if ti.static(wrap):
            new = wrap_two_pi(new)
        sin_new, cos_new = sin_cos(new)  # trig holds sin_cos(theta) exactly, as cos_sin computes it
    change = ti.abs(wrap_pi(new - th))
    for k in ti.static(range(width)):
        pos[0, at[k]] = qx[k]
        pos[1, at[k]] = qy[k]
        theta[at[k]] = new[k]
        trig[0, at[k]] = cos_new[k]
        trig[1, at[k]] = sin_new[k]
        ids[at[k]] = i[k]
        turn[at[k]] = change[k]
        updated[at[k]] = ti.select(update[k], 1, 0)
    if draw:
        for k in ti.static(range(width)):
            r = drawn_rank(i[k], bits, word_rank)
            if r >= 0:
                drawn[0, r, 0] = qx[k]
                drawn[0, r, 1] = qy[k]
                drawn[1, r, 0] = cos_new[k]
                drawn[1, r, 1] = sin_new[k]
                drawn[2, r, 0] = new[k]
                drawn[2, r, 1] = ti.select(update[k], 1.0, 0.0)


@ti.func
def _update_all(n, t, seed, per_replica, speed, noise, box, max_turn, inv_g, rule: ti.template(),
                boundary: ti.template(), leader: ti.template(), vectorial: ti.template(), wrap: ti.template(),
                id_sorted: ti.template(), pos_sorted: ti.template(), payload: ti.template(), sums: ti.template(),
                pos: ti.template(), theta: ti.template(), trig: ti.template(), ids: ti.template(),
                turn: ti.template(), updated: ti.template(), draw, bits: ti.template(), word_rank: ti.template(),
                drawn: ti.template()):
    """New headings and positions, written at each agent's slot (the arrangement becomes this step's cell order);
    with `draw`, also the frame rows of the drawn agents (``drawn``, one row per agent in id order)."""
    for b in range(n // UPDATE_WIDTH):
        _update_lanes(b * UPDATE_WIDTH, n - 1, False, t, seed, per_replica, speed, noise, box, max_turn, inv_g, rule,
                      boundary, leader, vectorial, wrap, id_sorted, pos_sorted, payload, sums, pos, theta,
                      trig, ids, turn, updated, draw, bits, word_rank, drawn)
    for b in range(ti.select(n % UPDATE_WIDTH > 0, 1, 0)):  # the last n % UPDATE_WIDTH agents, as one block
        _update_lanes(n // UPDATE_WIDTH * UPDATE_WIDTH + b, n - 1, True, t, seed, per_replica, speed, noise, box,
                      max_turn, inv_g, rule, boundary, leader, vectorial, wrap, id_sorted, pos_sorted,
                      payload, sums, pos, theta, trig, ids, turn, updated, draw, bits, word_rank, drawn)


@ti.kernel
def _update(n: ti.i32, t: ti.i32, seed: ti.u32, per_replica: ti.i32, speed: float, noise: float, box: float,
            max_turn: float, inv_g: float, rule: ti.template(), boundary: ti.template(), leader: ti.template(),
            vectorial: ti.template(), wrap: ti.template(), id_sorted: ti.types.ndarray(),
            pos_sorted: ti.types.ndarray(),
            payload: ti.types.ndarray(), sums: ti.types.ndarray(), pos: ti.types.ndarray(),
            theta: ti.types.ndarray(), trig: ti.types.ndarray(), ids: ti.types.ndarray(), turn: ti.types.ndarray(),
            updated: ti.types.ndarray(), draw: ti.i32, bits: ti.types.ndarray(), word_rank: ti.types.ndarray(),
            drawn: ti.types.ndarray()):
    """:func:`_update_all` as a launch of its own."""
    _update_all(n, t, seed, per_replica, speed, noise, box, max_turn, inv_g, rule, boundary, leader, vectorial, wrap,
                id_sorted, pos_sorted, payload, sums, pos, theta, trig, ids, turn, updated, draw, bits, word_rank,
                drawn)


@ti.kernel
def _lane_wise_steps(steps: ti.i32, t0: ti.i32, ready: ti.i32, finish: ti.i32, draw: ti.i32,
                     n: ti.i32, per_replica: ti.i32, box: float, cell_size: float, nc: ti.i32, n_buckets: ti.i32,
                     total_buckets: ti.i32, boundary: ti.template(), dim: ti.template(),
                     coords: ti.types.ndarray(), bucket: ti.types.ndarray(), counts: ti.types.ndarray(),
                     start: ti.types.ndarray(), order: ti.types.ndarray(), slot_of: ti.types.ndarray(),
                     pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(),
                     id_sorted: ti.types.ndarray(), mixed: ti.types.ndarray(), block_start: ti.types.ndarray(),
                     bounds: ti.types.ndarray(), anchor: ti.types.ndarray(), by_rank: ti.template(),
                     run_end: ti.types.ndarray(), seed: ti.u32, radius: float, speed: float, noise: float,
                     max_turn: float, inv_g: float, rule: ti.template(), summed_rule: ti.template(),
                     leader: ti.template(), vectorial: ti.template(), wrap: ti.template(),
                     pos: ti.types.ndarray(), theta: ti.types.ndarray(), trig: ti.types.ndarray(),
                     ids: ti.types.ndarray(), payload: ti.types.ndarray(), sums: ti.types.ndarray(),
                     turn: ti.types.ndarray(), updated: ti.types.ndarray(), bits: ti.types.ndarray(),
                     word_rank: ti.types.ndarray(), drawn: ti.types.ndarray()):
    """`steps` lane-wise synchronous steps t0 .. t0 + steps - 1 in one launch, on one thread: each the grid build
    (:func:`tflock.neighbors.build_grid`, :func:`tflock.neighbors.cut_runs`), :func:`_sorted_headings`,
    :func:`_lane_sums` and :func:`_update_all`, the bodies of the step's own launches, so every step computes what
    they compute, bit for bit. For the first step, `ready` says what is done already: 1 the grid is built for the
    current positions, 2 its neighbour sums are taken too (by the metrics pass); 0 nothing. With `finish`, the
    launch then builds the grid of the state it made, its runs and sorted headings (what the metrics pass and a
    frame read; steps = 0: only that). With `draw`, the last step writes the drawn agents' frame rows."""
    ti.loop_config(serialize=True)
    for step in range(steps + finish):
        if step > 0 or ready == 0:
            build_grid(pos, ids, n, per_replica, box, cell_size, nc, n_buckets, total_buckets, boundary, dim, coords,
                       bucket, counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed,
                       block_start, bounds, anchor, by_rank)
        if step > 0 or ready < 2:
            cut_runs(total_buckets // nc, nc, start, run_end)
            _sorted_headings(n, order, theta, trig, payload)
            if step < steps:
                _lane_sums(total_buckets, nc, radius, box, summed_rule, boundary, start, run_end, pos_sorted,
                           payload, sums)
        if step < steps:
            _update_all(n, t0 + step, seed, per_replica, speed, noise, box, max_turn, inv_g, rule, boundary, leader,
                        vectorial, wrap, id_sorted, pos_sorted, payload, sums, pos, theta, trig, ids, turn, updated,
                        ti.select(step == steps - 1, draw, 0), bits, word_rank, drawn)


@ti.kernel
def _frame_rows(m: ti.i32, selected: ti.types.ndarray(), slot_of: ti.types.ndarray(), order: ti.types.ndarray(),
                pos_sorted: ti.types.ndarray(), theta: ti.types.ndarray(), updated: ti.types.ndarray(),
                out: ti.types.ndarray()):
    for r in range(m):
        a = selected[r]
        s = slot_of[a]
        out[r, 0] = pos_sorted[0, s]
        out[r, 1] = pos_sorted[1, s]
        out[r, 2] = theta[order[s]]
        out[r, 3] = updated[order[s]]


@ti.kernel
def _drawn_rows(n: ti.i32, id_sorted: ti.types.ndarray(), order: ti.types.ndarray(), bits: ti.types.ndarray(),
                word_rank: ti.types.ndarray(), pos_sorted: ti.types.ndarray(), theta: ti.types.ndarray(),
                updated: ti.types.ndarray(), drawn: ti.types.ndarray(), slot: ti.types.ndarray(),
                serial: ti.template()):
    """Frame rows of the drawn agents (row r: the agent of rank r, see :func:`drawn_rank`): ``drawn[0]`` positions,
    ``drawn[1]`` heading vectors (cos, sin), ``drawn[2]`` (theta, 1 if updated), and their grid slots, by one pass
    over the grid's agents: sequential reads (the state is kept in the previous build's cell order, nearly the
    grid's), where looking each drawn agent up by id misses the cache every time. The lane-wise step writes these
    rows itself for a frame ``draw_next`` announced, at no measurable cost in its ``_update``, and
    :func:`_serial_steps` after its last build, which saves this launch. `serial`: on the calling thread (a small
    swarm, :func:`tflock.cpu_tasks.one_thread`)."""
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for _ in range(1):
            _write_drawn_rows(n, id_sorted, order, bits, word_rank, pos_sorted, theta, updated, drawn, slot)
    else:
        _write_drawn_rows(n, id_sorted, order, bits, word_rank, pos_sorted, theta, updated, drawn, slot)


@ti.func
def _write_drawn_rows(n, id_sorted: ti.template(), order: ti.template(), bits: ti.template(),
                      word_rank: ti.template(), pos_sorted: ti.template(), theta: ti.template(),
                      updated: ti.template(), drawn: ti.template(), slot: ti.template()):
    for s in range(n):
        r = drawn_rank(id_sorted[s], bits, word_rank)
        if r >= 0:
            e = order[s]
            th = theta[e]
            sin_th, cos_th = sin_cos(th)
            drawn[0, r, 0] = pos_sorted[0, s]
            drawn[0, r, 1] = pos_sorted[1, s]
            drawn[1, r, 0] = cos_th
            drawn[1, r, 1] = sin_th
            drawn[2, r, 0] = th
            drawn[2, r, 1] = ti.select(updated[e] != 0, 1.0, 0.0)
            slot[r] = s


class Vicsek(GridModel):
    """Vicsek / Jadbabaie / Samiloglu-Gazi-Koku heading alignment on the cell grid.

    Synchronous updates, or with ``async_bound`` B > 1 the partially asynchronous updates of Samiloglu-Gazi-Koku
    (Assumption 1, Table 1): each agent keeps Omega_i (steps since its last update, starting at 1) and updates
    at step t with probability 1 / (B - Omega_i + 1) (decided by ``Stream.UPDATE``), so it updates at least once
    in any B steps; an updating agent i sees each candidate j as it was at tau = t - d, d uniform in
    {0, ..., B - 1} (``Stream.DELAY`` keyed by i and j): j's position x_j(tau) decides whether it is a
    neighbour and its heading theta_j(tau) enters the rule. Candidates come from the grid with cells of side
    >= R + (B - 1) v0 (no agent moves further than that in B - 1 steps), and a ring of B + 1 past states
    (before t = 0 the initial state) supplies the delayed views. Agents that do not update keep their heading
    (no noise) and still move.

    The state arrays hold the agents in the cell order of the last step (``ids`` names the agent at each
    element), so the grid build and the step read and write memory nearly sequentially; :meth:`state` returns
    them in agent order.

    ``replicas`` > 1 runs that many independent realisations in the same kernel launches: replica r is the run
    with seed ``seed + r`` (bit-identical to running it alone; its leader is its agent 0), agent ids are
    ``r * n + i``, the state arrays hold all ``replicas * n`` agents (replica-major in :meth:`state`) and
    :meth:`replica_metrics` gives the metrics of each. Batches are for systems of at most ``EXACT_PAIRS_MAX``
    agents, whose e_d and e_theta are exact.
    """

    name = "vicsek"
    angle_metrics = ("mean_heading",)
    #: (step, grid build) whose neighbour sums metrics() already computed for the next step (a tuple, which
    #: checkpoint() leaves out)
    _summed: tuple[int, int] | None = None
    #: (step, grid build) whose sorted headings ``payload`` holds, where the fused launch wrote them
    _headed: tuple[int, int] | None = None

    @classmethod
    def can_batch(cls, params: VicsekParams) -> bool:
        return params.n <= EXACT_PAIRS_MAX

    def __new__(cls, params: VicsekParams, *args, **kwargs):
        """``params.dim = 3`` builds the 3D model, :class:`tflock.models.vicsek3d.Vicsek3D`."""
        if params.dim == 3:
            from tflock.models.vicsek3d import Vicsek3D

            return Vicsek3D(params, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, params: VicsekParams, seed: int, engine: EngineInfo, force_async: bool = False,
                 replicas: int = 1) -> None:
        """`force_async` runs the asynchronous kernel even for B = 1 (it must reproduce the synchronous one)."""
        super().__init__(params, seed, engine)
        if replicas > 1 and not self.can_batch(params):
            raise ValueError(f"batches of replicas need n <= {EXACT_PAIRS_MAX}")
        self.replicas = replicas
        n, real = params.n * replicas, engine.real
        self.n_total = n
        exact = params.n <= EXACT_PAIRS_MAX  # a batch's pair errors are exact per replica (can_batch)
        estimate = "" if exact else f" (estimate from {SAMPLED_PAIRS} sampled pairs)"
        self._pair_names = ("e_d", "e_theta") if exact else ("e_d_est", "e_theta_est")
        self.metric_descriptions = {
            "polarization": "polarization |mean unit heading| (Vicsek order parameter)",
            "mean_heading": "circular mean heading (rad)",
            "mean_neighbors": "mean neighbour count",
            "max_neighbors": "max neighbour count",
            "clusters": "clusters (components of the R-graph)",
            "largest_cluster": "largest cluster fraction S",
            self._pair_names[0]: "e_d mean pairwise distance" + estimate,
            self._pair_names[1]: "e_theta mean pairwise heading difference (rad)" + estimate,
            "de_theta": "de_theta mean heading change per step (rad)",
            "updated": "fraction of agents that updated at this step",
        }
        if params.leader.enabled:
            self.metric_descriptions["leader_error"] = "mean |heading - leader heading| of followers (rad)"
            self.first_plots = ("polarization", "leader_error")  # the run's question: do they follow?
        self.observables = TransitionObservables(params.n, 2, params.boundary, params.box, params.radius, replicas)
        self.metric_descriptions.update(self.observables.descriptions)
        self.profile_descriptions = self.observables.profile_descriptions
        self.asynchronous = force_async or params.async_bound > 1
        bound = params.async_bound
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = ti.ndarray(ftype, (2, n))  # component-major, as every kernel array
        self.theta = ti.ndarray(ftype, n)
        self.ids = ti.ndarray(ti.i32, n)
        self.payload = ti.ndarray(ftype, (3, n))  # cos, sin, theta in cell order
        # |heading change| at the last step, and 1 where the agent updated; like pos and theta in the arrangement's
        # order (element s holds agent ids[s]): written at the agent's slot, not at its id, which would scatter
        # two writes per agent over the whole array (and need grid.slots())
        self.turn = ti.ndarray(ftype, n)
        self.updated = ti.ndarray(ti.i32, n)
        ring, m = (bound + 1, n) if self.asynchronous else (1, 1)  # unused 1-element arrays when synchronous
        self.omega = ti.ndarray(ti.i32, m)
        self.hist_pos = ti.ndarray(ftype, (ring, 2, m))
        self.hist_theta = ti.ndarray(ftype, (ring, m))
        reach = params.radius + (bound - 1) * params.speed if self.asynchronous else params.radius
        self.topological = params.neighbours == "topological"
        if self.topological:  # cells sized for the k nearest, at least R for the R-graph metrics
            reach = max(reach, cell_side(params.n, params.k, 2, params.box,
                                         lanes=lane_wise(boundary_code(params.boundary), 2)))
        self.grid = CellGrid(n, 2, params.boundary, params.box, reach, real, replicas)
        # the lane-wise synchronous step (CPU, box boundaries) keeps each agent's neighbour sums between its kernels;
        # the topological step too (any arch and boundary), with each agent's k nearest (grid slots) and the rings
        # each search visited
        self.lane_wise = (not self.asynchronous and params.boundary != "open" and engine.arch == "cpu"
                          and not self.topological)
        m = n if self.lane_wise or self.topological else 1
        self.sums = ti.ndarray(ftype, (3, m))
        self.trig = ti.ndarray(ftype, (2, m))  # cos and sin of theta, element by element
        self.nbr = ti.ndarray(ti.i32, (params.k if self.topological else 1, m))
        self.rings = ti.ndarray(ti.i32, m)
        # components: found by the lane-wise pass itself (lane_graph; metric neighbours only, as lane_wise is), else
        # by the graph kernels of tflock.metrics
        self.components = LaneComponents(self.grid, engine.threads) if self.lane_wise and replicas == 1 else None
        self.graph = None if self.components is not None else NeighbourGraph(self.grid)
        self._grid_step = -1  # step whose positions the grid holds
        self._leader_id = ti.ndarray(ti.i32, 1)  # agent 0
        self._leader_id.fill(0)
        self._measured: tuple[tuple[int, int], float] | None = None  # the last metrics' state, mean heading
        draws = [initial_state(params, seed + r) for r in range(replicas)]
        self.set_state({k: np.concatenate([d[k] for d in draws]) for k in draws[0]}, 0)

    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state. With asynchrony, `state` may carry the ring of past states (``history_x``,
        ``history_theta``) and ``omega`` as :meth:`state` returns them; without them every past view becomes this
        state and Omega = 1."""
        real = self.engine.real
        x = np.ascontiguousarray(np.asarray(state["x"]).T, dtype=real)
        theta = np.ascontiguousarray(state["theta"], dtype=real)
        self.pos.from_numpy(x)
        self.theta.from_numpy(theta)
        if self.lane_wise or self.topological:
            cos_sin(self.n_total, self.theta, self.trig)
        self.ids.from_numpy(np.arange(self.n_total, dtype=np.int32))
        self.turn.fill(0)
        self.updated.fill(0)
        if self.asynchronous:
            ring = self.hist_theta.shape[0]
            if "history_x" in state:  # (ring, n, 2) and (ring, n): slot tau mod ring holds step tau
                hist_x = np.transpose(np.asarray(state["history_x"]), (0, 2, 1))
                hist_theta = np.asarray(state["history_theta"])
                self.omega.from_numpy(np.asarray(state["omega"], dtype=np.int32))
            else:
                hist_x = np.broadcast_to(x, (ring, *x.shape))
                hist_theta = np.broadcast_to(theta, (ring, len(theta)))
                self.omega.fill(1)
            self.hist_pos.from_numpy(np.ascontiguousarray(hist_x, dtype=real))
            self.hist_theta.from_numpy(np.ascontiguousarray(hist_theta, dtype=real))
        self.step_index = step
        self.invalidate()

    def state(self) -> dict[str, np.ndarray]:
        ids = self.ids.to_numpy()
        x = np.empty((self.n_total, 2), dtype=self.engine.real)
        theta = np.empty(self.n_total, dtype=self.engine.real)
        x[ids] = self.pos.to_numpy().T
        theta[ids] = self.theta.to_numpy()
        if not self.asynchronous:
            return {"x": x, "theta": theta}
        return {"x": x, "theta": theta, "history_x": np.transpose(self.hist_pos.to_numpy(), (0, 2, 1)).copy(),
                "history_theta": self.hist_theta.to_numpy(), "omega": self.omega.to_numpy()}

    def updated_agents(self) -> np.ndarray:
        """Boolean mask (agent order) of the agents that updated their heading at the last step."""
        mask = np.empty(self.n_total, dtype=bool)
        mask[self.ids.to_numpy()] = self.updated.to_numpy().astype(bool)
        return mask

    def advance(self, steps: int) -> None:
        """Run `steps` steps: the lane-wise step of at most :data:`FUSED_MAX_AGENTS` agents all in one launch
        (:func:`_lane_wise_steps`, which also builds the grid of the state it makes), else one step (a few launches)
        at a time."""
        p = self.params
        g = self.grid.geometry
        inv_g = 1.0 / p.g if p.rule == "laplacian" else 0.0
        if steps > 0 and self._fused():
            self._fused_steps(steps, inv_g)
            return
        if steps > 0 and self._serial():
            self._serial_steps(steps, inv_g)
            return
        for _ in range(steps):
            self._ensure_grid()
            if self.topological:
                self._topological_step(inv_g)
            elif self.lane_wise:
                self._lane_wise_step(inv_g)
            else:
                _step(self.step_index, self.seed, self.n_total, p.n, p.radius, p.speed, p.noise, p.box,
                      math.radians(p.max_turn_deg), inv_g, p.async_bound,
                      RULES[p.rule], boundary_code(p.boundary), p.leader.enabled, self.asynchronous,
                      p.noise_type == "vectorial", p.wrap_headings, g.cells_per_side, g.n_buckets, self.grid.start,
                      self.grid.mixed, self.grid.order,
                      self.grid.id_sorted, self.grid.pos_sorted, self.grid.coords_sorted, self.payload, self.pos,
                      self.theta, self.ids, self.turn, self.updated, self.omega, self.hist_pos, self.hist_theta)
            self.step_index += 1

    def _lane_wise_step(self, inv_g: float) -> None:
        p, grid = self.params, self.grid
        g, rule, boundary = grid.geometry, RULES[p.rule], boundary_code(p.boundary)
        vectorial = p.noise_type == "vectorial"
        if self._summed != (self.step_index, grid.builds):  # not yet summed by metrics() for this state
            _headings(self.n_total, grid.order, self.theta, self.trig, self.payload)
            _neighbour_sums(g.total_buckets, g.cells_per_side, p.radius, p.box, VECTOR_COUNTED if vectorial else rule,
                            boundary, grid.start, grid.runs(), grid.pos_sorted, self.payload, self.sums)
        _update(self.n_total, self.step_index, self.seed, p.n, p.speed, p.noise, p.box, math.radians(p.max_turn_deg),
                inv_g, rule, boundary, p.leader.enabled, vectorial, p.wrap_headings,
                grid.id_sorted, grid.pos_sorted,
                self.payload, self.sums, self.pos, self.theta, self.trig, self.ids, self.turn, self.updated,
                *self._draw_arguments(3, 2))

    def _fused(self) -> bool:
        """Whether steps, and the grid builds between them, run in :func:`_lane_wise_steps`."""
        return self.lane_wise and self.n_total <= FUSED_MAX_AGENTS

    def _serial(self) -> bool:
        """Whether the asynchronous step, and the grid builds between steps, run in :func:`_serial_steps`: on the
        CPU, up to :data:`SERIAL_MAX_AGENTS` agents. The general step's other uses (synchronous updates in open space,
        vectorial noise) keep one launch a step: in one serial loop LLVM compiles their sums to other roundings (the
        neighbour loop's reduction, the noise term's multiply-adds), and the trajectory must not depend on the
        launches."""
        return (self.asynchronous and self.params.noise_type != "vectorial" and self.engine.arch == "cpu"
                and self.n_total <= SERIAL_MAX_AGENTS)

    def _serial_steps(self, steps: int, inv_g: float) -> None:
        """`steps` steps of the general kernel in one launch of :func:`_serial_steps`, and the grid of the state they
        make (with the frame rows of a frame announced for it)."""
        p, grid = self.params, self.grid
        t0, ready = self.step_index, int(self._grid_step == self.step_index)
        draw, bits, word_rank, drawn = self._draw_arguments(3, 2, made=t0 + steps)
        drawing = self._drawn[1] if draw else None
        _serial_steps(steps, t0, ready, draw, *grid.build_arguments(), self.seed, p.radius, p.speed, p.noise,
                      math.radians(p.max_turn_deg), inv_g, p.async_bound, RULES[p.rule], boundary_code(p.boundary),
                      p.leader.enabled, self.asynchronous, p.noise_type == "vectorial", p.wrap_headings,
                      self.payload, self.pos, self.theta, self.ids, self.turn, self.updated, self.omega,
                      self.hist_pos, self.hist_theta, bits, word_rank, drawn,
                      drawing.slot if drawing is not None else word_rank)  # (an i32 array, unused without draw)
        grid.count_builds(steps + 1 - ready, runs=False)
        self.step_index = t0 + steps
        self._grid_step = self.step_index
        if drawing is not None:
            drawing.located()

    def _ensure_grid(self) -> None:
        """The grid of the current positions; on the fused path with its runs and sorted headings, from one launch of
        :func:`_lane_wise_steps` without steps, and on the serial path from one of :func:`_serial_steps` (a run then
        loads one kernel for its builds and steps, not also the grid's own build)."""
        if self._grid_step != self.step_index:
            if self._fused():
                self._fused_steps(0, 0.0)
            elif self._serial():
                self._serial_steps(0, 0.0)
        super()._ensure_grid()

    def _ready(self) -> int:
        """What the next step finds done: 2 its neighbour sums (taken by the metrics pass), 1 the grid built for the
        current positions (a frame, metrics), 0 nothing."""
        if self._grid_step != self.step_index:
            return 0
        return 2 if self._summed == (self.step_index, self.grid.builds) else 1

    def _fused_steps(self, steps: int, inv_g: float) -> None:
        """`steps` lane-wise steps in one launch of :func:`_lane_wise_steps`, from the grid and the sums that are
        ready for the current state (built by a frame or summed by the metrics pass), and the grid of the state they
        make, with its runs and sorted headings."""
        p, grid = self.params, self.grid
        t0, ready = self.step_index, self._ready()
        rule, vectorial = RULES[p.rule], p.noise_type == "vectorial"
        drawing = self._draw_arguments(3, 2, made=t0 + steps) if steps else self._no_draw_arguments(3, 2)
        draw, bits, word_rank, drawn = drawing
        _lane_wise_steps(steps, t0, ready, 1, draw, *grid.build_arguments(), grid.run_buffer(), self.seed, p.radius,
                         p.speed, p.noise, math.radians(p.max_turn_deg), inv_g, rule,
                         VECTOR_COUNTED if vectorial else rule, p.leader.enabled, vectorial, p.wrap_headings,
                         self.pos, self.theta, self.trig, self.ids, self.payload, self.sums, self.turn, self.updated,
                         bits, word_rank, drawn)
        grid.count_builds(steps + 1 - (1 if ready else 0))
        self.step_index = t0 + steps
        self._grid_step = self.step_index
        self._headed = (self.step_index, grid.builds)

    def _topological_step(self, inv_g: float) -> None:
        """The synchronous step with the k nearest agents as neighbours: :func:`tflock.topological.find_nearest`, their
        sums, then the lane-wise update."""
        p, grid = self.params, self.grid
        g, rule = grid.geometry, RULES[p.rule]
        _headings(self.n_total, grid.order, self.theta, self.trig, self.payload)
        find_nearest(grid, p.k, p.box, self.nbr, self.rings)
        _list_sums(self.n_total, p.k, rule, self.nbr, self.payload, self.sums)
        _update(self.n_total, self.step_index, self.seed, p.n, p.speed, p.noise, p.box, math.radians(p.max_turn_deg),
                inv_g, rule, g.boundary, p.leader.enabled, p.noise_type == "vectorial",
                p.wrap_headings, grid.id_sorted, grid.pos_sorted, self.payload, self.sums, self.pos, self.theta,
                self.trig, self.ids, self.turn, self.updated, *self._draw_arguments(3, 2))

    def metrics(self) -> dict[str, float]:
        if self.replicas > 1:
            raise RuntimeError("a batch of replicas has no single set of metrics: use replica_metrics()")
        p = self.params
        self._ensure_grid()
        leader_heading = float(self._leader_row()[2]) if p.leader.enabled else 0.0
        boundary = boundary_code(p.boundary)
        if self.components is not None:
            out = self._lane_wise_metrics()
            if p.leader.enabled:
                leader_gap = heading_order(self.theta, p.n, leader_heading)[2]
            pairs = pairwise_errors(self.pos, self.theta, p.n, p.box, boundary, 2, self.seed, self.step_index)
        else:
            (polarization, mean_heading, leader_gap), pairs = orders_and_pairs(
                self.theta, self.pos, p.n, leader_heading, p.box, boundary, 2, self.seed, self.step_index)
            out = {"polarization": polarization, "mean_heading": mean_heading}
            out.update(self.graph.compute(p.radius, p.box))
        out.update(zip(self._pair_names, pairs, strict=True))
        if self.components is None:  # (the lane-wise metrics add these up with their own)
            out.update(de_theta=mean(self.turn, p.n), updated=mean(self.updated, p.n))
        if p.leader.enabled:  # the leader's own term is 0
            out["leader_error"] = leader_gap / (p.n - 1) if p.n > 1 else 0.0
        heading = np.array([[math.cos(out["mean_heading"]), math.sin(out["mean_heading"])]])
        self._measured = (self._state_key(), out["mean_heading"])
        out.update({k: float(v[0]) for k, v in
                    self.observables.compute(self.pos, self.ids, heading, self._measured[0]).items()})
        return {name: out[name] for name in self.metric_descriptions}

    def _state_key(self) -> tuple[int, int]:
        """Names the current state for what metrics and a frame of the same step share, as ``_summed`` does: the
        step and the grid build (both callers build the grid first, and a state set anew is a new build)."""
        return self.step_index, self.grid.builds

    def _mean_heading(self) -> float:
        """The circular mean heading of the current state: the one :meth:`metrics` found at this state, or from the
        cos and sin of every heading the lane-wise step keeps (no trigonometry), or from the headings."""
        if self._measured is not None and self._measured[0] == self._state_key():
            return self._measured[1]
        unit = host_view(self.trig) if self.lane_wise or self.topological else None
        if unit is None:
            return heading_order(self.theta, self.params.n)[1]
        c, s = unit[:, : self.params.n].sum(axis=1, dtype=np.float64)
        return math.atan2(s, c) % TWO_PI

    def _lane_wise_metrics(self) -> dict[str, float]:
        """Order parameter and R-graph metrics from the next step's own neighbour pass, run now (its sums are kept
        for that step): the headings' cos and sin in cell order, each agent's neighbour count and the clusters."""
        p, grid = self.params, self.grid
        if self._headed != (self.step_index, grid.builds):
            _headings(self.n_total, grid.order, self.theta, self.trig, self.payload)
        clusters, largest = self._components_pass()
        c, s, count, most, turned, moved = self._lane_totals()
        return {"polarization": math.hypot(c, s) / p.n, "mean_heading": math.atan2(s, c) % TWO_PI,
                "clusters": float(clusters), "largest_cluster": largest / p.n, "mean_neighbors": count / p.n - 1.0,
                "max_neighbors": most - 1.0, "de_theta": turned / p.n, "updated": moved / p.n}

    def _components_pass(self) -> tuple[int, int]:
        """The next step's neighbour sums with each agent's count and the clusters (:func:`_neighbour_sums_graph`, on
        the sorted headings in ``payload``), kept for that step, and the clusters counted: (clusters, agents in the
        largest)."""
        p, grid = self.params, self.grid
        g, boundary = grid.geometry, boundary_code(p.boundary)
        rule = VECTOR_COUNTED if p.noise_type == "vectorial" else RULES[p.rule]  # the sums the step would take
        stripes = self.components.stripes()
        _neighbour_sums_graph(*stripes, g.cells_per_side, p.radius, p.box, rule, boundary, grid.start, grid.runs(),
                              grid.pos_sorted, self.payload, self.sums, self.components.parent,
                              self.components.size, stripes[0] == 1 and one_thread(grid.n))
        self._summed = (self.step_index, grid.builds)
        radius = grid.real(p.radius)  # R^2 as the pass above squares it, in the run's precision
        return self.components.finish(float(radius * radius), p.box, boundary)

    def _lane_totals(self) -> tuple[float, ...]:
        """The lane-wise metrics' totals: sum cos theta, sum sin theta, the neighbour counts' sum and max, sum
        |dtheta|, the agents updated; :func:`_lane_totals` in one pass, or NumPy's sums for a small swarm (a launch
        costs more)."""
        n = self.params.n
        payload = small_host_view(self.payload, n)  # lane-wise: on the CPU
        if payload is not None:
            counts = host_view(self.sums)[2]
            return (float(payload[0].sum(dtype=np.float64)), float(payload[1].sum(dtype=np.float64)),
                    float(counts.sum(dtype=np.float64)), float(counts.max()), total(self.turn, n),
                    total(self.updated, n))
        partial = scratch((n_blocks(n), 6), ti.f64)
        _lane_totals(n, self.payload, self.sums, self.turn, self.updated, partial)
        blocks = host_view(partial)
        c, s, count, _, turned, moved = blocks.sum(axis=0)
        return float(c), float(s), float(count), float(blocks[:, 3].max()), float(turned), float(moved)

    def replica_metrics(self) -> dict[str, np.ndarray]:
        """:meth:`metrics` of each replica of a batch: one array of length ``replicas`` per metric."""
        if self.components is not None:  # a batch of one: the lone model's lane-wise metrics
            return {name: np.array([value]) for name, value in self.metrics().items()}
        p = self.params
        self._ensure_grid()
        replicas, n = self.replicas, p.n
        theta = np.empty(self.n_total)
        theta[self.ids.to_numpy()] = self.theta.to_numpy()
        theta = theta.reshape(replicas, n)
        c, s = np.cos(theta).sum(axis=1), np.sin(theta).sum(axis=1)
        out = {"polarization": np.hypot(c, s) / n, "mean_heading": np.arctan2(s, c) % TWO_PI}
        out.update(self.graph.compute_replicas(p.radius, p.box))
        pairs = replica_pairwise_errors(self.grid, self.pos, self.theta, p.box, boundary_code(p.boundary), 2)
        out.update(zip(self._pair_names, pairs, strict=True))
        # turn and updated are in the arrangement's order, the last grid's slots: replica-major, as the grid's buckets
        out["de_theta"] = self.turn.to_numpy().astype(np.float64).reshape(replicas, n).mean(axis=1)
        out["updated"] = self.updated.to_numpy().reshape(replicas, n).mean(axis=1)
        if p.leader.enabled:
            gap = np.abs(wrap_pi_np(theta[:, 1:] - theta[:, :1])).sum(axis=1)
            out["leader_error"] = gap / (n - 1) if n > 1 else np.zeros(replicas)
        out.update(self.observables.compute(self.pos, self.ids, np.stack([c, s], axis=1)))
        return {name: out[name] for name in self.metric_descriptions}

    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """Agents coloured by heading, arrows along it (the heading of the step just made); with asynchrony,
        those that did not update at this step are dimmed."""
        p = self.params
        drawing = self.drawing(selected)
        grid = self.grid
        drawn = self._rows_written(drawing)  # by the step, for a frame draw_next announced
        if drawn is None:  # written in place on the CPU: no copy kernel
            drawn = np.zeros((3, len(selected), 2), dtype=grid.real)
            if len(selected):
                _drawn_rows(self.n_total, grid.id_sorted, grid.order, drawing.bits, drawing.word_rank,
                            grid.pos_sorted, self.theta, self.updated, drawn, drawing.slot, one_thread(self.n_total))
                drawing.located()
        colors = angle_colors(drawn[2, :, 0])  # from the headings themselves: no atan2 of the directions
        if self.asynchronous:
            colors = np.where(drawn[2, :, 1:2] > 0, colors, dimmed(colors))
        leader = leader_direction = None
        if p.leader.enabled:
            x0, y0, th0, _ = self._leader_row()
            leader = np.array([x0, y0], dtype=np.float32)
            leader_direction = np.array([math.cos(th0), math.sin(th0)], dtype=np.float32)
        if self.lane_wise or self.topological:  # the step keeps cos and sin of every heading
            fields = self._field_images(field_size, self.pos, self.trig, UNIT_VECTORS, grid)
        else:
            fields = self._field_images(field_size, self.pos, self.theta, ANGLES, grid)
        heading = self._mean_heading() if self.observables.enabled else 0.0
        profiles = self.observables.frame_profiles(self.pos, self.ids, np.array([math.cos(heading), math.sin(heading)]),
                                                   self._state_key())
        return Frame(
            positions=np.asarray(drawn[0], dtype=np.float32),
            directions=np.asarray(drawn[1], dtype=np.float32),
            arrow_length=arrow_length(p.box, len(selected), spread=drawn[0] if p.boundary == "open" else None),
            colors=colors,
            edges=self._edges_among(drawn[0], max_edges, p.radius),
            leader=leader,
            leader_direction=leader_direction,
            ids=selected,
            fields=fields,
            profiles=profiles,
        )

    @property
    def color_legend(self) -> ColorLegend:
        """The hue wheel of headings, with notes for the leader (white, larger, labelled) and, with asynchrony,
        the agents dimmed (:func:`dimmed`) because they did not update at this step (white dimmed so)."""
        notes = []
        if self.params.leader.enabled:
            notes.append(("the leader", LEADER_COLOR))
        if self.asynchronous:
            notes.append(("dimmed: not updated", tuple(int(c) for c in dimmed(np.full((1, 3), 255))[0])))
        return ColorLegend(HEADING_LEGEND.title, wheel=True, notes=tuple(notes))

    def _leader_row(self) -> np.ndarray:
        """x, y, theta, updated of the leader, agent 0 (grid current), through a scratch row made once (making an
        ndarray costs about a millisecond; a model attribute would change what a checkpoint holds)."""
        out = scratch((1, 4), self.pos.dtype)
        _frame_rows(1, self._leader_id, self.grid.slots(), self.grid.order, self.grid.pos_sorted, self.theta,
                    self.updated, out)
        return host_array(out)[0].copy()

    def world(self) -> WorldSpec:
        return WorldSpec(dim=2, boundary=self.params.boundary, box=self.params.box, dt=self.dt)
