"""Runs of steps between observations (Simulation.step hands the model advance(k)): the same trajectory bit for
bit as step by step, whatever the cadences, for the models and options the fused paths cover."""

from pathlib import Path

import numpy as np
import pytest
from conftest import ARCH, PRECISION, assert_same_run

from tflock.config import load_config
from tflock.models.potential import Potential
from tflock.space import PERIODIC, WINDOW


@pytest.mark.parametrize("graph", ["random", "complete"])
def test_potential_fixed_graph_fused_steps_match_single_steps(engine, graph):
    cfg = load_config(model="potential", overrides={"params.n": 10, "params.box": 5.0, "params.topology": "fixed",
                                                    "params.graph": graph, "seed": 3, "engine.precision": PRECISION})
    single, fused = Potential(cfg.params, cfg.seed, engine), Potential(cfg.params, cfg.seed, engine)
    for steps in (37, 2, 1, 60):  # odd and even runs: the double buffers end as after single steps
        for _ in range(steps):
            single.advance(1)
        fused.advance(steps)
        a, b = single.checkpoint(), fused.checkpoint()
        assert single.step_index == fused.step_index and list(a) == list(b)
        for key in a:
            assert np.array_equal(a[key], b[key]), (steps, key)


CADENCED = [
    ("potential", {"n": 10, "box": 5.0, "topology": "fixed", "graph": "random"}),
    ("potential", {"n": 60, "box": 8.0}),
    ("vicsek", {"n": 100, "box": 7.0, "noise": 0.4}),
    ("vicsek", {"n": 60, "box": 6.0, "rule": "average", "leader": {"enabled": True}, "max_turn_deg": 30.0}),
    ("vicsek", {"n": 60, "box": 6.0, "async_bound": 3, "boundary": "reflecting"}),
]


@pytest.mark.parametrize("model,params", CADENCED)
def test_runs_between_observations_match_step_by_step(make_sim, model, params):
    """Metrics every 7 steps and checkpoints every 10 (runs of 1-7 steps per advance) against metrics every step
    (advance(1) each step): the same states, and the same rows at the steps both took."""
    every_step = make_sim(model=model, params=params, steps=40, seed=5, log={"metrics_every": 1})
    every_step.run()
    cadenced = make_sim(model=model, params=params, steps=40, seed=5, log={"metrics_every": 7})
    cadenced.run()
    a, b = every_step.metrics(), cadenced.metrics()
    rows = np.isin(a["step"], b["step"])
    assert list(b["step"]) == [0, 7, 14, 21, 28, 35, 40]
    for key in a:
        if key != "lambda2":  # recomputed every params.lambda2_every metrics steps, kept in between: by cadence
            assert np.array_equal(a[key][rows], b[key], equal_nan=True), key
    for key, value in every_step.state().items():
        assert np.array_equal(value, cadenced.state()[key]), key


def test_step_by_step_api_and_run_agree(make_sim):
    """sim.step(1) in a loop and sim.run() give the same run (progress sees every observed step)."""
    params = {"n": 10, "box": 5.0, "topology": "fixed", "graph": "random"}
    looped = make_sim(model="potential", params=params, steps=30, seed=1, log={"metrics_every": 10})
    for _ in range(30):
        looped.step(1)
    seen = []
    whole = make_sim(model="potential", params=params, steps=30, seed=1, log={"metrics_every": 10})
    whole.run(progress=seen.append)
    assert seen == [10, 20, 30]
    assert_same_run(looped, whole)


