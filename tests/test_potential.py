"""Potential-field flocking (Tanner-Jadbabaie-Pappas, papers/001): kernels against the NumPy oracle, physics of
Theorems 1-2 and Corollaries 1-3, configs and validation.

Oracle: one step at a time from the oracle's state (f64 1e-10, f32 relative 1e-4), and free-running trajectories
at f64. Physics tests run at f64 only (test_precision.py reruns this file at f32 for the oracle tests).
"""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import ARCH, PRECISION

from tflock.config import ConfigError, default_config_toml, load_config
from tflock.models.potential import _SPEED_RAMP, Potential, speed_colors
from tflock.models.potential_graphs import component_labels, initial_state, to_csr
from tflock.reference import potential as ref

F64 = PRECISION == "f64"
TOL = 1e-10 if F64 else 1e-4
ROOT = Path(__file__).resolve().parents[1]
f64_only = pytest.mark.skipif(not F64, reason="physics and long horizons run at f64")


def config(**params):
    base = {"n": 10, "box": 5.0, "radius": 2.0, "desired_distance": 1.0, "dt": 0.01}
    base.update(params)
    return load_config(model="potential", overrides={**{f"params.{k}": v for k, v in base.items()},
                                                      "seed": 3, "engine.precision": PRECISION})


def gap(a, b):
    a, b = a.astype(np.float64), b.astype(np.float64)
    return float((np.abs(a - b) / (1.0 + np.abs(b))).max())


CASES = {
    "switching-2d": {"n": 80, "box": 9.0, "topology": "switching"},
    "switching-3d": {"n": 80, "box": 5.0, "dim": 3, "topology": "switching"},
    "fixed-random": {"n": 30, "box": 6.0, "topology": "fixed", "graph": "random", "graph_p": 0.2},
    "fixed-tree-3d": {"n": 30, "box": 4.0, "dim": 3, "topology": "fixed", "graph": "tree"},
    "fixed-ring": {"n": 12, "topology": "fixed", "graph": "ring"},
}


@pytest.mark.parametrize("case", CASES)
def test_step_matches_reference(engine, case):
    cfg = config(**CASES[case])
    model = Potential(cfg.params, cfg.seed, engine)
    edges = ref.graph_edges(cfg.params, cfg.seed)
    state = model.state()
    for t in range(40):
        expected_x, expected_v = ref.potential_step(state["x"], state["v"], cfg.params, edges)
        model.set_state(state, t)
        model.advance(1)
        got = model.state()
        assert gap(got["v"], expected_v) < TOL, f"v differs at step {t}"
        assert gap(got["x"], expected_x) < TOL, f"x differs at step {t}"
        state = {"x": expected_x, "v": expected_v}


@f64_only
@pytest.mark.parametrize("case", ["switching-2d", "switching-3d", "fixed-random"])
def test_trajectory_and_metrics_match_reference(engine, case):
    cfg = config(**CASES[case])
    model = Potential(cfg.params, cfg.seed, engine)
    edges = ref.graph_edges(cfg.params, cfg.seed)
    x, v = (a.astype(np.float64) for a in model.state().values())
    for _ in range(300):
        x, v = ref.potential_step(x, v, cfg.params, edges)
    model.advance(300)
    got = model.state()
    assert gap(got["x"], x) < 1e-8 and gap(got["v"], v) < 1e-8
    expected = ref.potential_metrics(x, v, cfg.params, edges)
    for name, value in model.metrics().items():
        assert value == pytest.approx(expected[name], rel=1e-9, abs=1e-9), name


def test_initial_state_follows_section_6():
    s = initial_state(400, 2, 5.0, 1.0, 0.15, seed=1)
    x, v = s["x"], s["v"]
    r = np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1)) + np.eye(400) * 9
    assert r.min() >= 0.15 and np.abs(x).max() < 2.5
    speed = np.linalg.norm(v, axis=1)
    assert 0 <= speed.min() and speed.max() < 1 and abs(speed.mean() - 0.5) < 0.05
    assert np.array_equal(x, initial_state(400, 2, 5.0, 1.0, 0.15, seed=1)["x"])
    s3 = initial_state(300, 3, 6.0, 2.0, 0.3, seed=2)
    assert np.linalg.norm(s3["v"], axis=1).max() < 2 and abs(s3["v"].mean(axis=0)).max() < 0.2


