"""Kernels against the NumPy reference, from the same state and the same random draws.

Two horizons (the dynamics are chaotic: rounding differences grow step by step):
- one step at a time from a shared state (the kernel is reset to the reference state before every step), for
  40 steps: isolates the step itself; tolerance 1e-10 at f64, 2e-4 rad / 2e-4 length at f32 (one f32 rounding of
  sums over tens of neighbours plus f32 trig);
- free-running trajectories (f64 only), 150 steps: the kernel and the oracle must stay within 1e-8 over a horizon
  long enough to cover many neighbourhood changes and, for reflecting boxes, many wall hits.
"""

import math

import numpy as np
import pytest
from conftest import PRECISION

from tflock import reference as ref
from tflock.config import load_config
from tflock.models.vicsek import Vicsek

F64 = PRECISION == "f64"
TOL = 1e-10 if F64 else 2e-4

RULES = ["vector", "average", "relative", "laplacian"]
BOUNDARIES = ["periodic", "reflecting", "open"]


def vicsek_config(rule, boundary, n=400, box=12.0, **extra):
    ov = {"params.n": n, "params.box": box, "params.radius": 1.0, "params.speed": 0.3, "params.noise": 0.6,
          "params.rule": rule, "params.boundary": boundary, "seed": 7, "engine.precision": PRECISION}
    if rule == "laplacian":
        ov["params.g"] = n + 1.5
    ov.update(extra)
    return load_config(overrides=ov)


def heading_gap(a, b):
    return float(np.abs(ref.wrap_pi(a.astype(np.float64) - b.astype(np.float64))).max())


def position_gap(a, b, boundary, box):
    d = np.abs(a.astype(np.float64) - b.astype(np.float64))
    if boundary == "periodic":
        d = np.minimum(d, box - d)
    return float(d.max())


def step_by_step(cfg, engine, steps=40):
    model = Vicsek(cfg.params, cfg.seed, engine)
    state = model.state()
    for t in range(steps):
        expected_x, expected_theta = ref.vicsek_step(state["x"], state["theta"], t, cfg.params, cfg.seed)
        model.set_state(state, t)
        model.advance(1)
        got = model.state()
        assert heading_gap(got["theta"], expected_theta) < TOL, f"theta differs at step {t}"
        assert position_gap(got["x"], expected_x, cfg.params.boundary, cfg.params.box) < TOL, f"x at step {t}"
        state = {"x": expected_x, "theta": expected_theta}
    return model


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("rule", RULES)
def test_step_matches_reference(engine, rule, boundary):
    step_by_step(vicsek_config(rule, boundary), engine)


@pytest.mark.parametrize("case", ["leader", "turn_limit", "leader_turn_limit_reflecting", "dense", "sparse_grid"])
def test_step_matches_reference_variants(engine, case):
    extra = {
        "leader": {"params.leader.enabled": True, "params.leader.heading_deg": 30.0},
        "turn_limit": {"params.max_turn_deg": 7.0},
        "leader_turn_limit_reflecting": {"params.leader.enabled": True, "params.max_turn_deg": 12.0},
        "dense": {"params.radius": 2.5},  # ~60 neighbours each
        "sparse_grid": {"params.radius": 5.0},  # 2 cells per side: the periodic stencil must not visit a cell twice
    }[case]
    boundary = "reflecting" if "reflecting" in case else "periodic"
    rule = "average" if case == "leader" else "vector"
    step_by_step(vicsek_config(rule, boundary, **extra), engine)


@pytest.mark.skipif(not F64, reason="long free-running horizons are compared at f64 only (f32 drifts chaotically)")
@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("rule", RULES)
def test_trajectory_matches_reference(engine, rule, boundary):
    free_run(vicsek_config(rule, boundary, n=300), engine, steps=150)


