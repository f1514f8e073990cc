"""NumPy oracle of the virtual-agent formation model (papers/004; DESIGN.md 3.4), plain O(N^2).

Written straight from the paper with every pair tested; see :mod:`tflock.models.formation` for the readings of the
ambiguous equations, which this module follows line for line. The state is a dict of agent-ordered arrays:
``x`` (n, 2), ``theta``, ``speed``, ``inside`` (int, 1 when the agent was inside the VAIR at its last speed
update), ``ramp_from`` (speed when the current ramp started), ``ramp_start`` (int step) and ``ramp_duration``.
"""

from __future__ import annotations

import math

import numpy as np

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
from tflock.reference import displacements, wrap_pi, wrap_two_pi
from tflock.rng import Stream, uniform_np


def va_direction(params: FormationParams) -> np.ndarray:
    a = math.radians(params.va_heading_deg)
    return np.array([math.cos(a), math.sin(a)])


def va_position(t: int | np.ndarray, params: FormationParams) -> np.ndarray:
    """VA position at step t (float64): from the torus centre, |va| per time unit along its heading, wrapped; for
    an (m, 1) array of steps, an (m, 2) array of positions (the same values)."""
    p = params.world / 2 + t * params.va_speed * va_direction(params)
    p = p - params.world * np.floor(p / params.world)
    return np.where((p >= params.world) | (p < 0), 0.0, p)


def initial_state(params: FormationParams, seed: int) -> dict[str, np.ndarray]:
    """Agents uniform in the init_length x init_width rectangle whose front side is centred on the VA (behind it),
    headings uniform in [0, 2 pi); settled speeds: |va| inside the VAIR, |vout| outside."""
    ids = np.arange(params.n)
    u = va_direction(params)
    across = np.array([-u[1], u[0]])
    back = params.init_length * uniform_np(seed, 0, ids, Stream.INIT_X)
    side = params.init_width * (uniform_np(seed, 0, ids, Stream.INIT_Y) - 0.5)
    x = va_position(0, params) - back[:, None] * u + side[:, None] * across
    x = x - params.world * np.floor(x / params.world)
    x = np.where((x >= params.world) | (x < 0), 0.0, x)
    theta = 2 * math.pi * uniform_np(seed, 0, ids, Stream.INIT_HEADING)
    inside = (to_va(x, 0, params) ** 2).sum(axis=1) <= params.vair**2
    speed = np.where(inside, params.va_speed, params.out_speed)
    return {"x": x, "theta": theta, "speed": speed, "inside": inside.astype(np.int32), "ramp_from": speed.copy(),
            "ramp_start": np.zeros(params.n, dtype=np.int32), "ramp_duration": np.ones(params.n)}


def to_va(x: np.ndarray, t: int, params: FormationParams) -> np.ndarray:
    """Minimum-image displacement from each agent to the VA, (n, 2)."""
    d = va_position(t, params).astype(x.dtype) - x
    return d - params.world * np.round(d / params.world)


def unit_force(target: np.ndarray, theta: np.ndarray, cap: float) -> np.ndarray:
    """The turn toward `target` that a force asks, at most `cap` either way (section 2: 'maximum value 1 degree')."""
    return np.clip(wrap_pi(target - theta), -cap, cap)


