"""Virtual-agent parallel formations (DESIGN.md section 3.4; papers/004, "reactive model").

A virtual agent (VA) starts at the centre of a square torus of side ``world`` and moves with fixed heading
theta_a and speed |va|: a(t) = centre + t |va| (cos, sin) theta_a, wrapped (computed in float64 from t, so it
never drifts). Agents start uniform in an ``init_length`` x ``init_width`` rectangle whose front side is centred
on the VA, behind it (section 4), headings uniform in [0, 2 pi). One synchronous step t -> t+1 for agent i:

1. neighbours from x(t) on the cell grid (minimum image). S-1: j != i within the vision radius R. S-2
   (non-overlapping rings, section 4, Figure 3b): zone of separation d < min_separation, of alignment
   min_separation <= d < align_radius, of cohesion align_radius <= d <= R. The paper gives no alignment-zone
   radius: ``align_radius`` (4.0 by default, the rings then split [2.5, 5.5] in equal halves) is ours.
2. forces, each the turn toward its target angle clamped to +-``max_turn_deg`` (1 degree: "maximum value 1.00
   decimal degree per time unit", with the worked example 159.5 -> 160 giving 0.5): Fa toward the circular mean
   heading of the alignment neighbours, Fc toward their centre of mass (cohesion neighbours), Fav toward theta_a,
   Fcv toward the VA (minimum image). Which forces are active is Table 1: by the strategy's last digit and by
   whether |x_i - a(t)| <= VAIR. A force with nobody to act on (Fa or Fc without neighbours in its zone) drops out.
3. eq. (3): F = sum(alpha_k F_k) / sum(alpha_k) over the active forces (F = 0 if none, or all weights 0).
   eq. (4): if some neighbour is closer than min_separation, F = Fs alone: the turn away from the nearest one
   (lowest id on ties), clamped to +-``separation_turn_deg`` (2 degrees).
4. communication failure: with probability p (``Stream.UPDATE``) the agent ignores all stimuli this step, F = 0
   (its speed ramp still runs: it is the agent's own controller). eq. (7): theta(t+1) = theta + F + eps,
   eps ~ U[-delta, delta] (``Stream.NOISE``), wrapped into [0, 2 pi).
5. speed, eqs. (1)-(2): crossing the VAIR (inside at x(t) differs from the stored flag) starts a linear ramp
   from the current speed v_ini at t_s = t toward |va| (entering) or |vout| (leaving), lasting
   dt_i = max(1, T + rnd), T = 2 VAIR / (|vout| - |va|) ("time to move from the VAIR boundary to the VA's
   position": an agent chasing the VA closes on it at |vout| - |va|, falling linearly to 0 over the ramp, so at half
   that on average; ``FormationParams.ramp_time``), rnd ~ U(-gamma, gamma), gamma = ``ramp_jitter`` T (the paper:
   gamma ~ T, "a homogeneous distribution of agents inside the VAIR"; drawn from stream 300). The printed
   eq. (1), |v| = |va| - (|v_ini| - |va|)(t - t_f)/dt_i with t_f = t_s + dt_i, is that ramp (t - t_f <= 0);
   the printed eq. (2) runs backwards (it ends at |va|), so we read it as the same ramp toward |vout|:
   |v| = |vout| - (|vout| - |v_ini|)(t_f - t)/dt_i. The speed for the move t -> t+1 is
   v_ini + (target - v_ini) min(1, (t + 1 - t_s)/dt_i), exactly the target after the ramp, so speeds stay in
   [|va|, |vout|]. Initial speeds are settled: |va| inside the VAIR, |vout| outside.
6. move (eq. 5): x(t+1) = x(t) + |v_i| (cos, sin) theta(t+1), wrapped into the torus.

Quantifiers (section 4): tau, the first step at which the desired formation of Definition 1 holds (all agents
inside the VAIR, |wrap(theta_a - theta_i)| < beta_lim, speed |va|), checked inside the step kernel every step
and reported as min(tau, tau_cap), or tau_cap while not reached; phi = |mean exp(i Theta_j)| (eq. 6), Theta_j
the angle of agent j seen from the VA; rho, the mean distance to the VA; the DF flag of the current step.

The state arrays hold the agents in the cell order of the last step (``ids`` names the agent at each element);
they are double-buffered: the step reads one set and writes the other in this step's cell order.
"""

import math
from collections.abc import Mapping

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.engine import EngineInfo
from tflock.fastmath import cos_sin, sin_cos
from tflock.field import UNIT_VECTORS
from tflock.frame import ColorLegend, Frame, Marker, WorldSpec, arrow_length
from tflock.guard import NO_AGENT, Guarded, first_non_finite
from tflock.models.base import Model
from tflock.models.formation_params import (
    ALIGN,
    COHESION,
    FAILED,
    INSIDE,
    OUTSIDE,
    RAMP_STREAM,
    SEPARATION,
    TABLE_1,
    VA_ALIGN,
    VA_COHESION,
    FormationParams,
)
from tflock.neighbors import (
    LANES,
    CellGrid,
    bounded_layout,
    bucket_of_cell,
    build_grid,
    cut_runs,
    lanes,
    load_cell,
    load_vec,
    run_at,
    run_spans,
    run_wraps,
    span_count,
    stencil_span,
    window_run_wraps,
)
from tflock.reductions import BLOCK, n_blocks, scratch
from tflock.reference import formation as ref
from tflock.rng import Stream, uniform_ti
from tflock.space import PERIODIC, REFLECTING, WINDOW, displacement, wrap_periodic, wrap_pi, wrap_two_pi
from tflock.taichi_host import host_array, host_view, small_host_view

TWO_PI = 2 * math.pi
# slots of the constants array
R2, ALIGN2, SEP2, VAIR2, WORLD, CAP, SEP_CAP, W_A, W_C, W_AV, W_CV, VA_HEADING, FAIL, NOISE, VA_SPEED, OUT_SPEED, \
    JITTER, RAMP_TIME, BETA, CAP_BEYOND, SEP_CAP_BEYOND, N_CONSTS = range(22)