def free_run(cfg, engine, steps):
    """Kernel and reference run freely from the same initial state; within 1e-8 after `steps` steps."""
    model = Vicsek(cfg.params, cfg.seed, engine)
    x, theta = model.state()["x"], model.state()["theta"]
    model.advance(steps)
    for t in range(steps):
        x, theta = ref.vicsek_step(x, theta, t, cfg.params, cfg.seed)
    got = model.state()
    assert heading_gap(got["theta"], theta) < 1e-8
    assert position_gap(got["x"], x, cfg.params.boundary, cfg.params.box) < 1e-8


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("bound", [1, 4])
def test_metrics_match_reference(engine, boundary, bound):
    cfg = vicsek_config("vector", boundary, n=600, box=14.0,
                        **{"params.leader.enabled": True, "params.async_bound": bound})
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(24)
    previous = model.state()["theta"].astype(np.float64)
    model.advance(1)
    state = model.state()
    got = model.metrics()
    updated = model.updated_agents()
    assert not updated[0] and (updated[1:].all() if bound == 1 else 0.1 < updated.mean() < 0.9)
    expected = ref.vicsek_metrics(state["x"], state["theta"], cfg.params, previous, updated)
    assert set(got) == set(expected)
    for name in ("clusters", "max_neighbors"):
        assert got[name] == expected[name], name
    for name in ("largest_cluster", "mean_neighbors"):
        assert got[name] == pytest.approx(expected[name], abs=1e-12), name
    for name in ("polarization", "leader_error", "e_d", "e_theta", "de_theta", "updated"):
        assert got[name] == pytest.approx(expected[name], rel=1e-5, abs=1e-5), name
    observables = [name for name in got if name.startswith(("gnf_", "band_"))]
    assert len(observables) == (0 if boundary == "open" else 6)  # exponent, std in 4, 8, 16 boxes a side, bands
    for name in observables:  # integer box and slab counts: the same agents in the same boxes
        assert got[name] == pytest.approx(expected[name], rel=1e-12), name
    assert math.cos(got["mean_heading"] - expected["mean_heading"]) == pytest.approx(1.0, abs=1e-8)


def test_initial_state_is_the_documented_draw(engine):
    cfg = vicsek_config("vector", "periodic", n=50)
    model = Vicsek(cfg.params, cfg.seed, engine)
    from tflock.rng import Stream, uniform_np

    ids = np.arange(50)
    assert np.allclose(model.state()["x"][:, 0], 12.0 * uniform_np(7, 0, ids, Stream.INIT_X), atol=1e-5)
    assert np.allclose(model.state()["theta"], 2 * np.pi * uniform_np(7, 0, ids, Stream.INIT_HEADING), atol=1e-5)


def async_step_by_step(cfg, engine, steps):
    """Kernel vs reference with asynchrony: before every step the kernel gets the reference's whole state (the
    ring of B + 1 past states and Omega), then both take one step with the same update and delay draws."""
    model = Vicsek(cfg.params, cfg.seed, engine)
    state = model.state()
    hist_x, hist_theta, omega = state["history_x"], state["history_theta"], state["omega"]
    ring = cfg.params.async_bound + 1
    n_updates = 0
    for t in range(steps):
        model.set_state({"x": hist_x[t % ring], "theta": hist_theta[t % ring], "history_x": hist_x,
                         "history_theta": hist_theta, "omega": omega}, t)
        model.advance(1)
        hist_x, hist_theta, omega, updated = ref.vicsek_step_async(hist_x, hist_theta, omega, t, cfg.params,
                                                                  cfg.seed)
        got = model.state()
        assert np.array_equal(model.updated_agents(), updated), f"updates differ at step {t}"
        assert np.array_equal(got["omega"], omega)
        assert heading_gap(got["theta"], hist_theta[(t + 1) % ring]) < TOL, f"theta differs at step {t}"
        assert position_gap(got["x"], hist_x[(t + 1) % ring], cfg.params.boundary, cfg.params.box) < TOL
        assert heading_gap(got["history_theta"], hist_theta) < TOL
        n_updates += updated.sum()
    assert 0 < n_updates < steps * cfg.params.n  # asynchrony happened


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("rule", RULES)
def test_async_step_matches_reference(engine, rule, boundary):
    async_step_by_step(vicsek_config(rule, boundary, n=250, **{"params.async_bound": 5}), engine, steps=20)