def assert_same_announced_frame(monkeypatch, threshold: tuple, single, fused, n: int) -> None:
    """A frame announced for a step that finds nothing done (its rows written by the step), of a model stepped one
    launch a step (the module's fused-loop `threshold` patched to 0) and of one stepped in a run: the same frame."""
    selected = np.arange(0, n, 3)
    with monkeypatch.context() as m:
        m.setattr(*threshold, 0)
        for _ in range(3):
            single.advance(1)
        single.draw_next(selected)
        single.advance(1)
        a = single.frame(selected, 0)
    fused.advance(3)
    fused.draw_next(selected)
    fused.advance(1)
    b = fused.frame(selected, 0)
    for name in ("positions", "directions", "colors", "ids"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


VICSEK_FUSED = [
    {"n": 100, "box": 7.0, "noise": 0.4, "max_turn_deg": 30.0},
    {"n": 61, "box": 6.0, "boundary": "reflecting", "noise_type": "vectorial", "leader": {"enabled": True}},
    {"n": 37, "box": 5.0, "rule": "average", "leader": {"enabled": True}, "max_turn_deg": 20.0,
     "wrap_headings": False},
]


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise step is the CPU's")
@pytest.mark.parametrize("params", VICSEK_FUSED)
def test_vicsek_fused_steps_match_single_launches(engine, monkeypatch, params):
    """The lane-wise Vicsek step run k steps a launch (_lane_wise_steps) against its launches of one step each
    (FUSED_MAX_AGENTS = 0): the same state, cell order, neighbour sums and metrics bit for bit, with metrics (whose
    pass sums the next step's neighbours) between runs of 1-30 steps; a batch of 2 replicas too; and a frame's rows,
    which the step writes."""
    import tflock.models.vicsek as vicsek

    def compared(replicas: int) -> tuple[str, ...]:
        # scratch too: the sums the last step used and, where the metrics pass sorted them, the headings (a batch's
        # metrics do not: the fused launch has sorted the new state's, the single launches the last step's)
        return ("pos", "theta", "trig", "ids", "turn", "updated", "sums") + (("payload",) if replicas == 1 else ())

    assert_vicsek_runs_match(engine, monkeypatch, params, "FUSED_MAX_AGENTS", compared,
                             lambda model: model.lane_wise and model.n_total <= vicsek.FUSED_MAX_AGENTS)


def assert_vicsek_runs_match(engine, monkeypatch, params: dict, threshold: str, compared, takes_path) -> None:
    """A Vicsek model of `params` stepped runs of 1-30 steps a launch against one stepped one launch a step (the
    module's agent cap `threshold` of the runs' path patched to 0), with metrics between runs, one system and a batch
    of 2 replicas: the arrays ``compared(replicas)`` and the metrics bit for bit, and an announced frame's rows.
    `takes_path(model)`: the model takes the runs' path."""
    import tflock.models.vicsek as vicsek

    overrides = {f"params.{k}": v for k, v in params.items() if k != "leader"}
    overrides.update({"params.leader.enabled": "leader" in params, "seed": 3, "engine.precision": PRECISION})
    cfg = load_config(model="vicsek", overrides=overrides)
    for replicas in (1, 2):
        single = vicsek.Vicsek(cfg.params, cfg.seed, engine, replicas=replicas)
        runs = vicsek.Vicsek(cfg.params, cfg.seed, engine, replicas=replicas)
        assert takes_path(runs)
        for steps in (1, 7, 2, 30):
            with monkeypatch.context() as m:
                m.setattr(vicsek, threshold, 0)
                for _ in range(steps):
                    single.advance(1)
                a = single.metrics() if replicas == 1 else single.replica_metrics()
            runs.advance(steps)
            b = runs.metrics() if replicas == 1 else runs.replica_metrics()
            for name in compared(replicas):
                assert np.array_equal(getattr(single, name).to_numpy(), getattr(runs, name).to_numpy()), (steps, name)
            for key in a:
                assert np.array_equal(a[key], b[key]), (steps, key)
        if replicas == 1:
            assert_same_announced_frame(monkeypatch, (vicsek, threshold), single, runs, cfg.params.n)


VICSEK_SERIAL = [
    {"n": 60, "box": 6.0, "async_bound": 3, "boundary": "reflecting", "rule": "average", "max_turn_deg": 30.0},
    {"n": 50, "box": 10.0, "async_bound": 4, "boundary": "open", "leader": {"enabled": True}},
    {"n": 45, "box": 5.0, "async_bound": 2, "rule": "relative", "noise": 0.3},
    {"n": 40, "box": 5.0, "async_bound": 3, "boundary": "open", "rule": "laplacian", "g": 100.0, "noise": 0.5,
     "wrap_headings": False},
]


@pytest.mark.skipif(ARCH != "cpu", reason="the serial launch is the CPU's (one GPU thread would be slow)")
@pytest.mark.parametrize("params", VICSEK_SERIAL)
def test_vicsek_serial_steps_match_single_launches(engine, monkeypatch, params):
    """The asynchronous Vicsek step run k steps a launch on one thread (_serial_steps) against its own launches, one
    step and one grid build each (SERIAL_MAX_AGENTS = 0): the same state, past views, cell order and metrics bit for
    bit, with metrics between runs of 1-30 steps, a batch of 2 replicas too; and a frame's rows, which the launch
    writes. The general step's other uses keep one launch a step (see Vicsek._serial)."""
    names = ("pos", "theta", "ids", "turn", "updated", "omega", "hist_pos", "hist_theta")
    assert_vicsek_runs_match(engine, monkeypatch, params, "SERIAL_MAX_AGENTS", lambda replicas: names,
                             lambda model: model._serial())


def test_vicsek_serial_steps_only_where_they_match(engine):
    """Synchronous updates in open space and vectorial noise take the general step one launch a step: compiled into
    one serial loop, their sums round differently (checked: 1 ulp in a few steps)."""
    import tflock.models.vicsek as vicsek

    for overrides in ({"params.boundary": "open"}, {"params.async_bound": 3, "params.noise_type": "vectorial"}):
        cfg = load_config(model="vicsek", overrides={"params.n": 40, "params.box": 5.0, **overrides})
        assert not vicsek.Vicsek(cfg.params, cfg.seed, engine)._serial(), overrides


POTENTIAL_FUSED = [
    {"n": 60, "box": 8.0},
    {"n": 40, "box": 5.0, "dim": 3},
    {"n": 10, "box": 5.0, "dim": 3},  # spreads beyond the bounded grid's 3 cells a side: the host's hashed steps
]


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise step is the CPU's")
@pytest.mark.parametrize("params", POTENTIAL_FUSED)
def test_potential_fused_steps_match_single_launches(engine, monkeypatch, params):
    """The switching topology's lane-wise step run k steps a launch (_lane_steps) against its launches of one step
    each (FUSED_MAX_N = 0): the same state, cell order and metrics bit for bit, with metrics (whose pass sums the
    next step's accelerations) between runs of 1-30 steps, through a swarm that outgrows the bounded grid (the launch
    stops there and the host's steps take over); and a frame's rows, which the launch writes."""
    import tflock.models.potential as potential

    overrides = {f"params.{k}": v for k, v in params.items()}
    overrides.update({"seed": 3, "engine.precision": PRECISION})
    cfg = load_config(model="potential", overrides=overrides)
    single = potential.Potential(cfg.params, cfg.seed, engine)
    fused = potential.Potential(cfg.params, cfg.seed, engine)
    assert fused.lane_wise and cfg.params.n <= potential.FUSED_MAX_N
    stopped = []
    for steps in (1, 7, 2, 30, 5, 30):
        with monkeypatch.context() as m:
            m.setattr(potential, "FUSED_MAX_N", 0)
            for _ in range(steps):
                single.advance(1)
            a = single.metrics()
        fused.advance(steps)
        stopped.append(int(fused._fused_done[0]) < steps)
        b = fused.metrics()
        for name in ("pos", "vel", "ids", "scratch"):
            assert np.array_equal(getattr(single, name).to_numpy(), getattr(fused, name).to_numpy()), (steps, name)
        for key in a:
            assert np.array_equal(a[key], b[key]), (steps, key)
    assert any(stopped) == (cfg.params.n == 10), stopped
    assert_same_announced_frame(monkeypatch, (potential, "FUSED_MAX_N"), single, fused, cfg.params.n)


PAPERS = Path(__file__).resolve().parents[1] / "configs" / "papers"
FORMATION_SERIAL = [
    ("formation-s1-1.toml", {}),  # the paper's setup: the swarm outgrows the window (steps 42-...) and fits again
    ("formation-failure-noise.toml", {"params.fail_prob": 0.3, "params.noise_deg": 0.9}),  # the random draws
]


@pytest.mark.parametrize("config,overrides", FORMATION_SERIAL)
@pytest.mark.skipif(ARCH != "cpu", reason="the serial launch is the CPU's (one GPU thread would be slow)")
def test_formation_serial_steps_match_single_launches(engine, monkeypatch, config, overrides):
    """The formation step run k steps a launch on one thread (_serial_steps) against its launches of one grid build
    and one step each (SERIAL_MAX_N = 0): the same state, cell order, rules and metrics bit for bit, with metrics
    between runs of 1-30 steps, through steps where no window holds the swarm (the torus's tiling then)."""
    import tflock.models.formation as formation

    cfg = load_config(PAPERS / config, overrides={**overrides, "engine.precision": PRECISION})
    single = formation.Formation(cfg.params, cfg.seed, engine)
    serial = formation.Formation(cfg.params, cfg.seed, engine)
    layouts = set()
    for steps in (1, 7, 2, 30, 5, 30, 1, 30):
        with monkeypatch.context() as m:
            m.setattr(formation, "SERIAL_MAX_N", 0)
            for _ in range(steps):
                single.advance(1)
                layouts.add(single.grid.geometry.boundary)
            a = single.metrics()
        serial.advance(steps)
        assert serial.step_index == single.step_index
        b = serial.metrics()
        assert a == b, steps
        for key, value in single.state().items():
            assert np.array_equal(value, serial.state()[key]), (steps, key)
        assert np.array_equal(single.rules(), serial.rules()), steps
        for name in ("ids", "pos", "f", "i"):  # the current buffers, in the same cell order
            assert np.array_equal(getattr(single, name)[single.cur].to_numpy(),
                                  getattr(serial, name)[serial.cur].to_numpy()), (steps, name)
        assert np.array_equal(single.trig.to_numpy(), serial.trig.to_numpy()), steps
    assert layouts == {WINDOW, PERIODIC}, layouts


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise launch is the CPU's")
def test_potential_small_swarm_grid_comes_from_the_steps_launch(engine, monkeypatch):
    """A small switching swarm's grid for its observations (metrics, guard, frame) comes from _lane_steps with no
    step, not from the host's build (whose kernels a run then never loads): the same layout, cells, order and runs
    as the host's build (FUSED_MAX_N = 0), and the same metrics."""
    import tflock.models.potential as potential
    import tflock.neighbors as neighbors

    cfg = load_config(model="potential", overrides={"params.n": 60, "params.box": 8.0, "seed": 3,
                                                    "engine.precision": PRECISION})
    launched, hosted = Potential(cfg.params, cfg.seed, engine), Potential(cfg.params, cfg.seed, engine)
    host_builds = []
    build = neighbors._build
    monkeypatch.setattr(neighbors, "_build", lambda *args: host_builds.append(1) or build(*args))
    for model in (launched, hosted):
        model.advance(7)
        model.invalidate()  # the grid the steps left is forgotten: the observation builds it
    launched._ensure_grid()
    assert host_builds == []
    with monkeypatch.context() as m:
        m.setattr(potential, "FUSED_MAX_N", 0)
        hosted._ensure_grid()
        assert host_builds == [1]
    a, b = launched.grid, hosted.grid
    assert a.geometry == b.geometry and a.geometry.boundary == neighbors.BOUNDED
    cells = a.geometry.total_buckets
    assert np.array_equal(a.start.to_numpy()[: cells + 1], b.start.to_numpy()[: cells + 1])
    assert np.array_equal(a.runs().to_numpy()[:cells], b.runs().to_numpy()[:cells])
    for name in ("order", "id_sorted", "pos_sorted", "coords_sorted"):
        assert np.array_equal(getattr(a, name).to_numpy(), getattr(b, name).to_numpy()), name
    with monkeypatch.context() as m:
        m.setattr(potential, "FUSED_MAX_N", 0)
        expected = hosted.metrics()
    assert launched.metrics() == expected


ONE_THREAD = [
    ("vicsek", {"n": 60, "box": 6.0, "boundary": "open", "noise": 0.3}),  # grid builds of the general step
    ("vicsek", {"n": 100, "box": 7.0, "noise": 0.4}),  # the lane-wise metrics pass, one stripe
    ("potential", {"n": 60, "box": 8.0}),  # the switching graph's metrics pass
    ("potential", {"n": 10, "box": 5.0, "topology": "fixed", "graph": "random"}),  # energies, nearest distances
]


@pytest.mark.parametrize("model,params", ONE_THREAD)
@pytest.mark.skipif(ARCH != "cpu", reason="the serialized passes are the CPU's")
def test_small_swarm_passes_on_one_thread_match_the_thread_pool(engine, make_sim, monkeypatch, model, params):
    """A small swarm's passes run serialized on the calling thread (tflock.cpu_tasks.one_thread): the same states,
    metrics and frame rows, bit for bit, as with every pass handed to the thread pool."""
    import tflock.models.potential as potential
    import tflock.models.vicsek as vicsek
    import tflock.neighbors as neighbors

    runs, asked = [], []
    for pooled in (False, True):
        with monkeypatch.context() as m:
            if pooled:
                for module in (neighbors, vicsek, potential):
                    m.setattr(module, "one_thread", lambda *args: bool(asked.append(args)))
            sim = make_sim(model=model, params=params, steps=30, seed=4, log={"metrics_every": 1})
            sim.run()
            frame = sim.model.frame(np.arange(params["n"]), 100, 0)
            runs.append((sim, frame))
    (serial, a), (pooled, b) = runs
    assert asked  # the pooled run did take the thread pool's passes
    assert_same_run(serial, pooled)
    for name in ("positions", "directions", "colors", "edges"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