# rows of the float and int state arrays
THETA, SPEED, RAMP_FROM, RAMP_DURATION = range(4)
IN_FLAG, RAMP_START = range(2)
RULE_COLORS = np.array([(235, 64, 52), (60, 200, 90), (70, 140, 240), (150, 150, 150)], dtype=np.uint8)
VA_COLOR = (255, 210, 0)
RULE_LEGEND = ColorLegend("agents: what drives them", entries=(
    ("separation (Fs alone)", tuple(RULE_COLORS[SEPARATION].tolist())),
    ("inside the VAIR", tuple(RULE_COLORS[INSIDE].tolist())),
    ("outside the VAIR", tuple(RULE_COLORS[OUTSIDE].tolist())),
    ("communication failure", tuple(RULE_COLORS[FAILED].tolist())),
    ("virtual agent (VA) and VAIR", VA_COLOR),
))
SETTLED_TOL = 1e-6  # |speed - |va|| <= SETTLED_TOL |va| counts as "the speed of the VA" (Definition 1)
#: radians: where the angle to a force's target lies this far beyond the cap (and this far short of a reversal), the
#: capped turn is taken without atan2 (see :func:`capped_turn`)
TURN_MARGIN = 1e-3
COS_TURN_MARGIN = math.cos(TURN_MARGIN)
#: what a pass of :func:`_scan` computes: the nearest neighbour, the zone sums, or both; FAR: skipping candidates
#: beyond reach of every lane first (see :func:`sparse_cells`)
NEAREST, ZONES, FAR = 1, 2, 4
#: on the CPU, swarms of at most this many agents run the steps between two observations on one thread, in
#: launches of at most SERIAL_RUN steps (:func:`_serial_steps`): there a launch costs more than its arithmetic
SERIAL_MAX_N, SERIAL_RUN = 1024, 1024


def sparse_cells(cell_size: float, params: FormationParams) -> bool:
    """Whether the lane-wise scan skips a candidate beyond reach of every lane of its block (:func:`_scan` with
    ``FAR``): where cells are so large (over 3.3 R wide with 8 lanes, 4.7 R with 16) that even a run of one cell
    (3 x 3 of them) holds over four times the area within reach of its LANES agents, most candidates are out of reach
    of all of them (the default workload at 1e6: a 2000 x 2000 tiling of cells 5.2 R wide). With cells of side R
    nearly every candidate is near some lane, and the branch is pure cost. Reach is R: the parameters keep the minimum
    separation within it."""
    return 9 * cell_size**2 > 4 * LANES * math.pi * params.radius**2


@ti.func
def unit_force(target, theta, cap):
    """The turn toward `target`, at most `cap` either way."""
    return ti.math.clamp(wrap_pi(target - theta), -cap, cap)


@ti.func
def capped_turn(v, theta, heading, cap, cos_beyond):
    """``unit_force(atan2(v[1], v[0]), theta, cap)``, the turn toward the direction of v, with no atan2 where the
    cap decides it. `heading` is (cos theta, sin theta), `cos_beyond` = cos(min(cap + TURN_MARGIN, pi)). Where the
    angle a between heading and v lies in (cap + TURN_MARGIN, pi - TURN_MARGIN), the clamped turn is +-cap, signed
    as heading x v; the margin is thousands of times the rounding of either test, so the two give the same bits.
    Elsewhere (a turn within the cap or near it, a near reversal, v = 0 or not finite) the formula itself."""
    cross = heading[0] * v[1] - heading[1] * v[0]
    dot = heading[0] * v[0] + heading[1] * v[1]
    norm = v.norm()
    turn = 0.0
    if dot < norm * cos_beyond and dot > -norm * COS_TURN_MARGIN:
        turn = ti.select(cross > 0, cap, -cap)
    else:
        turn = unit_force(ti.atan2(v[1], v[0]), theta, cap)
    return turn


@ti.func
def df_holds(q, theta, speed, va, c: ti.template()):
    """Definition 1 for one agent: inside the VAIR, parallel to the VA within beta_lim, at the VA's speed."""
    d = displacement(q, va, c[WORLD], PERIODIC)
    aligned = ti.abs(wrap_pi(c[VA_HEADING] - theta)) < c[BETA]
    settled = ti.abs(speed - c[VA_SPEED]) <= SETTLED_TOL * c[VA_SPEED]
    return d.norm_sqr() <= c[VAIR2] and aligned and settled


@ti.func
def _no_neighbours(width: ti.template(), c: ti.template()):
    """The sums of :func:`_scan` before any candidate, for `width` agents: zeros, no zone met, and as the nearest
    neighbour none, at the minimum separation with an id above all (a neighbour exactly that far replaces it,
    which changes nothing: eq. (4) asks for one strictly closer)."""
    zero = ti.Vector([0.0] * width)
    return zero, zero, zero, zero, ti.Vector([0] * width), zero + c[SEP2], ti.Vector([NO_AGENT] * width), zero, zero


@ti.func
def _scan(begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y,
          c: ti.template(), zones: ti.template(), minimum_image: ti.template(), id_sorted: ti.template(),
          pos_sorted: ti.template(), payload: ti.template(), parts: ti.template()):
    """Step 1 for the candidates [begin, end): with ``ZONES`` in `parts`, add those each agent sees to its zone
    sums and mark in `met` the zones that hold someone (the bits ALIGN, COHESION: a force with nobody to act on
    drops out); with ``NEAREST``, keep its nearest neighbour at most the minimum separation away (lowest id on
    ties). Element-wise: the agents `me` (ids) with positions (px, py) are the lanes of vectors, a single agent a
    vector of one. Without ``minimum_image`` the plain difference is taken (see
    :func:`tflock.neighbors.run_wraps`). With ``FAR``, a candidate farther than R from every lane is passed over
    before the sums: it changes none of them (the minimum separation lies within R, and the nearest starts there)."""
    r2, sep2, align2, world = c[R2], c[SEP2], c[ALIGN2], c[WORLD]  # locals: kept in registers in the loop
    metric = ti.static(PERIODIC if minimum_image else REFLECTING)  # REFLECTING: the plain difference
    for k in range(begin, end):
        xk = pos_sorted[0, k]
        if xk > 2 * world:  # never (positions lie in the torus); an exit LLVM's loop vectoriser cannot handle keeps
            break  # it off this loop (see the Vicsek model's lane-wise sums)
        dx = displacement(px, xk, world, metric)
        dy = displacement(py, pos_sorted[1, k], world, metric)
        d2 = dx * dx + dy * dy
        if ti.static(parts & FAR):
            if not (d2 <= r2).any():  # beyond reach of every lane
                continue
        j = id_sorted[k]
        other = j != me  # ids, not slots: one i32 compare with the id the tie rule loads anyway
        if ti.static(parts & ZONES):
            seen = (d2 <= r2) & other
            wa = seen
            wc = seen
            if ti.static(zones == 2):  # rings: alignment [sep, align), cohesion [align, R]
                wa = seen & (d2 >= sep2) & (d2 < align2)
                wc = seen & (d2 >= align2)
            a_cos += ti.select(wa, payload[0, k], 0.0)
            a_sin += ti.select(wa, payload[1, k], 0.0)
            c_x += ti.select(wc, dx, 0.0)
            c_y += ti.select(wc, dy, 0.0)
            met |= ti.select(wa, ALIGN, 0) | ti.select(wc, COHESION, 0)
        if ti.static(parts & NEAREST):
            nearer = other & ((d2 < best) | ((d2 == best) & (j < best_id)))
            best = ti.select(nearer, d2, best)
            best_id = ti.select(nearer, j, best_id)
            away_x = ti.select(nearer, -dx, away_x)
            away_y = ti.select(nearer, -dy, away_y)
    return a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y