@pytest.mark.parametrize("box", [30.0, 1e39])
def test_placement_grid_finds_every_close_pair_in_any_box(box):
    """The placement's hashed grid (cells widened for a box too wide for 64-bit cell keys, such as params.box =
    1e39 at f64) flags exactly the candidates a brute-force pass flags: within the separation of a placed agent or
    of a candidate with a smaller id."""
    from tflock.models.potential_graphs import _too_close

    rng = np.random.default_rng(5)
    n, separation = 600, 0.5
    x = rng.uniform(-box / 2, box / 2, (n, 3))
    x[1::7] = x[0::7][: len(x[1::7])] + rng.uniform(-0.3, 0.3, (len(x[1::7]), 3))  # planted close pairs
    placed = rng.random(n) < 0.5
    candidates = np.flatnonzero(~placed)
    d2 = ((x[:, None] - x[None]) ** 2).sum(-1)
    ids = np.arange(n)
    near = (d2 < separation**2) & (ids[:, None] != ids[None]) & (placed[None] | (ids[None] < ids[:, None]))
    want = near[candidates].any(axis=1)
    assert want.sum() > 20
    np.testing.assert_array_equal(_too_close(x, candidates, placed, separation), want)


def test_graph_families():
    n = 9
    for graph, n_edges in [("complete", 36), ("path", 8), ("ring", 9), ("tree", 8)]:
        model_edges = ref.graph_edges(config(n=n, topology="fixed", graph=graph).params, 0)
        assert len(np.unique(np.sort(model_edges, axis=1), axis=0)) == n_edges
        assert component_labels(n, model_edges).max() == 0
    offsets, neighbours = to_csr(4, np.array([[0, 1], [2, 1], [1, 0]]))
    assert offsets.tolist() == [0, 1, 3, 4, 4] and neighbours.tolist() == [1, 0, 2, 1]


def test_validation_errors(tmp_path):
    with pytest.raises(ConfigError, match="desired_distance: must be < params.radius"):
        config(desired_distance=2.5)
    with pytest.raises(ConfigError, match="params.dt"):
        config(dt=0.0)
    bad = tmp_path / "g.txt"
    bad.write_text("0 1\n1 2\n# comment\n3 4\n")
    with pytest.raises(ConfigError, match=r"not connected .*3 components: \{0, 1, 2\}, \{3, 4\}, \{5\}") as e:
        config(n=6, topology="fixed", graph="file", graph_file=str(bad))
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="graph file not found"):
        config(topology="fixed", graph="file", graph_file=str(tmp_path / "missing.txt"))
    bad.write_text("0 x\n")
    with pytest.raises(ConfigError, match="expected two agent ids"):
        config(topology="fixed", graph="file", graph_file=str(bad))
    with pytest.raises(ConfigError, match="min_separation: too large"):
        config(n=1000, min_separation=0.5)
    good = tmp_path / "ok.txt"
    good.write_text("\n".join(f"{i} {i + 1}" for i in range(9)))
    assert config(topology="fixed", graph="file", graph_file=str(good)).params.graph == "file"


def test_configs_match_defaults_and_load():
    assert (ROOT / "configs" / "potential.toml").read_text() == default_config_toml("potential")
    for path in sorted((ROOT / "configs" / "papers").glob("tanner-*.toml")):
        assert load_config(path).params.n == 10


