"""The virtual-agent formation model (papers/004): kernel against the NumPy oracle, forces, ramps, quantifiers.

Oracle horizons: one step at a time from the oracle's state (the kernel is reset before every step) for 40 steps
of every Table 1 strategy with communication failure and noise on, tolerance 1e-10 at f64 (2e-4 at f32); and a
free-running 300-step trajectory at f64 within 1e-8 (forces are clamped, so rounding differences stay small).
"""

import math
from pathlib import Path

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH, PRECISION

from tflock.config import ConfigError, default_config_toml, load_config
from tflock.models.formation import CAP, CAP_BEYOND, TURN_MARGIN, Formation, capped_turn, sparse_cells, unit_force
from tflock.models.formation_params import FAILED, INSIDE, OUTSIDE, RAMP_STREAM, SEPARATION, STRATEGIES
from tflock.reference import formation as rf
from tflock.reference import wrap_pi
from tflock.rng import uniform_np

F64 = PRECISION == "f64"
TOL = 1e-10 if F64 else 2e-4
ATOL = 1e-9 if F64 else 2e-4  # hand-built setups: degrees, lengths, phi
ROOT = Path(__file__).resolve().parents[1]
DEG = math.radians(1.0)


def params(**extra):
    ov = {f"params.{k}": v for k, v in extra.items()}
    ov["engine.precision"] = PRECISION
    return load_config(model="formation", overrides=ov).params


def small(strategy, **extra):
    """60 agents in a 30 x 20 rectangle: neighbours, separations, VAIR crossings within a few dozen steps."""
    return params(strategy=strategy, n=60, init_length=30.0, init_width=20.0, **extra)


def gap(a, b, key, world):
    d = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
    if key == "theta":
        d = np.abs(wrap_pi(d))
    elif key == "x":
        d = np.minimum(d, world - d)
    return float(d.max())


FLOATS = ("x", "theta", "speed", "ramp_from", "ramp_duration")


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_step_matches_reference(engine, strategy):
    p = small(strategy, fail_prob=0.2, noise_deg=0.5)
    model = Formation(p, 3, engine)
    state = rf.initial_state(p, 3)
    kinds = set()
    for t in range(40):
        expected, rule = rf.formation_step(state, t, p, 3)
        model.set_state(state, t)
        model.advance(1)
        got = model.state()
        for key in FLOATS:
            assert gap(got[key], expected[key], key, p.world) < TOL, f"{key} differs at step {t}"
        for key in ("inside", "ramp_start"):
            assert np.array_equal(got[key], expected[key]), f"{key} differs at step {t}"
        assert np.array_equal(model.rules(), rule), f"rules differ at step {t}"
        kinds |= set(rule.tolist())
        state = expected
    assert kinds == {SEPARATION, INSIDE, OUTSIDE, FAILED}  # every branch was exercised
    q = rf.quantifiers(state, 40, p)
    m = model.metrics()
    for key, value in q.items():
        assert m[key] == pytest.approx(value, abs=1e-9 if F64 else 1e-4), key


@pytest.mark.skipif(not F64, reason="free-running trajectories are compared at f64")
def test_trajectory_matches_reference(engine):
    p = small("S-2.4", noise_deg=0.3, fail_prob=0.1)
    model = Formation(p, 11, engine)
    state = rf.initial_state(p, 11)
    model.advance(300)
    for t in range(300):
        state, _ = rf.formation_step(state, t, p, 11)
    got = model.state()
    for key in FLOATS:
        assert gap(got[key], state[key], key, p.world) < 1e-8, key
    assert np.array_equal(got["inside"], state["inside"])


# ---------------------------------------------------------------------------------------------------------------
# Forces on hand-built two-agent setups (noise 0, no failure). The VA starts at (100, 100), heading 180 degrees.


def two_agents(engine, strategy, x, theta_deg, **extra):
    """A two-agent model set to positions x (relative to the VA) and headings; returns the turns (degrees) of one
    step and the rules."""
    p = params(strategy=strategy, n=2, **extra)
    model = Formation(p, 0, engine)
    x = np.asarray(x, dtype=np.float64) + rf.va_position(0, p)
    theta = np.radians(np.asarray(theta_deg, dtype=np.float64))
    model.set_state({"x": x, "theta": theta}, 0)
    model.advance(1)
    turn = np.degrees(wrap_pi(model.state()["theta"].astype(np.float64) - theta))
    return turn, model.rules()