@ti.func
def _scan_run(row, x0, x1, wraps, nc, start: ti.template(), layout: ti.template(), me, px, py, a_cos, a_sin, c_x,
              c_y, met, best, best_id, away_x, away_y, c: ti.template(), zones: ti.template(),
              id_sorted: ti.template(), pos_sorted: ti.template(), payload: ti.template(), parts: ti.template()):
    """:func:`_scan` over the 3 x (width + 2) cells of the run of cells [x0, x1) in grid row `row`, by minimum
    image where the run `wraps`."""
    for r in range(3):
        b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, layout, 2)
        for h in range(2):
            begin = ti.select(h == 0, b0, b1)
            end = ti.select(h == 0, e0, e1)
            if wraps:
                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                    begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y, c, zones,
                    True, id_sorted, pos_sorted, payload, parts)
            else:
                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                    begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y, c, zones,
                    False, id_sorted, pos_sorted, payload, parts)
    return a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y


@ti.func
def _advance(s, t, seed, c: ti.template(), out_set, in_set, va, va_next, a_cos, a_sin, c_x, c_y, met, best, away,
             order: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(), f_old: ti.template(),
             i_old: ti.template(), pos_new: ti.template(), f_new: ti.template(), i_new: ti.template(),
             ids_new: ti.template(), rule: ti.template(), payload: ti.template(), trig: ti.template()):
    """Steps 2-6 for the agent at slot s, from its neighbour sums and `met` (see :func:`_scan`): the new state is
    written at slot s. Returns 1 when the agent is outside the desired formation afterwards (Definition 1), else
    0."""
    i = id_sorted[s]
    e = order[s]
    p = load_vec(pos_sorted, s, 2)
    th = f_old[THETA, e]
    heading = ti.Vector([payload[0, s], payload[1, s]])  # cos th, sin th
    dva = displacement(p, va, c[WORLD], PERIODIC)
    inside = dva.norm_sqr() <= c[VAIR2]
    # the turn: a failed agent's is 0, else Fs alone when separating, else the weighted mean; only the forces the
    # agent uses are computed (the draws are counters, so skipping one changes no other)
    force = 0.0
    r = ti.select(inside, INSIDE, OUTSIDE)
    failed = False
    if c[FAIL] > 0:  # a draw u in [0, 1) is never below 0
        failed = uniform_ti(seed, t, i, Stream.UPDATE) < c[FAIL]
    if failed:
        r = FAILED
    elif best < c[SEP2]:  # eq. (4)
        force = capped_turn(away, th, heading, c[SEP_CAP], c[SEP_CAP_BEYOND])
        r = SEPARATION
    else:
        active = ti.select(inside, in_set, out_set) & (met | VA_ALIGN | VA_COHESION)
        num = 0.0
        den = 0.0
        if (active & ALIGN) != 0:
            num += c[W_A] * capped_turn(ti.Vector([a_cos, a_sin]), th, heading, c[CAP], c[CAP_BEYOND])
            den += c[W_A]
        if (active & COHESION) != 0:
            num += c[W_C] * capped_turn(ti.Vector([c_x, c_y]), th, heading, c[CAP], c[CAP_BEYOND])
            den += c[W_C]
        if (active & VA_ALIGN) != 0:
            num += c[W_AV] * unit_force(c[VA_HEADING], th, c[CAP])
            den += c[W_AV]
        if (active & VA_COHESION) != 0:
            num += c[W_CV] * capped_turn(dva, th, heading, c[CAP], c[CAP_BEYOND])
            den += c[W_CV]
        if den > 0:
            force = num / den  # eq. (3)
    eps = 0.0
    if c[NOISE] > 0:
        eps = c[NOISE] * (2.0 * uniform_ti(seed, t, i, Stream.NOISE) - 1.0)
    new = wrap_two_pi(th + force + eps)  # eqs. (5), (7)
    # speed ramps, eqs. (1)-(2)
    flag = ti.select(inside, 1, 0)
    v_from = f_old[RAMP_FROM, e]
    t_start = i_old[RAMP_START, e]
    duration = f_old[RAMP_DURATION, e]
    if flag != i_old[IN_FLAG, e]:
        v_from = f_old[SPEED, e]
        t_start = t
        jitter = c[JITTER] * c[RAMP_TIME] * (2.0 * uniform_ti(seed, t, i, RAMP_STREAM) - 1.0)
        duration = ti.max(1.0, c[RAMP_TIME] + jitter)
    target = ti.select(inside, c[VA_SPEED], c[OUT_SPEED])
    progress = (t + 1 - t_start) / duration
    speed = target
    if progress < 1:
        speed = v_from + (target - v_from) * progress
    # polynomials (tflock.fastmath), not two libm calls
    sin_new, cos_new = sin_cos(new)
    q = wrap_periodic(p + speed * ti.Vector([cos_new, sin_new]), c[WORLD])
    pos_new[0, s] = q[0]
    pos_new[1, s] = q[1]
    f_new[THETA, s] = new
    f_new[SPEED, s] = speed
    f_new[RAMP_FROM, s] = v_from
    f_new[RAMP_DURATION, s] = duration
    i_new[IN_FLAG, s] = flag
    i_new[RAMP_START, s] = t_start
    ids_new[s] = i
    trig[0, s] = cos_new  # the next step's headings, with no cos and sin to compute again
    trig[1, s] = sin_new
    rule[s] = r  # at the agent's new slot, beside its state (a write by agent id scattered over all of memory)
    return ti.select(df_holds(q, new, speed, va_next, c), 0, 1)


