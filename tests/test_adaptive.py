"""Li-Wang adaptive-velocity model (papers/002): kernel against the NumPy oracle, and the paper's physics.

Oracle tests (names contain ``oracle``) also run at f32 through ``test_precision.py``: one step at a time from
shared states, tolerance 2e-4; free-running and physics tests run at f64 only.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import PRECISION

from tflock.config import default_config_toml, load_config
from tflock.models.adaptive import Adaptive
from tflock.reference import adaptive as ref

F64 = PRECISION == "f64"
TOL = 1e-10 if F64 else 2e-4
REPO = Path(__file__).resolve().parents[1]
f64_only = pytest.mark.skipif(not F64, reason="f64 only (the f32 rerun covers the one-step oracle tests)")


def config(dim=2, boundary="open", alpha=1.5, noise=0.4, n=300, box=5.0, radius=2.0, speed=0.5, seed=7):
    return load_config(model="adaptive", overrides={
        "params.n": n, "params.dim": dim, "params.box": box, "params.radius": radius, "params.speed": speed,
        "params.alpha": alpha, "params.noise": noise, "params.boundary": boundary, "seed": seed,
        "engine.precision": PRECISION})


def gap(got, want, box=None):
    d = np.abs(got.astype(np.float64) - want.astype(np.float64))
    if box is not None:
        d = np.minimum(d, box - d)
    return float(d.max())


def assert_close(got, want, tol, box=None):
    assert gap(got["x"], want["x"], box) < tol
    assert gap(got["d"], want["d"]) < tol
    assert gap(got["phi"], want["phi"]) < tol


def step_by_step(cfg, engine, steps=25):
    """Kernel reset to the oracle's state before every step; same draws, step t -> t+1 compared."""
    p = cfg.params
    model = Adaptive(p, cfg.seed, engine)
    box = p.box if p.boundary == "periodic" else None
    state = model.state()
    assert_close(state, ref.initial_state(p, cfg.seed, engine.real), TOL, box)
    for t in range(steps):
        x, d, phi = ref.adaptive_step(state["x"], state["d"], state["phi"], t, p, cfg.seed)
        model.set_state(state, t)
        model.advance(1)
        assert_close(model.state(), {"x": x, "d": d, "phi": phi}, TOL, box)
        state = {"x": x, "d": d, "phi": phi}
    return model, state