def test_async_with_leader_and_turn_limit_matches_reference(engine):
    cfg = vicsek_config("relative", "reflecting", n=250, **{"params.async_bound": 3, "params.max_turn_deg": 10.0,
                                                           "params.leader.enabled": True})
    async_step_by_step(cfg, engine, steps=20)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_b1_is_the_synchronous_run(engine, boundary):
    """B = 1: a config with async_bound = 1 runs the synchronous kernel (bit-identical by construction), and the
    asynchronous kernel forced at B = 1 (every agent updates every step and sees the present) agrees with it up
    to summation order: the synchronous neighbour loop is vectorised, the asynchronous one (gathers from the
    ring) is not, so the last bits of the sums differ."""
    cfg = vicsek_config("vector", boundary, n=500, **{"params.async_bound": 1})
    sync = Vicsek(cfg.params, cfg.seed, engine)
    assert not sync.asynchronous
    forced = Vicsek(cfg.params, cfg.seed, engine, force_async=True)
    for _ in range(4):
        sync.advance(5)
        forced.advance(5)
        assert forced.updated_agents().all() and (forced.state()["omega"] == 1).all()
        a, b = sync.state(), forced.state()
        assert heading_gap(a["theta"], b["theta"]) < TOL
        assert position_gap(a["x"], b["x"], boundary, cfg.params.box) < TOL


# ------------------------------------------------------------------------------------------------------------
# Vectorial noise and topological neighbours (issue 29).

VECTORIAL = {"params.noise_type": "vectorial", "params.noise": 0.4}


@pytest.mark.parametrize("boundary,variant", [
    *((b, "synchronous") for b in BOUNDARIES),  # lane-wise (box) and general (open space) kernels
    ("reflecting", "turn_limit_leader"), ("periodic", "asynchronous"), ("open", "asynchronous"),
])
def test_vectorial_noise_matches_reference(engine, boundary, variant):
    """Gregoire-Chate noise: a unit vector of weight eta (1 + n_i) in the vector rule's sum, in the lane-wise, the
    general (open space) and the asynchronous kernels."""
    extra = {"synchronous": {}, "asynchronous": {"params.async_bound": 3},
             "turn_limit_leader": {"params.max_turn_deg": 20.0, "params.leader.enabled": True}}[variant]
    cfg = vicsek_config("vector", boundary, n=300, **VECTORIAL, **extra)
    if variant == "asynchronous":
        async_step_by_step(cfg, engine, steps=15)
    else:
        step_by_step(cfg, engine, steps=20)


def test_vectorial_noise_is_the_documented_draw(engine):
    """One agent alone: its new heading is the direction of its own unit vector plus eta times the noise vector at
    angle 2 pi u (u of Stream.NOISE), exactly as docs/models/vicsek.md states it."""
    from tflock.rng import Stream, uniform_np

    cfg = vicsek_config("vector", "periodic", n=1, box=5.0, **{"params.noise_type": "vectorial",
                                                              "params.noise": 0.7, "params.speed": 0.0})
    model = Vicsek(cfg.params, cfg.seed, engine)
    theta = float(model.state()["theta"][0])
    model.advance(1)
    psi = 2 * math.pi * uniform_np(cfg.seed, 0, np.arange(1), Stream.NOISE)[0]
    expected = math.atan2(math.sin(theta) + 0.7 * math.sin(psi), math.cos(theta) + 0.7 * math.cos(psi))
    assert heading_gap(model.state()["theta"], np.array([expected])) < TOL


TOPOLOGICAL = {"params.neighbours": "topological", "params.k": 6}


@pytest.mark.parametrize("rule,boundary", [*((r, b) for r in RULES for b in ("periodic", "open")),
                                           ("vector", "reflecting"), ("average", "reflecting")])
def test_topological_step_matches_reference(engine, rule, boundary):
    step_by_step(vicsek_config(rule, boundary, n=300, **TOPOLOGICAL), engine, steps=20)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_topological_with_vectorial_noise_leader_and_turn_limit(engine, boundary):
    cfg = vicsek_config("vector", boundary, n=300, **TOPOLOGICAL, **VECTORIAL,
                        **{"params.leader.enabled": True, "params.max_turn_deg": 30.0})
    step_by_step(cfg, engine, steps=20)