@ti.func
def _step_all(t, seed, n, c: ti.template(), out_set, in_set, zones: ti.template(), va_x, va_y, next_x, next_y, nc,
              n_buckets, cell_size, layout: ti.template(), lane_wise: ti.template(), sparse: ti.template(),
              start: ti.template(), run_end: ti.template(), bounds: ti.template(), anchor: ti.template(),
              order: ti.template(), id_sorted: ti.template(), pos_sorted: ti.template(), coords_sorted: ti.template(),
              payload: ti.template(), trig: ti.template(), f_old: ti.template(), i_old: ti.template(),
              pos_new: ti.template(), f_new: ti.template(), i_new: ti.template(), ids_new: ti.template(),
              rule: ti.template(), bad: ti.template(), tau: ti.template()):
    """One synchronous step (see the module) from the grid of the current state, as :func:`_step` launches it.
    ``lane_wise`` (the CPU): the agents of each run of cells (:meth:`CellGrid.runs`) are scanned ``LANES`` at a
    time against the run's 3 x (width + 2) cells; otherwise each agent scans its own stencil. Both meet the same
    candidates in the same order (a run's wider window only adds candidates beyond R), so they give the same step."""
    for s in range(n):  # headings in cell order: contiguous reads in the neighbour loop
        e = order[s]
        payload[0, s] = trig[0, e]
        payload[1, s] = trig[1, e]
    bad[0] = 0
    if ti.static(lane_wise):
        first_pass = ti.static(NEAREST | ZONES | (FAR if sparse else 0))
        # only the buckets from the first agent's to the last one's: Taichi's CPU threads split a loop's range
        # into contiguous parts, and a swarm filling half a window's rows would leave one thread all the work
        first = bucket_of_cell(load_cell(coords_sorted, 0, 2), nc, n_buckets, layout, 2)
        last = bucket_of_cell(load_cell(coords_sorted, n - 1, 2), nc, n_buckets, layout, 2)
        for occupied in range(last - first + 1):
            b = first + occupied
            row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
            wraps = True  # declared here: a static if's branches are scopes of their own
            if ti.static(layout == WINDOW):
                wraps = window_run_wraps(row, x0, x1, nc, cell_size, c[WORLD], bounds, anchor)
            else:
                wraps = run_wraps(row, x0, x1, nc, layout)
            for block in range((a1 - a0 + LANES - 1) // LANES):
                i0 = a0 + block * LANES
                me = ti.Vector([id_sorted[ti.min(i0 + k, a1 - 1)] for k in ti.static(range(LANES))])
                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _no_neighbours(LANES, c)
                px = lanes(pos_sorted, 0, i0, a1 - 1, LANES)
                py = lanes(pos_sorted, 1, i0, a1 - 1, LANES)
                # where the run's stencil is crowded enough that an agent expects more than two neighbours within the
                # minimum separation, nearly every agent separates and uses no zone sum (eq. 4): the nearest
                # neighbours first, the zone sums only for a block where some agent does not separate; elsewhere
                # both in one pass (the same sums, in the same order, either way). Counted a block, not a run: out of
                # the block loop the count slows the uncrowded default workload
                candidates = 0
                for r in range(3):
                    b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, layout, 2)
                    candidates += e0 - b0 + e1 - b1
                crowded = candidates * math.pi * c[SEP2] > 2.0 * 3 * (x1 - x0 + 2) * cell_size * cell_size
                # the nearest neighbours, with the zone sums unless crowded: this loop stays inline (through
                # _scan_run, with the parts picked at run time, the step kernel is markedly slower)
                for r in range(3):
                    b0, e0, b1, e1 = run_spans(row, x0, x1, r, nc, start, layout, 2)
                    for h in range(2):
                        begin = ti.select(h == 0, b0, b1)
                        end = ti.select(h == 0, e0, e1)
                        if not crowded:
                            if wraps:
                                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                                    begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x,
                                    away_y, c, zones, True, id_sorted, pos_sorted, payload, first_pass)
                            else:
                                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                                    begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x,
                                    away_y, c, zones, False, id_sorted, pos_sorted, payload, first_pass)
                        elif wraps:
                            a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                                begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x,
                                away_y, c, zones, True, id_sorted, pos_sorted, payload, NEAREST)
                        else:
                            a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                                begin, end, me, px, py, a_cos, a_sin, c_x, c_y, met, best, best_id, away_x,
                                away_y, c, zones, False, id_sorted, pos_sorted, payload, NEAREST)
                spread = 0  # some agent of the block does not separate
                for k in ti.static(range(LANES)):
                    spread |= ti.select(best[k] >= c[SEP2], 1, 0)
                if crowded and spread:
                    a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan_run(
                        row, x0, x1, wraps, nc, start, layout, me, px, py, a_cos, a_sin, c_x, c_y, met, best,
                        best_id, away_x, away_y, c, zones, id_sorted, pos_sorted, payload, ZONES)
                outside = 0  # one atomic add to the shared counter a block, not one an agent
                # a loop, not unrolled: inlined copies of the update would bloat and slow the kernel
                for k in range(ti.min(LANES, a1 - i0)):
                    outside += _advance(i0 + k, t, seed, c, out_set, in_set, ti.Vector([va_x, va_y]),
                                        ti.Vector([next_x, next_y]), a_cos[k], a_sin[k], c_x[k], c_y[k], met[k],
                                        best[k], ti.Vector([away_x[k], away_y[k]]), order, id_sorted, pos_sorted,
                                        f_old, i_old, pos_new, f_new, i_new, ids_new, rule, payload, trig)
                if outside:
                    ti.atomic_add(bad[0], outside)
    else:
        for s in range(n):
            a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _no_neighbours(1, c)
            px = ti.Vector([pos_sorted[0, s]])
            py = ti.Vector([pos_sorted[1, s]])
            cell = load_cell(coords_sorted, s, 2)
            for o in range(ti.static(span_count(layout, 2))):
                lo, hi, _ = stencil_span(cell, o, nc, n_buckets, layout, 2)
                a_cos, a_sin, c_x, c_y, met, best, best_id, away_x, away_y = _scan(
                    start[lo], start[hi], ti.Vector([id_sorted[s]]), px, py, a_cos, a_sin, c_x, c_y, met, best,
                    best_id, away_x, away_y, c, zones, True, id_sorted, pos_sorted, payload, NEAREST | ZONES)
            if _advance(s, t, seed, c, out_set, in_set, ti.Vector([va_x, va_y]), ti.Vector([next_x, next_y]),
                        a_cos[0], a_sin[0], c_x[0], c_y[0], met[0], best[0], ti.Vector([away_x[0], away_y[0]]),
                        order, id_sorted, pos_sorted, f_old, i_old, pos_new, f_new, i_new, ids_new, rule, payload,
                        trig):
                ti.atomic_add(bad[0], 1)
    if bad[0] == 0 and tau[0] < 0:
        tau[0] = t + 1