def formation_step(state: dict[str, np.ndarray], t: int, params: FormationParams, seed: int,
                   ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """One synchronous step t -> t+1; returns the new state and what drove each agent (SEPARATION, ...)."""
    x, theta = state["x"], state["theta"]
    n = len(theta)
    ids = np.arange(n)
    zones = int(params.strategy[2])  # 1: one vision radius, 2: rings
    out_set, in_set = TABLE_1[int(params.strategy[4])]
    d = displacements(x, "periodic", params.world)  # d[i, j] = x_j - x_i
    d2 = (d * d).sum(axis=2)
    np.fill_diagonal(d2, np.inf)
    seen = d2 <= params.radius**2
    if zones == 1:
        wa = wc = seen
    else:
        wa = seen & (d2 >= params.min_separation**2) & (d2 < params.align_radius**2)
        wc = seen & (d2 >= params.align_radius**2)
    nearest = np.argmin(d2, axis=1)  # the lowest id among equally near ones
    near_d2 = d2[ids, nearest]
    separate = near_d2 < params.min_separation**2

    dva = to_va(x, t, params)
    inside = (dva**2).sum(axis=1) <= params.vair**2
    cap = math.radians(params.max_turn_deg)
    w = params.weights
    active = np.where(inside, in_set, out_set)
    num = np.zeros(n)
    den = np.zeros(n)
    terms = [
        (ALIGN, w.align, wa.any(axis=1),
         np.arctan2((wa * np.sin(theta)[None, :]).sum(axis=1), (wa * np.cos(theta)[None, :]).sum(axis=1))),
        (COHESION, w.cohesion, wc.any(axis=1),
         np.arctan2((wc * d[:, :, 1]).sum(axis=1), (wc * d[:, :, 0]).sum(axis=1))),
        (VA_ALIGN, w.va_align, np.ones(n, dtype=bool), np.full(n, math.radians(params.va_heading_deg))),
        (VA_COHESION, w.va_cohesion, np.ones(n, dtype=bool), np.arctan2(dva[:, 1], dva[:, 0])),
    ]
    for bit, weight, available, target in terms:  # eq. (3) over the active forces
        use = ((active & bit) != 0) & available
        num += np.where(use, weight * unit_force(target, theta, cap), 0.0)
        den += np.where(use, weight, 0.0)
    force = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    away = -d[ids, nearest]
    sep = unit_force(np.arctan2(away[:, 1], away[:, 0]), theta, math.radians(params.separation_turn_deg))
    force = np.where(separate, sep, force)  # eq. (4)
    failed = uniform_np(seed, t, ids, Stream.UPDATE) < params.fail_prob
    force = np.where(failed, 0.0, force)
    eps = math.radians(params.noise_deg) * (2 * uniform_np(seed, t, ids, Stream.NOISE) - 1)
    new_theta = wrap_two_pi(theta + force + eps)  # eqs. (5), (7)

    rule = np.where(failed, FAILED, np.where(separate, SEPARATION, np.where(inside, INSIDE, OUTSIDE)))
    speed, ramp = speed_update(state, inside, t, params, seed)
    new_x = x + speed[:, None] * np.stack([np.cos(new_theta), np.sin(new_theta)], axis=1)
    new_x = new_x - params.world * np.floor(new_x / params.world)
    new_x = np.where((new_x >= params.world) | (new_x < 0), 0.0, new_x)
    return {"x": new_x, "theta": new_theta, "speed": speed, **ramp}, rule.astype(np.int32)


def speed_update(state: dict[str, np.ndarray], inside: np.ndarray, t: int, params: FormationParams, seed: int):
    """Speed for the move t -> t+1 by the ramps of eqs. (1)-(2), and the new ramp state.

    A crossing of the VAIR (inside now differs from the stored flag) starts a ramp from the current speed v_ini
    at t_s = t, lasting dt_i = max(1, T + rnd), T = ``params.ramp_time`` = 2 vair / (|vout| - |va|),
    rnd ~ U(-gamma, gamma), gamma = ramp_jitter T;
    the speed at step t+1 is v_ini + (target - v_ini) min(1, (t + 1 - t_s) / dt_i), target |va| inside and |vout|
    outside, and exactly the target once the ramp ends.
    """
    ids = np.arange(len(inside))
    crossed = inside != state["inside"].astype(bool)
    start_from = state["speed"]
    period = params.ramp_time
    jitter = params.ramp_jitter * period * (2 * uniform_np(seed, t, ids, RAMP_STREAM) - 1)
    v0 = np.where(crossed, start_from, state["ramp_from"])
    t0 = np.where(crossed, t, state["ramp_start"]).astype(np.int32)
    dur = np.where(crossed, np.maximum(1.0, period + jitter), state["ramp_duration"])
    target = np.where(inside, params.va_speed, params.out_speed)
    progress = (t + 1 - t0) / dur
    speed = np.where(progress >= 1, target, v0 + (target - v0) * np.minimum(progress, 1.0))
    return speed, {"inside": inside.astype(np.int32), "ramp_from": v0, "ramp_start": t0, "ramp_duration": dur}


def quantifiers(state: dict[str, np.ndarray], t: int, params: FormationParams) -> dict[str, float]:
    """phi (eq. 6 on the agents' angles around the VA), rho (mean distance to the VA) and the DF condition
    (Definition 1: all inside the VAIR, |theta_a - theta_i| < beta_lim, speed |va|)."""
    dva = -to_va(state["x"], t, params)  # VA -> agent
    angle = np.arctan2(dva[:, 1], dva[:, 0])
    dist = np.sqrt((dva**2).sum(axis=1))
    inside = (dva**2).sum(axis=1) <= params.vair**2
    aligned = np.abs(wrap_pi(math.radians(params.va_heading_deg) - state["theta"])) < math.radians(params.beta_lim_deg)
    settled = np.abs(state["speed"] - params.va_speed) <= 1e-6 * params.va_speed
    return {
        "phi": float(np.hypot(np.cos(angle).mean(), np.sin(angle).mean())),
        "rho": float(dist.mean()),
        "df": float(np.all(inside & aligned & settled)),
        "inside": float(inside.mean()),
        "aligned": float(aligned.mean()),
        "mean_speed": float(state["speed"].mean()),
    }