@pytest.mark.skipif(not F64, reason="long free-running horizons are compared at f64 only (f32 drifts chaotically)")
@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_topological_trajectory_matches_reference(engine, boundary):
    free_run(vicsek_config("vector", boundary, n=300, **TOPOLOGICAL), engine, steps=100)


def test_topological_neighbours_ignore_the_radius(engine):
    """With topological neighbours the interaction does not depend on R: two runs with R = 0.5 and R = 3 give the
    same trajectory (R only sizes the cells' lower bound and the R-graph metrics)."""
    runs = []
    for radius in (0.5, 3.0):
        cfg = vicsek_config("vector", "periodic", n=300, **TOPOLOGICAL, **{"params.radius": radius})
        model = Vicsek(cfg.params, cfg.seed, engine)
        model.advance(10)
        runs.append(model.state())
    assert heading_gap(runs[0]["theta"], runs[1]["theta"]) < TOL
    assert position_gap(runs[0]["x"], runs[1]["x"], "periodic", 12.0) < TOL


@pytest.mark.parametrize("bound", [1, 4])
@pytest.mark.parametrize("rule", ["average", "vector"])
def test_real_headings_match_reference(engine, rule, bound):
    """wrap_headings = false (the other reading of Samiloglu section 3): headings stay real numbers after the
    update and after a wall reflection, in the synchronous (lane-wise) and asynchronous kernels alike; compared
    without wrapping, so a kernel that wrapped would fail."""
    cfg = vicsek_config(rule, "reflecting", n=250, **{"params.wrap_headings": False, "params.async_bound": bound})
    model = Vicsek(cfg.params, cfg.seed, engine)
    state = model.state()
    outside = 0
    for t in range(40):
        if bound == 1:
            expected_x, expected_theta = ref.vicsek_step(state["x"], state["theta"], t, cfg.params, cfg.seed)
            model.set_state(state, t)
            state = {"x": expected_x, "theta": expected_theta}
        else:
            ring = bound + 1
            model.set_state({"x": state["history_x"][t % ring], "theta": state["history_theta"][t % ring],
                             "history_x": state["history_x"], "history_theta": state["history_theta"],
                             "omega": state["omega"]}, t)
            hist_x, hist_theta, omega, _ = ref.vicsek_step_async(state["history_x"], state["history_theta"],
                                                                 state["omega"], t, cfg.params, cfg.seed)
            state = {"history_x": hist_x, "history_theta": hist_theta, "omega": omega,
                     "x": hist_x[(t + 1) % ring], "theta": hist_theta[(t + 1) % ring]}
        model.advance(1)
        got = model.state()["theta"].astype(np.float64)
        assert np.abs(got - state["theta"]).max() < TOL, f"theta differs at step {t}"
        outside += int(((got < 0) | (got >= 2 * math.pi)).sum())
    assert outside > 0  # headings left [0, 2 pi): nothing wrapped them


def test_real_headings_with_topological_neighbours(engine):
    """wrap_headings = false with topological neighbours (the topological step's own update): headings stay real
    numbers, compared without wrapping."""
    cfg = vicsek_config("average", "reflecting", n=250, **TOPOLOGICAL, **{"params.wrap_headings": False})
    model = Vicsek(cfg.params, cfg.seed, engine)
    state = model.state()
    outside = 0
    for t in range(30):
        expected_x, expected_theta = ref.vicsek_step(state["x"], state["theta"], t, cfg.params, cfg.seed)
        model.set_state(state, t)
        model.advance(1)
        got = model.state()["theta"].astype(np.float64)
        assert np.abs(got - expected_theta).max() < TOL, f"theta differs at step {t}"
        outside += int(((got < 0) | (got >= 2 * math.pi)).sum())
        state = {"x": expected_x, "theta": expected_theta}
    assert outside > 0  # headings left [0, 2 pi): nothing wrapped them