@ti.kernel
def _step(t: ti.i32, seed: ti.u32, n: ti.i32, c: ti.types.ndarray(), out_set: ti.i32, in_set: ti.i32,
          zones: ti.template(), va_x: float, va_y: float, next_x: float, next_y: float,
          nc: ti.i32, n_buckets: ti.i32, cell_size: float, layout: ti.template(), lane_wise: ti.template(),
          sparse: ti.template(),
          start: ti.types.ndarray(), run_end: ti.types.ndarray(), bounds: ti.types.ndarray(),
          anchor: ti.types.ndarray(), order: ti.types.ndarray(), id_sorted: ti.types.ndarray(),
          pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), payload: ti.types.ndarray(),
          trig: ti.types.ndarray(), f_old: ti.types.ndarray(), i_old: ti.types.ndarray(), pos_new: ti.types.ndarray(),
          f_new: ti.types.ndarray(), i_new: ti.types.ndarray(), ids_new: ti.types.ndarray(),
          rule: ti.types.ndarray(), bad: ti.types.ndarray(), tau: ti.types.ndarray()):
    _step_all(t, seed, n, c, out_set, in_set, zones, va_x, va_y, next_x, next_y, nc, n_buckets, cell_size, layout,
              lane_wise, sparse, start, run_end, bounds, anchor, order, id_sorted, pos_sorted, coords_sorted, payload,
              trig, f_old, i_old, pos_new, f_new, i_new, ids_new, rule, bad, tau)


@ti.kernel
def _serial_steps(steps: ti.i32, t0: ti.i32, seed: ti.u32, n: ti.i32, c: ti.types.ndarray(), out_set: ti.i32,
                  in_set: ti.i32, zones: ti.template(), va: ti.types.ndarray(), box: float, radius: float,
                  max_side: ti.i32, tiling_nc: ti.i32, tiling_cell: float,
                  coords: ti.types.ndarray(), bucket: ti.types.ndarray(), counts: ti.types.ndarray(),
                  start: ti.types.ndarray(), order: ti.types.ndarray(), slot_of: ti.types.ndarray(),
                  pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), id_sorted: ti.types.ndarray(),
                  mixed: ti.types.ndarray(), block_start: ti.types.ndarray(), bounds: ti.types.ndarray(),
                  anchor: ti.types.ndarray(), by_rank: ti.template(), run_end: ti.types.ndarray(),
                  payload: ti.types.ndarray(), trig: ti.types.ndarray(), pos: ti.types.ndarray(),
                  f: ti.types.ndarray(), i: ti.types.ndarray(), ids: ti.types.ndarray(), pos_new: ti.types.ndarray(),
                  f_new: ti.types.ndarray(), i_new: ti.types.ndarray(), ids_new: ti.types.ndarray(),
                  rule: ti.types.ndarray(), bad: ti.types.ndarray(), tau: ti.types.ndarray(),
                  last: ti.types.ndarray()):
    """`steps` steps from step `t0` in one launch, on one thread (a small swarm: a launch costs more than its
    arithmetic), each the grid's layout and build and :func:`_step_all`, as the host's launches make them
    (:meth:`Formation._one_step`), so every step computes what they compute, bit for bit: the window's layout where
    one holds the swarm (:func:`tflock.neighbors.bounded_layout`, `max_side` cells a side at most) and the lane-wise
    step; else the torus's tiling (`tiling_nc` cells of side `tiling_cell` a side) and the per-agent step (the two
    give the same step; the lane-wise one's second copy would lengthen the kernel's load at every process start).
    The new state is copied back into (pos, f, i, ids), the current buffers. `va` holds the VA's positions at steps
    t0 .. t0 + steps (computed in float64 on the host, as the host's steps take them). ``last[0]``: the last step's
    window cells a side, 0 where it took the tiling."""
    ti.loop_config(serialize=True)
    for _ in range(1):
        for made in range(steps):
            t = t0 + made
            side = bounded_layout(n, 2, box, radius, max_side, WINDOW, pos, bounds, anchor)
            last[0] = side
            if side > 0:
                cells = side * side
                build_grid(pos, ids, n, n, box, radius, side, cells, cells, WINDOW, 2, coords, bucket, counts, start,
                           order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed, block_start, bounds, anchor,
                           by_rank)
                cut_runs(side, side, start, run_end)
                _step_all(t, seed, n, c, out_set, in_set, zones, va[made, 0], va[made, 1], va[made + 1, 0],
                          va[made + 1, 1], side, cells, radius, WINDOW, True, False, start, run_end, bounds, anchor,
                          order, id_sorted, pos_sorted, coords_sorted, payload, trig, f, i, pos_new, f_new, i_new,
                          ids_new, rule, bad, tau)
            else:
                cells = tiling_nc * tiling_nc
                build_grid(pos, ids, n, n, box, tiling_cell, tiling_nc, cells, cells, PERIODIC, 2, coords, bucket,
                           counts, start, order, slot_of, pos_sorted, coords_sorted, id_sorted, mixed, block_start,
                           bounds, anchor, by_rank)
                _step_all(t, seed, n, c, out_set, in_set, zones, va[made, 0], va[made, 1], va[made + 1, 0],
                          va[made + 1, 1], tiling_nc, cells, tiling_cell, PERIODIC, False, False, start,
                          run_end, bounds, anchor, order, id_sorted, pos_sorted, coords_sorted, payload, trig, f, i,
                          pos_new, f_new, i_new, ids_new, rule, bad, tau)
            for s in range(n):
                for a in ti.static(range(2)):
                    pos[a, s] = pos_new[a, s]
                    i[a, s] = i_new[a, s]
                for a in ti.static(range(4)):
                    f[a, s] = f_new[a, s]
                ids[s] = ids_new[s]