def run(engine, steps, every=10, **params):
    cfg = config(**params)
    model = Potential(cfg.params, cfg.seed, engine)
    rows = [model.metrics()]
    for _ in range(steps // every):
        model.advance(every)
        rows.append(model.metrics())
    return model, {k: np.array([r[k] for r in rows]) for k in rows[0]}


@f64_only
def test_fixed_connected_graph_synchronises_and_w_falls(engine):
    """Theorem 1: velocities synchronise; W (eq. 5) never rises beyond the integration error."""
    _, m = run(engine, 3000, topology="fixed", graph="random")
    assert m["velocity_mismatch_max"][-1] < 1e-3 * m["velocity_mismatch_max"][0]
    assert np.diff(m["W"]).max() < 1e-3 * m["W"][0]
    assert m["W"][-1] < 0.6 * m["W"][0]
    assert m["polarization"][-1] > 0.999


@f64_only
def test_complete_graph_avoids_collisions(engine):
    """Corollary 3: with a complete graph the minimum distance stays away from 0 (it starts at >= 0.25)."""
    _, m = run(engine, 2000, every=5, n=10, topology="fixed", graph="complete", speed=3.0)
    assert m["min_distance"].min() > 0.2
    assert m["velocity_mismatch_max"][-1] < 1e-3


@f64_only
def test_tree_distances_converge_to_d(engine):
    """Corollary 1: along the edges of a tree, distances converge to the desired distance."""
    model, _ = run(engine, 4000, every=4000, n=10, topology="fixed", graph="tree", desired_distance=0.8)
    x = model.state()["x"]
    e = model.edges
    dist = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    assert np.abs(dist - 0.8).max() < 1e-3


@f64_only
def test_higher_lambda2_synchronises_faster(engine):
    """Corollary 2: from the same start, the complete graph (lambda_2 = n) aligns faster than the path."""
    _, path = run(engine, 6000, every=20, n=10, topology="fixed", graph="path")
    _, complete = run(engine, 6000, every=20, n=10, topology="fixed", graph="complete")
    assert path["lambda2"][0] == pytest.approx(2 * (1 - math.cos(math.pi / 10)))
    assert complete["lambda2"][0] == pytest.approx(10.0)
    assert path["velocity_mismatch_mean"][0] == complete["velocity_mismatch_mean"][0]

    def settle(m):  # first sample after which the velocity mismatch stays below 1e-2
        above = np.flatnonzero(m["velocity_mismatch_max"] >= 1e-2)
        return above[-1] + 1 if above.size else 0

    assert settle(complete) < len(complete["W"]) - 1
    assert settle(complete) < 0.5 * settle(path)


@f64_only
def test_switching_from_connected_start_agrees_on_speed(engine):
    """Theorem 2: from a connected R-graph, speeds agree and Q (eq. 10) does not rise beyond the integration error."""
    model, m = run(engine, 4000, every=20, n=10, topology="switching", radius=2.0)
    assert m["connected"][0] == 1
    assert m["speed_spread"][0] > 0.5 and m["speed_spread"][-1] < 1e-3
    assert m["velocity_mismatch_max"][-1] < 1e-3
    assert np.diff(m["Q"]).max() < 1e-3 * abs(m["Q"]).max()
    assert m["min_distance"].min() > 0.2
    assert m["valency_mean"][-1] >= m["valency_mean"][0]
    assert {f"valency_{i}" for i in range(10)} | {f"speed_{i}" for i in range(10)} <= set(m)


@f64_only
def test_frame_draws_the_graph(engine):
    cfg = config(n=12, topology="fixed", graph="ring")
    model = Potential(cfg.params, cfg.seed, engine)
    frame = model.frame(np.arange(12), 100)
    assert frame.positions.shape == (12, 2) and frame.colors.shape == (12, 3) and frame.edges.shape == (12, 2, 2)
    x = model.state()["x"]
    assert np.allclose(frame.positions, x, atol=1e-6)
    assert np.allclose(frame.edges[0], x[[1, 0]], atol=1e-6)  # from the later drawn agent to the earlier
    cfg = config(n=60, box=5.0, dim=3, topology="switching")
    model = Potential(cfg.params, cfg.seed, engine)
    frame = model.frame(np.arange(0, 60, 2), 50)
    assert frame.positions.shape == (30, 3) and 0 < len(frame.edges) <= 50


def test_fixed_frame_rows_in_numpy_are_the_kernels(engine, monkeypatch):
    """A small swarm's frame rows (fixed graph), gathered in NumPy on the arrays' host memory, are the gather
    kernel's, for drawn agents in any order."""
    import tflock.taichi_host as taichi_host

    cfg = config(n=12, topology="fixed", graph="ring")
    model = Potential(cfg.params, cfg.seed, engine)
    model.advance(7)
    drawn = np.array([11, 3, 0, 7, 5])
    small = model.frame(drawn, 100)
    monkeypatch.setattr(taichi_host, "SMALL_SWARM_MAX", 0)
    kernel = model.frame(drawn, 100)
    for name in ("positions", "directions", "colors", "edges"):
        np.testing.assert_array_equal(getattr(small, name), getattr(kernel, name), err_msg=name)
    x = model.state()["x"]
    assert np.allclose(small.positions, x[drawn], atol=1e-6)


@pytest.mark.skipif(ARCH != "cpu", reason="GPU arches keep the hashed grid")
def test_step_matches_reference_in_both_layouts(engine):
    """The switching step on a bounded grid (the swarm's bounding box: 2D runs lane-wise on the CPU) and, with one
    agent far out, on the hashed grid it falls back to: both follow the oracle step by step."""
    from tflock.neighbors import BOUNDED, OPEN

    cfg = config(**CASES["switching-2d"])
    model = Potential(cfg.params, cfg.seed, engine)
    assert model.grid.bounded
    state = model.state()
    for layout, straggler in ((BOUNDED, None), (OPEN, 1e5)):
        x, v = state["x"].copy(), state["v"].copy()
        if straggler is not None:
            x[0] = straggler
        for t in range(10):
            expected_x, expected_v = ref.potential_step(x, v, cfg.params)
            model.set_state({"x": x, "v": v}, t)
            model.advance(1)
            assert model.grid.geometry.boundary == layout
            got = model.state()
            assert gap(got["v"], expected_v) < TOL and gap(got["x"], expected_x) < TOL, f"step {t}"
            x, v = expected_x, expected_v


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise step is the CPU's")
@pytest.mark.parametrize("dim", [2, 3])
def test_lane_wise_step_equals_per_agent_step(engine, dim):
    """The CPU's lane-wise step (runs of cells, 8 agents at a time) adds the same terms in the same order as the
    per-agent kernel on the same bounded grid: equal states (to an ulp or two, where the compiler fuses
    differently), in a dense clump (cells of several lane blocks) and a sparse field (runs of several cells)."""
    import taichi as ti

    from tflock.models.potential import _sort_velocities, _step_lanes, _step_switching

    assert Potential(config().params, 3, engine).lane_wise
    rng = np.random.default_rng(1)
    n = 500
    side = 40.0 if dim == 2 else 12.0
    x = np.concatenate([rng.random((400, dim)) * side, 5.0 + rng.random((100, dim)) * 2.0])
    v = rng.normal(size=(n, dim))
    cfg = config(n=n, box=side, dim=dim, topology="switching", min_separation=0.0)
    model = Potential(cfg.params, cfg.seed, engine)
    results = []
    for lane_wise in (True, False):
        model.set_state({"x": x, "v": v}, 0)
        model._ensure_grid()
        grid, g, p = model.grid, model.grid.geometry, cfg.params
        _sort_velocities(n, dim, grid.order, model.vel, model.scratch)
        args = (p.radius**2, p.desired_distance**2, p.dt)
        if lane_wise:
            _step_lanes(g.total_buckets, g.cells_per_side, *args, dim, g.boundary, grid.start, grid.runs(),
                        grid.id_sorted, grid.pos_sorted, model.scratch, model.pos, model.vel, model.ids,
                        *model._draw_arguments(2, dim))  # no frame announced: no rows
        else:
            _step_switching(n, *args, dim, g.boundary, g.cells_per_side, g.n_buckets, grid.start, grid.mixed,
                            grid.id_sorted, grid.pos_sorted, grid.coords_sorted, model.scratch, model.pos, model.vel,
                            model.ids)
        ti.sync()
        results.append(model.state())
    # rounding bound: a few ulps of the largest partial sums, dt times the sum of |terms| (close pairs in the clump
    # give terms far larger than their sum)
    d = x[None, :, :] - x[:, None, :]
    r2 = (d * d).sum(axis=2)
    np.fill_diagonal(r2, 1.0)
    near = (r2 < cfg.params.radius**2) & ~np.eye(n, dtype=bool)
    terms = np.abs(v[None, :, :] - v[:, None, :]) + np.abs(2 * (r2 - 1.0) / r2**2)[:, :, None] * np.abs(d)
    scale = 1.0 + np.abs(v) + cfg.params.dt * (terms * near[:, :, None]).sum(axis=1)
    ulp = np.finfo(engine.real).eps
    for key in ("x", "v"):
        a, b = (r[key].astype(np.float64) for r in results)
        assert np.all(np.abs(a - b) <= 8 * ulp * (scale + np.abs(b))), key


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise metrics pass is the CPU's")
def test_lane_wise_pass_reports_each_agents_valency(engine):
    """The lane-wise pass writes the valencies at the agents' grid slots; the per-agent metrics valency_i are still
    agent i's, as the oracle counts them, step after step."""
    cfg = config(n=16, box=3.0, topology="switching", radius=1.2, min_separation=0.0)
    model = Potential(cfg.params, cfg.seed, engine)
    assert model.lane_wise
    for t in range(4):
        state = model.state()
        got = model.metrics()
        assert model._pairs_step[1]  # written in slot order
        agent_at = model.grid.id_sorted.to_numpy()[:16]
        assert not np.array_equal(agent_at, np.arange(16))  # the slots are not the agents' order: the test bites
        expected = ref.potential_metrics(state["x"], state["v"], cfg.params)
        for i in range(16):
            assert got[f"valency_{i}"] == expected[f"valency_{i}"], f"agent {i} at step {t}"
        model.advance(5)


def _lane_pass_state(dim, shape):
    """Positions of a sparse field (many small clusters) or a jittered lattice (one dense cluster), several
    stripes of grid layers where they fit, and random velocities."""
    rng = np.random.default_rng(7 + dim)
    if shape == "clusters":
        side = 40.0 if dim == 2 else 16.0
        x = rng.random((600, dim)) * side
    else:
        per_side, spacing = (25, 0.8) if dim == 2 else (9, 0.9)
        x = np.stack(np.meshgrid(*[np.arange(per_side)] * dim, indexing="ij"), axis=-1).reshape(-1, dim) * spacing
        x = x + rng.uniform(-0.1, 0.1, x.shape)
        side = per_side * spacing
    return x, rng.normal(size=x.shape), side


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise metrics pass is the CPU's")
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("shape", ["clusters", "flock"])
@pytest.mark.parametrize("one_launch", [True, False])
def test_lane_wise_metrics_pass_matches_reference_and_keeps_the_trajectory(engine, monkeypatch, dim, shape,
                                                                             one_launch):
    """The metrics pass that also sums the next step (each agent's valency; the components by stripes of grid
    layers and their cross-stripe joins, and each agent's energy and nearest distance over its pairs with the agents
    at smaller grid slots) gives the oracle's numbers, and the steps after it are bit for bit those of a run without
    metrics: many small clusters, and one dense cluster. Both the small swarm's pass in one launch (the components
    as one stripe) and the striped pass of larger swarms (FUSED_MAX_N = ONE_STRIPE_MAX = 0 here)."""
    import tflock.lane_graph as lane_graph
    import tflock.models.potential as potential
    from tflock.neighbors import BOUNDED

    if not one_launch:
        monkeypatch.setattr(potential, "FUSED_MAX_N", 0)
        monkeypatch.setattr(lane_graph, "ONE_STRIPE_MAX", 0)

    x, v, side = _lane_pass_state(dim, shape)
    n = len(x)
    cfg = config(n=n, box=side, dim=dim, topology="switching", min_separation=0.0)
    p = cfg.params
    observed, plain = Potential(p, cfg.seed, engine), Potential(p, cfg.seed, engine)
    observed.set_state({"x": x, "v": v}, 0)
    plain.set_state({"x": x, "v": v}, 0)
    for t in range(3):
        state = observed.state()
        observed.lyapunov()  # the pass alone: min_distance of a small swarm comes from all pairs, not from it
        assert observed.grid.geometry.boundary == BOUNDED and observed._next_step.summed is not None
        if t == 0 and shape == "clusters" and not one_launch:
            assert observed.components.stripes()[0] > 1  # the cross-stripe joins run
        xs = state["x"].astype(np.float64)
        r2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(axis=2)
        np.fill_diagonal(r2, np.inf)
        near = r2 < p.radius**2
        agent_at = observed.grid.id_sorted.to_numpy()[:n]  # the pass writes each agent's numbers at its grid slot
        assert np.array_equal(observed.valency.to_numpy(), near.sum(axis=1)[agent_at]), f"valency at step {t}"
        slot = np.empty(n, dtype=np.int64)  # each agent's grid slot: a pair is summed at its later slot
        slot[agent_at] = np.arange(n)
        earlier = near & (slot[None, :] < slot[:, None])
        nearest = np.sqrt(np.where(earlier, r2, p.radius**2).min(axis=1))
        assert gap(observed.nearest.to_numpy(), nearest[agent_at]) < TOL, f"nearest at step {t}"
        pair_v = p.desired_distance**2 / r2 + np.log(r2) - (p.desired_distance**2 / p.radius**2 + np.log(p.radius**2))
        energy = np.where(earlier, pair_v, 0.0).sum(axis=1)
        assert gap(observed.energy.to_numpy(), energy[agent_at]) < 10 * TOL, f"energy at step {t}"
        assert observed.nearest.to_numpy().min() == pytest.approx(np.sqrt(min(r2.min(), p.radius**2)), rel=TOL)
        expected = ref.potential_metrics(state["x"], state["v"], p)
        got = observed.metrics()
        assert got["components"] == expected["components"], f"components at step {t}"
        assert (got["components"] == 1) == (shape == "flock")
        for name in ("valency_mean", "valency_min", "valency_max", "connected"):
            assert got[name] == expected[name], name
        if t == 0:  # then every params.lambda2_every steps; 0 exactly for a graph of several components
            assert got["lambda2"] == pytest.approx(expected["lambda2"], rel=1e-9, abs=1e-9)
            assert (got["lambda2"] == 0.0) == (shape == "clusters")
        assert got["potential_energy"] == pytest.approx(expected["potential_energy"], rel=10 * TOL, abs=TOL)
        observed.advance(1)
        plain.advance(1)
        for key, value in observed.state().items():
            assert np.array_equal(value, plain.state()[key]), f"{key} after step {t + 1}"


@pytest.mark.parametrize("dim", [2, 3])
def test_small_swarm_velocity_statistics_are_the_kernels(engine, monkeypatch, dim):
    """A small swarm's velocity metrics, in NumPy on the velocities' host memory, are the two kernel launches' (to
    the last bits of a float64 sum), an agent at rest included."""
    import tflock.taichi_host as taichi_host

    cfg = config(n=50, box=6.0, dim=dim, topology="switching")
    model = Potential(cfg.params, cfg.seed, engine)
    model.advance(5)
    state = model.state()
    state["v"][7] = 0.0
    model.set_state(state, 5)
    small = model._velocity_stats()
    monkeypatch.setattr(taichi_host, "SMALL_SWARM_MAX", 0)
    kernels = model._velocity_stats()
    assert small.keys() == kernels.keys()
    for name, value in kernels.items():
        assert small[name] == pytest.approx(value, rel=1e-12, abs=1e-15), name


@pytest.mark.parametrize("dim", [2, 3])
def test_velocity_statistics_over_several_blocks_are_numpys(engine, dim):
    """The velocity kernels' lanes and blocks (two blocks, the second ending inside a group of lanes, agents at
    rest among them) give NumPy's float64 statistics of the same velocities."""
    from tflock.models.potential import velocity_stats
    from tflock.reductions import BLOCK

    n = BLOCK + 13
    cfg = config(n=n, box=200.0, dim=dim, topology="switching")
    model = Potential(cfg.params, cfg.seed, engine)
    state = model.state()
    rng = np.random.default_rng(3)
    state["v"] = (1.0 + rng.normal(size=state["v"].shape)).astype(state["v"].dtype)
    state["v"][[0, 5, n - 1]] = 0.0  # at rest: a first lane, a middle one, the last agent
    model.set_state(state, 0)
    expected = velocity_stats(model.vel.to_numpy())
    got = model._velocity_stats()
    for name, value in expected.items():
        assert got[name] == pytest.approx(value, rel=1e-12, abs=1e-15), name


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise metrics pass is the CPU's")
def test_frame_after_a_metrics_step_is_the_plain_runs(engine):
    """A step after the metrics pass only moves the agents and writes the announced frame's rows: the frame equals
    that of a run without metrics (whose frame gathers its rows from the grid)."""
    cfg = config(n=600, box=40.0, topology="switching")
    observed, plain = Potential(cfg.params, cfg.seed, engine), Potential(cfg.params, cfg.seed, engine)
    selected = np.arange(0, 600, 3)
    for _ in range(3):
        observed.metrics()
        observed.draw_next(selected)
        observed.advance(1)
        plain.advance(1)
        assert observed._drawn is not None and observed._drawn[0] == observed.step_index  # rows by the move
        a, b = observed.frame(selected, 400), plain.frame(selected, 400)
        for name in ("positions", "directions", "edges", "colors"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_speed_colours_follow_the_ramp():
    """The looked-up colours stay within one level of the ramp interpolated per agent; its ends are exact."""
    speed = np.concatenate([np.linspace(0.0, 2.0, 20001), [0.0, 1.0, 5.0]])
    t = np.clip(speed / 2.0, 0.0, 1.0) * (len(_SPEED_RAMP) - 1)
    k = np.minimum(t.astype(np.int64), len(_SPEED_RAMP) - 2)
    f = (t - k)[:, None]
    exact = np.rint(_SPEED_RAMP[k] * (1 - f) + _SPEED_RAMP[k + 1] * f)
    colours = speed_colors(speed, 2.0)
    assert colours.dtype == np.uint8 and colours.shape == (len(speed), 3)
    assert np.abs(colours.astype(int) - exact).max() <= 1
    assert (colours[-3] == _SPEED_RAMP[0]).all() and (colours[-1] == _SPEED_RAMP[-1]).all()