@pytest.mark.parametrize("boundary", ["open", "periodic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_oracle_step(engine, dim, boundary):
    step_by_step(config(dim, boundary), engine)


@pytest.mark.parametrize(("dim", "alpha", "noise"), [(2, 0.0, 0.3), (2, "inf", 0.0), (3, "inf", 0.2), (3, 8.0, 0.0)])
def test_oracle_step_alpha_and_noise(engine, dim, alpha, noise):
    step_by_step(config(dim, alpha=alpha, noise=noise, radius=1.0), engine)


@pytest.mark.parametrize("dim", [2, 3])
def test_oracle_metrics(engine, dim):
    """Metrics against the oracle on a sparse swarm with several clusters."""
    cfg = config(dim, box=12.0, radius=1.2 if dim == 2 else 2.0, n=200, speed=0.3)
    model, _ = step_by_step(cfg, engine, steps=5)
    got, s = model.metrics(), model.state()
    want = ref.adaptive_metrics(s["x"], s["d"], s["phi"], cfg.params)
    assert want["clusters"] > 3
    for name, value in want.items():
        assert got[name] == pytest.approx(value, rel=1e-9 if F64 else 1e-5, abs=1e-12 if F64 else 1e-5), name


@f64_only
@pytest.mark.parametrize(("dim", "boundary"), [(2, "open"), (3, "open"), (2, "periodic")])
def test_free_running_matches_oracle(engine, dim, boundary):
    cfg = config(dim, boundary, n=250, noise=0.3)
    p = cfg.params
    model = Adaptive(p, cfg.seed, engine)
    s = ref.initial_state(p, cfg.seed)
    model.advance(120)
    x, d, phi = s["x"], s["d"], s["phi"]
    for t in range(120):
        x, d, phi = ref.adaptive_step(x, d, phi, t, p, cfg.seed)
    assert_close(model.state(), {"x": x, "d": d, "phi": phi}, 1e-8, p.box if boundary == "periodic" else None)


@f64_only
@pytest.mark.parametrize("dim", [2, 3])
def test_open_space_far_apart_finds_the_right_neighbours(engine, dim):
    """Groups 1e6 units apart (and at negative coordinates): the hashed grid still finds exactly the oracle's
    neighbours, and each group is its own cluster."""
    cfg = config(dim, n=240, radius=1.0, noise=0.2)
    p = cfg.params
    model = Adaptive(p, cfg.seed, engine)
    s = model.state()
    offsets = np.array([[0.0] * dim, [1e6] + [0.0] * (dim - 1), [-1e6] + [1e6] * (dim - 1), [3e6] * dim])
    s["x"] = s["x"] + offsets[np.arange(p.n) % 4]
    for t in range(10):
        x, d, phi = ref.adaptive_step(s["x"], s["d"], s["phi"], t, p, cfg.seed)
        model.set_state(s, t)
        model.advance(1)
        assert_close(model.state(), {"x": x, "d": d, "phi": phi}, 1e-8)
        s = {"x": x, "d": d, "phi": phi}
    got = model.metrics()
    want = ref.adaptive_metrics(s["x"], s["d"], s["phi"], p)
    assert got["clusters"] == want["clusters"] >= 4
    assert got["mean_neighbors"] == want["mean_neighbors"]


def displacement_norms(before, after):
    return np.linalg.norm(after["x"].astype(np.float64) - before["x"], axis=1)


@f64_only
@pytest.mark.parametrize("dim", [2, 3])
def test_alpha_zero_moves_every_agent_at_v0(engine, dim):
    """alpha = 0 is the constant-speed (Vicsek) model: |X_i(k+1) - X_i(k)| = v0 for all agents, every step,
    although the local polarities are far from 1."""
    cfg = config(dim, alpha=0.0, noise=0.5, speed=0.7)
    model = Adaptive(cfg.params, cfg.seed, engine)
    assert model.state()["phi"].min() < 0.5
    for _ in range(5):
        before = model.state()
        model.advance(1)
        assert np.abs(displacement_norms(before, model.state()) - 0.7).max() < 1e-12
    m = model.metrics()
    assert m["c_alpha"] == m["mean_speed"] == pytest.approx(1.0)
    assert m["phi_v"] == pytest.approx(m["phi_theta"])  # eqs. (2) and (3) coincide at constant speed


@f64_only
@pytest.mark.parametrize("dim", [2, 3])
def test_positive_alpha_starts_slow_and_reaches_v0(engine, dim):
    """The paper's setting (N = 300, L = 5, R = 2), alpha = 2: speeds v0 phi_i^2 start well below v0 and every
    agent reaches v0 once the group agrees; tau is the first step with mean speed >= 0.98 v0."""
    cfg = config(dim, alpha=2.0, noise=0.0, speed=0.1)
    model = Adaptive(cfg.params, cfg.seed, engine)
    first = model.metrics()
    assert first["mean_speed"] < 0.5 and math.isnan(first["tau"])
    speeds = [first["mean_speed"]]
    for _ in range(150):
        model.advance(1)
        speeds.append(model.metrics()["mean_speed"])
    m = model.metrics()
    tau = int(m["tau"])
    assert speeds[tau] >= 0.98 and max(speeds[:tau]) < 0.98
    before = model.state()
    model.advance(1)
    assert np.abs(displacement_norms(before, model.state()) - 0.1).max() < 1e-6
    assert m["largest_cluster"] == 1.0 and m["converged"] == 1.0 and m["phi_theta"] > 0.999


@f64_only
def test_alpha_inf_stays_still_until_the_neighbourhood_agrees(engine):
    """alpha = inf (eq. 6): an agent whose neighbours disagree (phi < 1) does not move; here the graph is complete
    (R >> L), so after one step every neighbourhood agrees and then all agents move at v0."""
    cfg = config(2, alpha="inf", noise=0.0, radius=50.0, speed=0.3)
    model = Adaptive(cfg.params, cfg.seed, engine)
    s0 = model.state()
    assert s0["phi"].max() < 0.5
    model.advance(1)
    s1 = model.state()
    assert np.array_equal(s1["x"], s0["x"])  # nobody moved
    assert s1["phi"].min() > 1 - 1e-12  # all directions are now the same mean direction
    model.advance(1)
    assert np.abs(displacement_norms(s1, model.state()) - 0.3).max() < 1e-12


@f64_only
def test_alpha_inf_moves_only_agreed_agents(engine):
    """Local version: after a step, exactly the agents with phi_i >= 1 - 1e-6 moved (by v0), the others stayed."""
    cfg = config(2, alpha="inf", noise=0.0, radius=0.6, box=8.0, n=300, speed=0.2)
    model = Adaptive(cfg.params, cfg.seed, engine)
    model.advance(10)
    before = model.state()
    model.advance(1)
    moved = displacement_norms(before, model.state())
    agreed = before["phi"] >= 1 - 1e-6
    assert 0 < agreed.sum() < cfg.params.n
    assert np.abs(moved[agreed] - 0.2).max() < 1e-12 and np.all(moved[~agreed] == 0)


@f64_only
def test_3d_aligned_swarm_stays_aligned_at_v0(engine):
    cfg = config(3, alpha=3.0, noise=0.0, speed=0.4)
    model = Adaptive(cfg.params, cfg.seed, engine)
    s = model.state()
    d = np.array([1.0, -2.0, 2.0]) / 3.0
    s["d"] = np.broadcast_to(d, s["d"].shape).copy()
    s["phi"] = np.ones(cfg.params.n)
    model.set_state(s, 0)
    model.advance(20)
    end = model.state()
    assert np.abs(end["d"] - d).max() < 1e-12 and np.abs(end["phi"] - 1).max() < 1e-12
    assert np.abs(end["x"] - (s["x"] + 20 * 0.4 * d)).max() < 1e-9
    m = model.metrics()
    assert m["phi_theta"] == pytest.approx(1.0) and m["mean_speed"] == pytest.approx(1.0) and m["tau"] == 0


@f64_only
def test_3d_noise_stays_in_the_cone(engine):
    """3D noise: the new direction is within eta of the mean direction m_i / |m_i| (and not always on the rim)."""
    eta = 0.3
    cfg = config(3, alpha=1.0, noise=eta)
    model = Adaptive(cfg.params, cfg.seed, engine)
    s = model.state()
    model.advance(1)
    noiseless = ref.align(s["x"] + 0.5 * s["phi"][:, None] * s["d"], s["d"], 0, cfg.params, cfg.seed, noise=False)[0]
    angle = np.arccos(np.clip((model.state()["d"] * noiseless).sum(axis=1), -1, 1))
    assert angle.max() <= eta + 1e-9 and angle.mean() > 0.5 * eta


def test_default_config_file_is_the_generated_default():
    assert (REPO / "configs" / "adaptive.toml").read_text() == default_config_toml("adaptive")


def test_paper_configs_load():
    files = sorted((REPO / "configs" / "papers").glob("liwang-*.toml"))
    assert len(files) >= 3
    for path in files:
        cfg = load_config(path)
        assert cfg.model == "adaptive"
        assert (cfg.params.n, cfg.params.box, cfg.params.radius) == (300, 5.0, 2.0)


@f64_only
@pytest.mark.parametrize("dim", [2, 3])
def test_recording_2d_and_3d(make_sim, tmp_path, dim):
    from tflock.record import read_recording, verify_recording

    path = tmp_path / f"a{dim}.rrd"
    sim = make_sim(model="adaptive", params={"n": 200, "box": 5.0, "dim": dim}, steps=5, record=path)
    sim.run()
    sim.close()
    assert verify_recording(path)
    summary = read_recording(path)
    assert summary.model == "adaptive" and summary.frames == 6
    assert {"/world/agents", "/world/agents/headings", "/metrics/phi_theta", "/metrics/tau"} <= set(summary.entities)
    assert summary.final_metrics["largest_cluster"] == sim.metrics()["largest_cluster"][-1]