@ti.kernel
def _quantifier_blocks(n: ti.i32, c: ti.types.ndarray(), va_x: float, va_y: float, pos: ti.types.ndarray(),
                       f: ti.types.ndarray(), rule: ti.types.ndarray(), partial: ti.types.ndarray()):
    """Per block of agents: sum cos Theta, sin Theta, distance to the VA, inside, aligned, speed, separation, and
    agents outside the desired formation (storage order: deterministic block sums)."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            va = ti.Vector([va_x, va_y])
            acc = ti.Vector([0.0] * 8)
            for e in range(blk * BLOCK, ti.min(n, (blk + 1) * BLOCK)):
                p = load_vec(pos, e, 2)
                d = displacement(va, p, c[WORLD], PERIODIC)  # VA -> agent
                dist = d.norm()
                th = f[THETA, e]
                inside = d.norm_sqr() <= c[VAIR2]
                acc[0] += ti.select(dist > 0, d[0] / dist, 1.0)  # cos Theta, Theta = atan2(0, 0) = 0 at the VA
                acc[1] += ti.select(dist > 0, d[1] / dist, 0.0)
                acc[2] += dist
                acc[3] += ti.select(inside, 1.0, 0.0)
                acc[4] += ti.select(ti.abs(wrap_pi(c[VA_HEADING] - th)) < c[BETA], 1.0, 0.0)
                acc[5] += f[SPEED, e]
                acc[6] += ti.select(rule[e] == SEPARATION, 1.0, 0.0)  # a count, exact whatever the order
                acc[7] += ti.select(df_holds(p, th, f[SPEED, e], va, c), 0.0, 1.0)
            for k in ti.static(range(8)):
                partial[blk, k] = acc[k]


@ti.kernel
def _tau_now(t: ti.i32, n: ti.i32, c: ti.types.ndarray(), va_x: float, va_y: float, pos: ti.types.ndarray(),
             f: ti.types.ndarray(), bad: ti.types.ndarray(), tau: ti.types.ndarray()):
    """tau = t if the desired formation holds now, else 'not reached' (-1)."""
    bad[0] = 0
    for e in range(n):
        va = ti.Vector([va_x, va_y])
        if not df_holds(load_vec(pos, e, 2), f[THETA, e], f[SPEED, e], va, c):
            ti.atomic_add(bad[0], 1)
    tau[0] = ti.select(bad[0] == 0, t, -1)


@ti.kernel
def _frame_rows(m: ti.i32, n: ti.i32, selected: ti.types.ndarray(), ids: ti.types.ndarray(),
                where: ti.types.ndarray(), pos: ti.types.ndarray(), f: ti.types.ndarray(), rule: ti.types.ndarray(),
                out: ti.types.ndarray()):
    for e in range(n):
        where[ids[e]] = e
    for r in range(m):
        a = selected[r]
        e = where[a]
        out[r, 0] = pos[0, e]
        out[r, 1] = pos[1, e]
        out[r, 2] = f[THETA, e]
        out[r, 3] = rule[e]
        out[r, 4] = f[SPEED, e]


class Formation(Model):
    """Reactive agents converging to a parallel formation inside the VAIR of a moving virtual agent (papers/004).

    See the module docstring for the step and the readings of eqs. (1)-(4), (7) and Table 1.
    """

    name = "formation"
    color_legend = RULE_LEGEND

    def __init__(self, params: FormationParams, seed: int, engine: EngineInfo) -> None:
        super().__init__(params, seed, engine)
        n, real = params.n, engine.real
        self.metric_descriptions = {
            "tau": f"tau: first step of the desired formation (Definition 1), capped at {params.tau_cap}",
            "df": "1 when the agents are in the desired formation now, else 0",
            "phi": "phi: angular uniformity around the VA (eq. 6); 0 uniform around it, 1 all in one direction",
            "rho": "rho: mean distance to the VA",
            "inside": "fraction of agents inside the VAIR",
            "aligned": "fraction of agents within beta_lim of the VA heading",
            "mean_speed": "mean speed",
            "separating": "fraction of agents driven by separation (Fs) at the last step",
        }
        ftype = ti.f32 if real == np.float32 else ti.f64
        self.pos = [ti.ndarray(ftype, (2, n)) for _ in range(2)]
        self.f = [ti.ndarray(ftype, (4, n)) for _ in range(2)]  # theta, speed, ramp_from, ramp_duration
        self.i = [ti.ndarray(ti.i32, (2, n)) for _ in range(2)]  # inside flag, ramp_start
        self.ids = [ti.ndarray(ti.i32, n) for _ in range(2)]
        self.cur = 0
        self.payload = ti.ndarray(ftype, (2, n))
        self.trig = ti.ndarray(ftype, (2, n))  # cos and sin of each heading, in the state's order (fastmath.cos_sin)
        self.rule = ti.ndarray(ti.i32, n)  # what drove each agent at the last step (in the state's order, as ids)
        self.where = ti.ndarray(ti.i32, n)
        self.bad = ti.ndarray(ti.i32, 1)
        self.tau = ti.ndarray(ti.i32, 1)
        self.partial = ti.ndarray(ftype, (n_blocks(n), 8))
        self.consts = ti.ndarray(ftype, N_CONSTS)
        self.consts.from_numpy(self._constants().astype(real))
        self.lane_wise = engine.arch == "cpu"  # see _step
        # the swarm fills a small part of the torus: on the CPU the grid covers the window of cells it occupies (the
        # torus's capped tiling had cells ~5 R wide at N = 1e6); GPU arches keep the tiling (not yet run there)
        self.grid = CellGrid(n, 2, "periodic", params.world, params.radius, real, bounded=self.lane_wise)
        self._zones = int(params.strategy[2])
        self._out_set, self._in_set = TABLE_1[int(params.strategy[4])]
        self.set_state(ref.initial_state(params, seed), 0)

    def _constants(self) -> np.ndarray:
        p = self.params
        c = np.zeros(N_CONSTS)
        c[R2], c[ALIGN2], c[SEP2] = p.radius**2, p.align_radius**2, p.min_separation**2
        c[VAIR2], c[WORLD] = p.vair**2, p.world
        c[CAP], c[SEP_CAP] = math.radians(p.max_turn_deg), math.radians(p.separation_turn_deg)
        w = p.weights
        c[W_A], c[W_C], c[W_AV], c[W_CV] = w.align, w.cohesion, w.va_align, w.va_cohesion
        c[VA_HEADING] = math.radians(p.va_heading_deg) % TWO_PI
        c[FAIL], c[NOISE] = p.fail_prob, math.radians(p.noise_deg)
        c[VA_SPEED], c[OUT_SPEED], c[JITTER], c[RAMP_TIME] = p.va_speed, p.out_speed, p.ramp_jitter, p.ramp_time
        c[BETA] = math.radians(p.beta_lim_deg)
        c[CAP_BEYOND], c[SEP_CAP_BEYOND] = (math.cos(min(cap + TURN_MARGIN, math.pi)) for cap in (c[CAP], c[SEP_CAP]))
        return c

    def va_position(self, step: int | None = None) -> np.ndarray:
        """Position of the virtual agent at `step` (default: now), float64."""
        return ref.va_position(self.step_index if step is None else step, self.params)

    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state (agent-ordered arrays as :meth:`state` returns them). Without ``speed`` and the ramp
        arrays, speeds are the settled ones (|va| inside the VAIR, |vout| outside); without ``tau``, tau is `step`
        if the desired formation holds now, else not reached."""
        p, real = self.params, self.engine.real
        x = np.asarray(state["x"], dtype=np.float64)
        n = p.n
        if "speed" in state:
            speed = np.asarray(state["speed"], dtype=np.float64)
            inside = np.asarray(state["inside"])
            ramp = (state["ramp_from"], state["ramp_duration"], state["ramp_start"])
        else:
            inside = ((ref.to_va(x, step, p) ** 2).sum(axis=1) <= p.vair**2).astype(np.int32)
            speed = np.where(inside == 1, p.va_speed, p.out_speed)
            ramp = (speed, np.ones(n), np.full(n, step))
        k = self.cur
        self.pos[k].from_numpy(np.ascontiguousarray(x.T, dtype=real))
        floats = np.stack([np.asarray(state["theta"], dtype=np.float64), speed, ramp[0], ramp[1]])
        floats = np.ascontiguousarray(floats, dtype=real)
        self.f[k].from_numpy(floats)
        cos_sin(n, floats[THETA], self.trig)  # the headings' cos and sin, as the step keeps them
        self.i[k].from_numpy(np.stack([inside, ramp[2]]).astype(np.int32))
        self.ids[k].from_numpy(np.arange(n, dtype=np.int32))
        self.rule.from_numpy(np.where(inside == 1, INSIDE, OUTSIDE).astype(np.int32))
        self.step_index = step
        if "tau" in state:
            self.tau.from_numpy(np.array([int(state["tau"])], dtype=np.int32))
        else:
            va = self.va_position(step)
            _tau_now(step, n, self.consts, va[0], va[1], self.pos[k], self.f[k], self.bad, self.tau)

    def state(self) -> dict[str, np.ndarray]:
        """Agent-ordered snapshot: x, theta, speed, inside, ramp_from, ramp_start, ramp_duration, tau (-1: not
        reached) and va (the VA position)."""
        k = self.cur
        ids = self.ids[k].to_numpy()
        n = self.params.n
        x = np.empty((n, 2), dtype=self.engine.real)
        x[ids] = self.pos[k].to_numpy().T
        f = np.empty((4, n), dtype=self.engine.real)
        f[:, ids] = self.f[k].to_numpy()
        i = np.empty((2, n), dtype=np.int32)
        i[:, ids] = self.i[k].to_numpy()
        return {"x": x, "theta": f[THETA], "speed": f[SPEED], "inside": i[IN_FLAG], "ramp_from": f[RAMP_FROM],
                "ramp_start": i[RAMP_START], "ramp_duration": f[RAMP_DURATION],
                "tau": np.array(int(self.tau.to_numpy()[0])), "va": self.va_position()}

    def first_non_finite(self) -> tuple[int, str] | None:
        """The guard over the current buffers: positions, headings and speeds (not the ramp bookkeeping)."""
        k = self.cur
        guarded = [Guarded("position", self.pos[k]), Guarded("heading", self.f[k], (THETA, THETA + 1)),
                   Guarded("velocity", self.f[k], (SPEED, SPEED + 1))]
        return first_non_finite(guarded, self.ids[k])

    def rules(self) -> np.ndarray:
        """What drove each agent (agent order) at the last step: SEPARATION, INSIDE, OUTSIDE or FAILED."""
        rules = np.empty(self.params.n, dtype=np.int32)
        rules[self.ids[self.cur].to_numpy()] = self.rule.to_numpy()
        return rules

    def tau_reached(self) -> int | None:
        """The first step of the desired formation (uncapped), or None if not reached yet."""
        tau = int(host_array(self.tau)[0])
        return None if tau < 0 else tau

    def build_neighbours(self) -> None:
        """Rebuild the neighbour grid for the current positions (benchmarks time it apart from the step)."""
        self.grid.build(self.pos[self.cur], self.ids[self.cur])

    def advance(self, steps: int) -> None:
        """Run `steps` steps: on the CPU with at most :data:`SERIAL_MAX_N` agents in launches of up to
        :data:`SERIAL_RUN` steps (:func:`_serial_steps`), else one step (a grid build and a step launch) at a
        time."""
        if self.lane_wise and self.params.n <= SERIAL_MAX_N:
            while steps > 0:
                run = min(steps, SERIAL_RUN)
                self._serial_steps(run)
                steps -= run
        else:
            for _ in range(steps):
                self._one_step()

    def _serial_steps(self, steps: int) -> None:
        """`steps` steps in one launch of :func:`_serial_steps`."""
        p, grid, t0 = self.params, self.grid, self.step_index
        va = scratch((SERIAL_RUN + 1, 2), self.pos[0].dtype)  # written on its host memory (this path is the CPU's)
        host_view(va)[: steps + 1] = ref.va_position(np.arange(t0, t0 + steps + 1)[:, None], p)
        tiling, last = grid.fallback, scratch((1,), ti.i32)
        k = self.cur
        _serial_steps(steps, t0, self.seed, p.n, self.consts, self._out_set, self._in_set, self._zones, va, p.world,
                      grid.radius, grid.max_window_side, tiling.cells_per_side, tiling.cell_size, grid.coords,
                      grid.bucket, grid.counts, grid.start, grid.order, grid.slot_of, grid.pos_sorted,
                      grid.coords_sorted, grid.id_sorted, grid.mixed, grid.block_start, grid.bounds, grid.anchor,
                      grid.rank_sort, grid.run_buffer(), self.payload, self.trig, self.pos[k], self.f[k], self.i[k],
                      self.ids[k], self.pos[1 - k], self.f[1 - k], self.i[1 - k], self.ids[1 - k], self.rule,
                      self.bad, self.tau, last)
        grid.count_bounded_builds(steps, int(host_array(last)[0]), fallback=True)
        self.step_index = t0 + steps

    def _one_step(self) -> None:
        """One step: the grid of the current state built on the host's layout, then :func:`_step`."""
        p = self.params
        t = self.step_index
        a, b = self.cur, 1 - self.cur
        self.grid.build(self.pos[a], self.ids[a])
        g = self.grid.geometry  # a bounded grid's layout is the build's
        va, va_next = self.va_position(t), self.va_position(t + 1)
        _step(t, self.seed, p.n, self.consts, self._out_set, self._in_set, self._zones,
              va[0], va[1], va_next[0], va_next[1], g.cells_per_side, g.n_buckets, g.cell_size, g.boundary,
              self.lane_wise, self.lane_wise and sparse_cells(g.cell_size, p), self.grid.start,
              self.grid.runs() if self.lane_wise else self.grid.start,
              self.grid.bounds, self.grid.anchor, self.grid.order,
              self.grid.id_sorted, self.grid.pos_sorted, self.grid.coords_sorted, self.payload, self.trig,
              self.f[a], self.i[a], self.pos[b], self.f[b], self.i[b], self.ids[b], self.rule, self.bad, self.tau)
        self.cur = b
        self.step_index += 1

    def metrics(self) -> dict[str, float]:
        p = self.params
        n = p.n
        k = self.cur
        va = self.va_position()
        _quantifier_blocks(n, self.consts, va[0], va[1], self.pos[k], self.f[k], self.rule, self.partial)
        s = host_array(self.partial).astype(np.float64).sum(axis=0)
        tau = self.tau_reached()
        return {
            "tau": float(p.tau_cap if tau is None else min(tau, p.tau_cap)),
            "df": float(s[7] == 0),
            "phi": float(math.hypot(s[0], s[1]) / n),
            "rho": float(s[2] / n),
            "inside": float(s[3] / n),
            "aligned": float(s[4] / n),
            "mean_speed": float(s[5] / n),
            "separating": float(s[6] / n),
        }

    def _rows(self, selected: np.ndarray) -> np.ndarray:
        """(m, 5) rows x, y, theta, rule, speed of the `selected` agents: :func:`_frame_rows`, or for a small swarm
        on the CPU the same copies in NumPy on the arrays' host memory (a launch costs more than such a pass)."""
        k, n, m = self.cur, self.params.n, len(selected)
        x = small_host_view(self.pos[k], n)
        if x is not None:
            where = host_view(self.where)
            where[host_view(self.ids[k])[:n]] = np.arange(n, dtype=where.dtype)  # as the kernel leaves it
            e = where[np.asarray(selected, dtype=np.int64)]
            f = host_view(self.f[k])
            rows = np.empty((m, 5), dtype=x.dtype)
            rows[:, 0], rows[:, 1], rows[:, 2] = x[0, e], x[1, e], f[THETA, e]
            rows[:, 3], rows[:, 4] = host_view(self.rule)[e], f[SPEED, e]
            return rows
        ids = scratch((max(1, m),), ti.i32)  # made once (making an ndarray costs about a millisecond)
        out = scratch((max(1, m), 5), self.pos[k].dtype)
        if m:
            ids.from_numpy(np.asarray(selected, dtype=np.int32))
            _frame_rows(m, n, ids, self.ids[k], self.where, self.pos[k], self.f[k], self.rule, out)
        return host_array(out)[:m].copy()

    def frame(self, selected: np.ndarray, max_edges: int, field_size: int = 0) -> Frame:
        """Agents coloured by what drives them this step (red: separation, green: inside the VAIR, blue: outside,
        grey: communication failure) with arrows of their velocity / |vout|, edges within the vision radius; the VA
        with its heading and VAIR circle. The torus is drawn centred on the VA (:meth:`world`): each position x as
        wrap(x - a(t) + world / 2), so the agents around the VA are never cut apart by the box's edge."""
        p = self.params
        rows = self._rows(selected)
        relative = rows[:, 4] / p.out_speed
        directions = (np.stack([np.cos(rows[:, 2]), np.sin(rows[:, 2])], axis=1) * relative[:, None]).astype(np.float32)
        va_heading = ref.va_direction(p).astype(np.float32)
        corner = self.va_position() - p.world / 2  # the point drawn at the box's corner
        # (wrapped again in float32: a float64 value just below the world's side may round up to it)
        drawn = np.mod(np.mod(rows[:, :2].astype(np.float64) - corner, p.world).astype(np.float32),
                       np.float32(p.world))
        marker = Marker("virtual_agent", np.full(2, p.world / 2, np.float32), va_heading * p.va_speed / p.out_speed,
                        circle=p.vair, color=VA_COLOR)
        k = self.cur
        return Frame(
            positions=drawn,
            directions=directions,
            arrow_length=arrow_length(p.world, len(selected)),
            colors=RULE_COLORS[rows[:, 3].astype(np.int64)],
            edges=self._edges_among(drawn, max_edges, p.radius),
            markers=[marker],
            ids=selected,
            fields=self._field_images(field_size, self.pos[k], self.trig, UNIT_VECTORS, rolled=corner),
        )

    def world(self) -> WorldSpec:
        """The torus, drawn centred on the virtual agent (:meth:`frame`)."""
        return WorldSpec(dim=2, boundary="periodic", box=self.params.world, dt=self.dt,
                         centred_on="the virtual agent")