def test_va_alignment_alone(engine):
    # S-1.1 inside the VAIR: Fav only. Far apart agents (no neighbours) turn toward 180 degrees, at most 1 degree
    turn, rules = two_agents(engine, "S-1.1", [[5.0, 0.0], [-5.0, 10.0]], [90.0, 179.5])
    assert turn == pytest.approx([1.0, 0.5], abs=ATOL)  # the paper's example: 159.5 -> 160 is a 0.5 turn
    assert list(rules) == [INSIDE, INSIDE]


def test_va_cohesion_alone(engine):
    # S-1.2 outside the VAIR: Fcv only. An agent 40 to the right of the VA heading up turns left toward it (+1);
    # one 40 above heading 0 turns right toward it (-1)
    turn, rules = two_agents(engine, "S-1.2", [[40.0, 0.0], [0.0, 40.0]], [90.0, 0.0])
    assert turn == pytest.approx([1.0, -1.0], abs=ATOL)
    assert list(rules) == [OUTSIDE, OUTSIDE]


def test_alignment_alone(engine):
    # S-1.1 outside with alpha_cv = 0: Fa only; two agents 4 apart (> min separation) head toward each other's
    # heading
    turn, _ = two_agents(engine, "S-1.1", [[60.0, 0.0], [60.0, 4.0]], [0.0, 30.0], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([1.0, -1.0], abs=ATOL)
    turn, _ = two_agents(engine, "S-1.1", [[60.0, 0.0], [60.0, 4.0]], [0.0, 0.4], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([0.4, -0.4], abs=ATOL)


def test_cohesion_alone_and_zones(engine):
    # S-1.3 outside with alpha_cv = 0: Fc only; agents 4 apart on a horizontal line, heading up, turn toward each
    # other: the left one right (-1), the right one left (+1)
    turn, _ = two_agents(engine, "S-1.3", [[60.0, 0.0], [64.0, 0.0]], [90.0, 90.0], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([-1.0, 1.0], abs=ATOL)
    # S-2.3: 4.5 apart lies in the cohesion ring [4, 5.5]: the same turns
    turn, _ = two_agents(engine, "S-2.3", [[60.0, 0.0], [64.5, 0.0]], [90.0, 90.0], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([-1.0, 1.0], abs=ATOL)
    # S-2.3: 3 apart lies in the alignment ring, where cohesion does not act: no force at all
    turn, _ = two_agents(engine, "S-2.3", [[60.0, 0.0], [63.0, 0.0]], [90.0, 90.0], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([0.0, 0.0], abs=ATOL)
    # S-2.1 outside with alpha_cv = 0: Fa only, and a neighbour in the cohesion ring is not aligned with
    turn, _ = two_agents(engine, "S-2.1", [[60.0, 0.0], [64.5, 0.0]], [0.0, 30.0], **{"weights.va_cohesion": 0.0})
    assert turn == pytest.approx([0.0, 0.0], abs=ATOL)


def test_weighted_mean(engine):
    # eq. (3), S-1.1 outside: Fa asks +1 (toward 30 degrees), Fcv asks -1 (toward the VA, behind on the left):
    # F = (3 * 1 - 1 * 1) / 4 = 0.5 with alpha_a = 3, alpha_cv = 1
    turn, _ = two_agents(engine, "S-1.1", [[60.0, 0.0], [60.0, 4.0]], [270.0, 300.0],
                         **{"weights.align": 3.0, "weights.va_cohesion": 1.0})
    assert turn[0] == pytest.approx(0.5, abs=ATOL)


def test_separation_overrides(engine):
    # 1.5 apart (< 2.5): each turns away from the other by 2 degrees, whatever the other forces ask (S-1.4 outside:
    # all four active, and for agent 0 every one of them asks -1 degree)
    turn, rules = two_agents(engine, "S-1.4", [[60.0, 0.0], [58.5, 0.0]], [270.0, 200.0])
    assert turn == pytest.approx([2.0, -2.0], abs=ATOL)
    assert list(rules) == [SEPARATION, SEPARATION]
    # inside the VAIR too, and with a smaller cap
    turn, _ = two_agents(engine, "S-2.2", [[5.0, 0.0], [6.0, 0.0]], [170.0, 10.0], separation_turn_deg=0.5)
    assert turn == pytest.approx([0.5, -0.5], abs=ATOL)


def test_turns_never_exceed_caps(engine):
    p = params(strategy="S-1.4", n=200, init_length=40.0, init_width=30.0, max_turn_deg=1.5,
               separation_turn_deg=3.0)
    model = Formation(p, 5, engine)
    seen = set()
    for _ in range(30):
        before = model.state()["theta"].astype(np.float64)
        model.advance(1)
        turn = np.abs(wrap_pi(model.state()["theta"].astype(np.float64) - before))
        rules = model.rules()
        seen |= set(rules.tolist())
        assert turn[rules == SEPARATION].max(initial=0) <= math.radians(3.0) + ATOL
        assert turn[rules != SEPARATION].max(initial=0) <= math.radians(1.5) + ATOL
    assert {SEPARATION, INSIDE, OUTSIDE} <= seen


@ti.kernel
def _turns(v: ti.types.ndarray(), theta: ti.types.ndarray(), cap: float, cos_beyond: float,
           out: ti.types.ndarray()):
    for i in range(theta.shape[0]):
        th = theta[i]
        w = ti.Vector([v[0, i], v[1, i]])
        out[0, i] = capped_turn(w, th, ti.Vector([ti.cos(th), ti.sin(th)]), cap, cos_beyond)
        out[1, i] = unit_force(ti.atan2(w[1], w[0]), th, cap)


@pytest.mark.parametrize("cap_deg", [1e-4, 1.0, 2.0, 30.0, 179.9, 180.0])
def test_capped_turn_is_the_clamped_atan2_bit_for_bit(engine, cap_deg):
    """The turn without atan2 where the cap decides it gives the formula's bits: random directions and lengths,
    targets just inside and outside the cap and the margin, straight ahead and behind, v = 0."""
    rng = np.random.default_rng(3)
    n = 20000
    theta = rng.uniform(0, 2 * math.pi, n)
    cap = math.radians(cap_deg)
    offsets = np.concatenate([rng.uniform(-math.pi, math.pi, n // 2),
                              np.repeat([0.0, math.pi, -math.pi, cap, -cap, cap + TURN_MARGIN, -cap - TURN_MARGIN,
                                         math.pi - TURN_MARGIN, cap * (1 + 1e-9), cap * (1 - 1e-9)], n // 20)])
    length = 10.0 ** rng.uniform(-6, 4, n)
    v = length * np.stack([np.cos(theta + offsets), np.sin(theta + offsets)])
    v[:, :10] = 0.0
    v[:, 10:20] = np.array([[-1.0, 1.0, 0.0, 0.0, -2.0, 3.0, -0.5, 0.5, -1e-30, 1e30]] * 2)
    theta[10:20] = [0.0, math.pi, math.pi / 2, 3 * math.pi / 2, 0.0, math.pi, 0.0, math.pi, 0.0, math.pi]
    real = engine.real
    out = ti.ndarray(ti.f32 if real == np.float32 else ti.f64, (2, n))
    c = Formation(params(max_turn_deg=cap_deg), 0, engine)._constants()
    _turns(v.astype(real), theta.astype(real), c[CAP], c[CAP_BEYOND], out)
    fast, formula = out.to_numpy()
    assert np.array_equal(fast, formula)
    if cap_deg <= 30:  # most turns decided by the cap: the path without atan2 ran
        assert np.mean(np.abs(formula) == real(cap)) > 0.3


def test_full_failure_goes_straight(engine):
    p = params(strategy="S-1.4", n=100, init_length=30.0, init_width=20.0, fail_prob=1.0)
    model = Formation(p, 2, engine)
    start = model.state()
    model.advance(50)
    end = model.state()
    assert np.array_equal(end["theta"], start["theta"])
    assert np.all(model.rules() == FAILED)


def test_noise_is_bounded_and_used(engine):
    p = params(strategy="S-2.2", n=100, init_length=30.0, init_width=20.0, fail_prob=1.0, noise_deg=0.7)
    model = Formation(p, 2, engine)
    before = model.state()["theta"].astype(np.float64)
    model.advance(1)
    turn = np.degrees(wrap_pi(model.state()["theta"].astype(np.float64) - before))
    assert np.abs(turn).max() <= 0.7 + ATOL
    assert np.abs(turn).max() > 0.5 and turn.min() < 0 < turn.max()  # eps ~ U[-delta, delta]


# ---------------------------------------------------------------------------------------------------------------
# Speed ramps (eqs. 1-2)


def test_speed_ramps_stay_in_range(engine):
    p = params()  # the paper's setup, S-2.2
    model = Formation(p, 1, engine)
    ramping = 0
    for _ in range(400):
        model.advance(1)
        speed = model.state()["speed"].astype(np.float64)
        assert speed.min() >= p.va_speed - ATOL and speed.max() <= p.out_speed + ATOL
        ramping += int(np.sum((speed > p.va_speed) & (speed < p.out_speed)))
    assert ramping > 0  # agents entered the VAIR and slowed down gradually


def test_entering_ramp_is_linear(engine):
    # one agent about to enter the VAIR from behind, heading with the VA: its speed falls linearly from 1.4 to 1
    p = params(strategy="S-1.1", n=1, ramp_jitter=0.0)
    model = Formation(p, 0, engine)
    x = rf.va_position(0, p) + [25.2, 0.0]
    model.set_state({"x": x[None, :], "theta": np.array([math.pi])}, 0)
    speeds = []
    for _ in range(140):
        model.advance(1)
        speeds.append(float(model.state()["speed"][0]))
    state = model.state()
    start = int(state["ramp_start"][0])
    duration = 2 * p.vair / (p.out_speed - p.va_speed)  # T with rnd = 0: the VAIR at half the closing speed
    assert state["ramp_duration"][0] == pytest.approx(duration)
    for t, v in enumerate(speeds):
        expected = p.out_speed - (p.out_speed - p.va_speed) * min(1.0, max(0.0, (t + 1 - start) / duration))
        assert v == pytest.approx(expected, abs=ATOL)
    assert speeds[-1] == p.va_speed


def ramp_gain(duration, closing):
    """Depth a ramp of `duration` gains on the VA, in whole steps: the speed for the move t_s + k - 1 -> t_s + k is
    |va| + closing (1 - min(1, k / duration)), so the gain is closing (K - K (K + 1) / (2 duration)), K = floor."""
    k = math.floor(duration)
    return closing * (k - k * (k + 1) / (2 * duration))


def test_ramp_time_stops_a_lone_agent_anywhere_on_the_vair_diameter():
    # the closed form behind T = 2 VAIR / (|vout| - |va|): an agent that enters from straight behind at the
    # boundary and ramps for T stops at the VA; with gamma = T the ramp lasts U(0, 2T) and the stopping point
    # covers the VAIR's diameter, behind the VA and in front of it, uniformly (eqs. 1-2, "a homogeneous
    # distribution of agents inside the VAIR")
    p = params()
    closing = p.out_speed - p.va_speed
    assert p.ramp_time == pytest.approx(125.0)
    assert ramp_gain(p.ramp_time, closing) == pytest.approx(p.vair, abs=closing)  # reaches the VA, to half a step
    durations = np.linspace(1.0, 2 * p.ramp_time, 2001)[1:-1]  # uniform in (0, 2T); max(1, .) is the floor
    rest = p.vair - np.array([ramp_gain(d, closing) for d in durations])  # distance behind the VA at rest
    assert rest.max() == pytest.approx(p.vair, abs=0.5) and rest.min() == pytest.approx(-p.vair, abs=0.5)
    assert np.mean(rest < 0) == pytest.approx(0.5, abs=0.01)  # as often in front of the VA as behind
    assert np.histogram(rest, bins=5, range=(-p.vair, p.vair))[0].min() > 0.18 * len(rest)  # spread evenly


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_lone_agent_comes_to_rest_where_the_ramp_closed_form_says(engine, seed):
    # one agent straight behind the VA, heading with it, no neighbour: no force turns it (Fcv and Fav point along
    # its heading), so it closes on the VA at |vout| - |va| until it crosses the VAIR, then eq. (1) slows it over
    # dt = max(1, T + rnd) with rnd ~ U(-T, T) drawn at the crossing step; afterwards it keeps its place. Its
    # offset from the VA at rest is the entry distance less the ramp's gain, in the kernel and the reference
    # (seeds 0, 3, 4 draw short ramps and stop behind the VA; 1, 2, 5 long ones and stop in front of it)
    p = params(n=1, va_heading_deg=0.0)  # heading 0: the VA's path and the agent's stay on one grid row
    closing = p.out_speed - p.va_speed
    start = {"x": (rf.va_position(0, p) - [p.vair + 0.3, 0.0])[None, :], "theta": np.zeros(1)}
    entry = 1  # 25.3 bl behind at step 0, 24.9 at step 1: inside from step 1
    u = float(uniform_np(seed, entry, np.zeros(1, dtype=np.int64), RAMP_STREAM)[0])
    duration = max(1.0, p.ramp_time * (1 + p.ramp_jitter * (2 * u - 1)))
    behind = p.vair + 0.3 - closing * entry - ramp_gain(duration, closing)  # > 0 behind the VA, < 0 in front
    steps = int(duration) + 5
    model = Formation(p, seed, engine)
    model.set_state(start, 0)  # outside the VAIR: settled at |vout|
    model.advance(steps)
    state = {**start, "speed": np.full(1, p.out_speed), "inside": np.zeros(1, dtype=np.int32),
             "ramp_from": np.full(1, p.out_speed), "ramp_start": np.zeros(1, dtype=np.int32),
             "ramp_duration": np.ones(1)}
    for t in range(steps):
        state, _ = rf.formation_step(state, t, p, seed)
    for got, tol in ((model.state(), 1e-9 if F64 else 5e-3), (state, 1e-9)):
        assert int(got["ramp_start"][0]) == entry and got["ramp_duration"][0] == pytest.approx(duration, rel=1e-6)
        offset = rf.to_va(np.asarray(got["x"], dtype=np.float64), steps, p)[0]  # agent -> VA
        assert offset[0] == pytest.approx(behind, abs=tol) and abs(offset[1]) < tol
        assert float(got["speed"][0]) == pytest.approx(p.va_speed)


# ---------------------------------------------------------------------------------------------------------------
# Quantifiers


def quantifiers_of(engine, x_rel, theta, step=0, **extra):
    p = params(n=len(x_rel), **extra)
    model = Formation(p, 0, engine)
    x = np.asarray(x_rel, dtype=np.float64) + rf.va_position(step, p)
    x -= p.world * np.floor(x / p.world)
    model.set_state({"x": x, "theta": np.asarray(theta, dtype=np.float64)}, step)
    return model.metrics(), model


def test_phi_rho_ring_and_line(engine):
    a = 2 * math.pi * np.arange(12) / 12
    ring = 10.0 * np.stack([np.cos(a), np.sin(a)], axis=1)
    m, _ = quantifiers_of(engine, ring, np.full(12, math.pi))
    assert m["phi"] == pytest.approx(0.0, abs=ATOL)
    assert m["rho"] == pytest.approx(10.0, abs=ATOL)
    line = np.stack([np.arange(1, 13) * 2.0, np.zeros(12)], axis=1)  # in a row behind the VA
    m, _ = quantifiers_of(engine, line, np.full(12, math.pi))
    assert m["phi"] == pytest.approx(1.0, abs=ATOL)
    assert m["rho"] == pytest.approx(13.0, abs=ATOL)
    # the ring across the torus edge (VA at x = 5 after 95 steps): minimum-image distances
    m, _ = quantifiers_of(engine, ring, np.full(12, math.pi), step=95)
    assert m["phi"] == pytest.approx(0.0, abs=ATOL) and m["rho"] == pytest.approx(10.0, abs=ATOL)
    half = ring[:6]  # angles 0..150 degrees: |mean exp(i Theta)| = |sum| / 6
    m, _ = quantifiers_of(engine, half, np.full(6, math.pi))
    assert m["phi"] == pytest.approx(abs(np.exp(1j * a[:6]).mean()), abs=ATOL)


def test_desired_formation_and_tau(engine):
    a = 2 * math.pi * np.arange(12) / 12
    ring = 10.0 * np.stack([np.cos(a), np.sin(a)], axis=1)
    theta = np.full(12, math.pi) + np.radians(np.linspace(-4.9, 4.9, 12))
    m, model = quantifiers_of(engine, ring, theta, step=7)
    assert m["df"] == 1.0 and m["tau"] == 7.0  # DF holds when set: tau is that step
    theta[3] = math.pi + math.radians(5.1)  # one agent out of beta_lim
    m, model = quantifiers_of(engine, ring, theta, step=7, tau_cap=50)
    assert m["df"] == 0.0 and m["tau"] == 50.0  # not reached: the cap
    outside = ring.copy()
    outside[0] = [30.0, 0.0]  # one agent out of the VAIR
    m, _ = quantifiers_of(engine, outside, np.full(12, math.pi))
    assert m["df"] == 0.0 and m["inside"] == pytest.approx(11 / 12)


def test_paper_setup_reaches_desired_formation(engine):
    p = params()  # S-2.2 with Figure 4a's weights
    model = Formation(p, 0, engine)
    for _ in range(30):
        model.advance(50)
        if model.tau_reached() is not None:
            break
    tau = model.tau_reached()
    assert tau is not None and 200 < tau < 1500
    m = model.metrics()
    assert m["tau"] == tau and m["inside"] == 1.0 and m["aligned"] == 1.0 and m["mean_speed"] == pytest.approx(1.0)
    model.advance(20)  # the formation holds: aligned agents at |va| inside the VAIR
    assert model.metrics()["df"] == 1.0 and model.metrics()["tau"] == tau


# ---------------------------------------------------------------------------------------------------------------
# Configs, drawing, determinism


def test_default_config_file_is_current():
    assert (ROOT / "configs" / "formation.toml").read_text() == default_config_toml("formation")


def test_paper_configs_load():
    names = sorted((ROOT / "configs" / "papers").glob("formation-*.toml"))
    strategies = {load_config(path).params.strategy for path in names}
    assert strategies == set(STRATEGIES)


@pytest.mark.parametrize("override, key", [
    ({"params.world": 150.0}, "params.world"),
    ({"params.min_separation": 6.0}, "params.min_separation"),
    ({"params.align_radius": 2.0}, "params.align_radius"),
    ({"params.out_speed": 0.5}, "params.out_speed"),
    ({"params.strategy": "S-3.1"}, "params.strategy"),
])
def test_bad_params_are_clear_errors(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config(model="formation", overrides=override)


@pytest.mark.skipif(ARCH != "cpu", reason="host views of ndarrays are the CPU's")
def test_small_swarm_frame_rows_without_a_launch(engine, monkeypatch):
    """A small swarm's frame rows come from NumPy on the arrays' host memory (CPU): the same frame, and the same
    `where` scratch (checkpoints keep it), as the kernel's (SMALL_SWARM_MAX = 0)."""
    import tflock.taichi_host as taichi_host

    p = small("S-2.2", fail_prob=0.2)
    host, kernel = Formation(p, 4, engine), Formation(p, 4, engine)
    selected = np.array([0, 3, 7, 8, 21, 59])
    for model in (host, kernel):
        model.advance(9)
    a = host.frame(selected, 100)
    with monkeypatch.context() as m:
        m.setattr(taichi_host, "SMALL_SWARM_MAX", 0)
        b = kernel.frame(selected, 100)
    for name in ("positions", "directions", "colors", "ids", "edges"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(host.where.to_numpy(), kernel.where.to_numpy())


def test_frame_draws_va_and_rules(engine):
    p = params(n=50, init_length=30.0, init_width=20.0)
    model = Formation(p, 0, engine)
    model.advance(3)
    selected = np.array([0, 7, 19, 42])
    frame = model.frame(selected, 100)
    state = model.state()
    # the torus drawn centred on the VA: x at wrap(x - a(t) + world / 2)
    corner = rf.va_position(3, p) - p.world / 2
    assert np.allclose(frame.positions, np.mod(state["x"][selected] - corner, p.world), atol=1e-4)
    assert model.world().centred_on == "the virtual agent"
    # arrows: the velocity of the step just made over |vout| (tflock.frame's convention)
    relative = state["speed"][selected] / p.out_speed
    assert np.allclose(frame.directions[:, 0], np.cos(state["theta"][selected]) * relative, atol=1e-5)
    assert np.allclose(frame.directions[:, 1], np.sin(state["theta"][selected]) * relative, atol=1e-5)
    assert frame.ids.tolist() == selected.tolist()
    (marker,) = frame.markers
    assert marker.name == "virtual_agent" and marker.circle == p.vair
    assert np.allclose(marker.position, [p.world / 2] * 2)
    from tflock.models.formation import RULE_COLORS
    assert np.array_equal(frame.colors, RULE_COLORS[model.rules()[selected]])


def test_frame_keeps_the_swarm_whole_across_the_torus_edge(engine):
    """Once the VA has reached the torus's edge (100 steps at |va| = 1 from the centre of a world of 200), the agents
    around it lie on both sides of the edge; drawn centred on the VA they are one group around the box's centre,
    at their true distances from the VA, and the field of all agents is binned where they are drawn."""
    p = params(n=60, init_length=30.0, init_width=20.0)
    model = Formation(p, 0, engine)
    model.advance(100)
    x = model.state()["x"]
    va = model.va_position()
    gap = x - va
    gap -= p.world * np.round(gap / p.world)
    near = np.linalg.norm(gap, axis=1) < p.world / 4
    assert near.sum() >= 10 and np.ptp(x[near, 0]) > p.world / 2  # cut apart by the edge where drawn as simulated
    frame = model.frame(np.arange(p.n), 100, field_size=8)
    assert np.ptp(frame.positions[near, 0]) < p.world / 2  # drawn whole
    assert ((frame.positions >= 0) & (frame.positions < p.world)).all()  # inside the drawn box
    np.testing.assert_allclose(frame.positions[near], p.world / 2 + gap[near], atol=1e-3)
    (image,) = frame.fields
    assert image.origin == (0.0, 0.0) and image.agents == p.n
    pixels = np.minimum((frame.positions / image.pixel).astype(int), 7)
    drawn = np.zeros((8, 8), int)
    np.add.at(drawn, (pixels[:, 1], pixels[:, 0]), 1)
    assert np.array_equal(image.classes > 0, drawn > 0)


def test_recording_and_state_round_trip(make_sim, tmp_path):
    from tflock.record import verify_recording

    path = tmp_path / "formation.rrd"
    sim = make_sim(model="formation", steps=5, record=path, params={"n": 30})
    sim.run()
    sim.close()
    assert verify_recording(path)
    table = sim.metrics()
    assert set(table) >= {"tau", "df", "phi", "rho"} and len(table["phi"]) == 6
    # a restored state continues the same trajectory
    state = sim.model.state()
    sim.model.advance(10)
    later = sim.model.state()
    sim.model.set_state(state, 5)
    sim.model.advance(10)
    assert np.array_equal(sim.model.state()["x"], later["x"])


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise step runs on the CPU only")
@pytest.mark.parametrize("strategy", ["S-1.2", "S-2.2"])
def test_lane_wise_step_equals_per_agent_step(engine, strategy):
    """The CPU's lane-wise step (runs of cells, 8 agents at a time) and the per-agent step (other arches) meet the
    same candidates in the same order and share the update: the same states and rules, in crowded cells, across
    the torus's edges (agents on both sides of them) and with exact ties for the nearest neighbour."""
    p = params(strategy=strategy, n=400, world=60.0, init_length=20.0, init_width=20.0, fail_prob=0.2, noise_deg=0.5)
    rng = np.random.default_rng(4)
    state = rf.initial_state(p, 3)
    x = rng.random((400, 2)) * 60.0
    x[:100] = 30.0 + rng.random((100, 2)) * 6.0  # crowded: cells of several lane blocks, separations
    x[100:140, 0] = rng.random(40) * 2.0 - 1.0  # astride the torus's edges
    x[140:180, 1] = rng.random(40) * 2.0 - 1.0
    x %= 60.0
    x[200] = x[201] + [1.0, 0.0]  # agent 201 has agents 200 and 202 equally near: the lower id wins
    x[202] = x[201] - [1.0, 0.0]
    state["x"] = x
    rules = _lane_wise_equals_per_agent(engine, p, state, sparse=False)
    assert (rules == SEPARATION).sum() >= 20


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise step runs on the CPU only")
@pytest.mark.parametrize("strategy", ["S-1.2", "S-2.2"])
def test_lane_wise_step_on_sparse_cells_equals_per_agent_step(engine, strategy):
    """Where the torus's tiling has cells over 3.3 R wide (400 agents in a 1200 x 1200 torus: cells of 30), the
    lane-wise scan skips the candidates beyond reach of every lane of a block; the same states and rules as the
    per-agent step, with agents scattered alone, in pairs within R, in a crowded clump and astride the edges."""
    from tflock.space import WINDOW

    p = params(strategy=strategy, n=400, world=1200.0, init_length=20.0, init_width=20.0, fail_prob=0.2,
               noise_deg=0.5)
    rng = np.random.default_rng(5)
    state = rf.initial_state(p, 3)
    x = rng.random((400, 2)) * 1200.0
    x[:60] = 600.0 + rng.random((60, 2)) * 5.0  # crowded: separations
    angle, radius = rng.random(50) * 2 * np.pi, 20.0 * np.sqrt(rng.random(50))
    x[61:161:2] = [595.0, 600.0] + radius[:, None] * np.c_[np.cos(angle), np.sin(angle)]  # inside the VAIR
    x[60:160:2] = x[61:161:2] + rng.normal(size=(50, 2)) * 2.5  # pairs: the alignment and cohesion zones in use
    x[160:200, 0] = rng.random(40) * 8.0 - 4.0  # astride the torus's edges
    x %= 1200.0
    state["x"] = x
    model = Formation(p, 3, engine)
    model.set_state(state, 5)
    model.build_neighbours()
    geometry = model.grid.geometry
    assert geometry.boundary != WINDOW and sparse_cells(geometry.cell_size, p)
    rules = _lane_wise_equals_per_agent(engine, p, state, sparse=True)
    assert (rules == SEPARATION).sum() >= 40 and (rules == INSIDE).sum() >= 10 and (rules == OUTSIDE).sum() >= 150


def _lane_wise_equals_per_agent(engine, p, state, sparse):
    """Three steps of the lane-wise and of the per-agent step from `state`: the same rules (returned) and the same
    states, bit for bit."""
    results = []
    for lane_wise in (True, False):
        model = Formation(p, 3, engine)
        model.lane_wise = lane_wise
        model.set_state(state, 5)
        model.build_neighbours()
        assert sparse_cells(model.grid.geometry.cell_size, p) == sparse
        model.advance(3)
        ti.sync()
        results.append((model.state(), model.rules()))
    (a, rule_a), (b, rule_b) = results
    assert np.array_equal(rule_a, rule_b)
    for key in FLOATS:
        assert gap(a[key], b[key], key, p.world) == 0, (key, gap(a[key], b[key], key, p.world))
    return rule_a


def test_window_grid_across_the_torus_edge(engine):
    """On the CPU the grid covers the window of cells the swarm occupies (the torus's own tiling of 60 x 60 has cells
    12 wide here). A crowded swarm astride the torus's corner, stepped one step at a time from the oracle's state:
    the window layout is used, and the lane-wise and per-agent steps both match the oracle."""
    from tflock.space import WINDOW

    p = params(strategy="S-2.2", n=300, world=60.0, init_length=20.0, init_width=20.0, fail_prob=0.1,
               noise_deg=0.5)
    rng = np.random.default_rng(7)
    state = rf.initial_state(p, 3)
    state["x"] = (rng.random((300, 2)) * 16.0 - 8.0) % 60.0
    for lane_wise in (True, False) if engine.arch == "cpu" else (False,):  # the lane-wise step is the CPU's
        model = Formation(p, 3, engine)
        model.lane_wise = lane_wise
        current = dict(state)
        for t in range(5):
            expected, rule = rf.formation_step(current, t, p, 3)
            model.set_state(current, t)
            model.advance(1)
            if engine.arch == "cpu":
                assert model.grid.geometry.boundary == WINDOW
            got = model.state()
            for key in FLOATS:
                assert gap(got[key], expected[key], key, p.world) < TOL, f"{key} differs at step {t}"
            assert np.array_equal(model.rules(), rule), f"rules differ at step {t}"
            assert (rule == SEPARATION).sum() >= 30
            current = expected
