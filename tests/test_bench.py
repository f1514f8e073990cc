"""`tflock bench` at tiny sizes: the cases run, the peers are timed, the results are written as data."""

import csv
import importlib.util
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from conftest import ARCH, invoke_in

HAS_NUMBA = importlib.util.find_spec("numba") is not None


def test_bench_writes_json_csv_and_plot(tmp_path):
    prefix = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "tflock", "bench", "--models", "vicsek", "--sizes", "300,600",
                           "--states", "uniform,developed", "--develop-steps", "5", "--repeats", "2", "--log",
                           "--out", str(prefix)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(prefix.with_suffix(".json").read_text())
    assert data["command"].startswith("tflock bench") and data["machine"]["cores"] >= 1
    results = data["results"]
    assert [(r["case"]["n"], r["case"]["state"]) for r in results] == [
        (300, "uniform"), (300, "developed"), (600, "uniform"), (600, "developed")]
    for r in results:
        assert r["ms_min"] <= r["ms_median"] <= r["ms_max"]
        assert r["agent_steps_per_s"] == pytest.approx(r["case"]["n"] / r["ms_median"] * 1e3)
        assert r["build_ms"] > 0 and r["interactions_ms"] >= 0 and r["metrics_ms"] > 0 and r["logging_ms"] > 0
        assert r["run_ms_min"] <= r["run_ms_median"] <= r["run_ms_max"]
        assert r["run_overhead"] > -1.0  # defined as test_runs_pair_turns checks
        assert r["logged_ms_min"] <= r["logged_ms_median"] <= r["logged_ms_max"] and r["logging_overhead"] > -1.0
        assert r["mean_neighbors"] > 0 and r["first_step_s"] > 0
        assert 50 < r["device_bytes_per_agent"] < 400 and r["peak_rss_mb"] > 0
        assert set(r["peers"]) == {"numpy_reference", "ckdtree_sparse"} | ({"numba_cells"} if HAS_NUMBA else set())
        for peer in r["peers"].values():
            assert peer["ms"] > 0 and peer["ratio"] == pytest.approx(peer["ms"] / r["ms_median"])
        if HAS_NUMBA:
            assert r["peers"]["numba_cells"]["first_call_s"] > 0
    with open(prefix.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and "ckdtree_sparse_ratio" in rows[0]
    assert not HAS_NUMBA or {"numba_cells_ms", "numba_cells_ratio", "numba_cells_first_call_s"} <= set(rows[0])
    assert prefix.with_suffix(".png").stat().st_size > 10_000
    assert "agent-steps/s" in proc.stdout and "run ms/step" in proc.stdout and "logged run" in proc.stdout


def test_small_potential_case_has_its_numpy_peer_and_cadence(tmp_path):
    """--metrics-every sets the timed runs' cadence (kept with the case); potential's peer is its NumPy step."""
    prefix = tmp_path / "small"
    proc = subprocess.run([sys.executable, "-m", "tflock", "bench", "--models", "potential", "--sizes", "20",
                           "--states", "uniform", "--repeats", "2", "--metrics-every", "5", "--out", str(prefix)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (result,) = json.loads(prefix.with_suffix(".json").read_text())["results"]
    assert result["case"]["metrics_every"] == 5 and set(result["peers"]) == {"numpy_reference"}
    peer = result["peers"]["numpy_reference"]
    assert peer["ms"] > 0 and peer["ratio"] == pytest.approx(peer["ms"] / result["ms_median"])


@pytest.mark.parametrize("args,key", [(["--sizes", "0"], "--sizes"), (["--models", "boids"], "--models"),
                                      (["--states", "hot"], "--states"), (["--set", "params.boxx=3"], "params.boxx"),
                                      (["--set", "params.n=3"], "--set"), (["--set", "engine.threads=1"], "--set"),
                                      (["--metrics-every", "-1"], "--metrics-every")])
def test_bench_bad_input_is_one_line(args, key):
    proc = subprocess.run([sys.executable, "-m", "tflock", "bench", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in proc.stderr


def test_bench_overrides_scale_with_n():
    """--set changes the default config at its own N; the lengths then scale with N (the density is kept)."""
    from tflock.bench import BenchCase, case_config
    from tflock.config import load_config

    case = BenchCase(model="potential", n=1000, overrides=("params.box=240", "params.radius=1.5"))
    config = load_config(case_config(case))
    assert config.params.n == 1000 and config.params.radius == 1.5
    assert config.params.box == pytest.approx(240 * (1000 / 100_000) ** 0.5)
    nested = BenchCase(model="formation", n=24, overrides=("params.weights.align=2.0",))
    assert load_config(case_config(nested)).params.weights.align == 2.0


def test_workload_of_a_model_without_a_neighbour_metric(engine):
    """formation reports no neighbour count: the bench counts agents within its vision radius on its grid (here a
    window grid astride the torus's edge), as brute force does."""
    from tflock import reference as ref
    from tflock.bench import _mean_neighbours
    from tflock.config import load_config
    from tflock.models.formation import Formation

    overrides = {"params.n": 300, "params.world": 60.0, "params.init_length": 20.0, "params.init_width": 20.0,
                 "engine.precision": engine.precision}
    params = load_config(model="formation", overrides=overrides).params
    model = Formation(params, 1, engine)
    x = (np.random.default_rng(0).random((300, 2)) * 16.0 - 8.0) % 60.0
    model.set_state({"x": x, "theta": np.zeros(300)}, 0)
    expected = ref.adjacency(x.astype(engine.real), params.radius, "periodic", 60.0).sum(axis=1).mean()
    assert expected > 5 and _mean_neighbours(model, model.metrics(), 60.0) == pytest.approx(expected)


@pytest.mark.parametrize("n,box", [(1500, 27.4), (40, 2.5)])  # 27 cells a side; under 3 cells: one cell
def test_numba_peer_is_the_reference_vicsek_step(n, box):
    """The bench's numba peer computes tflock's model: one noiseless step equals the NumPy reference (f64 1e-10,
    f32 1e-5, from the same state), and the noise is U[-eta/2, eta/2] around the noiseless heading."""
    pytest.importorskip("numba")
    from tflock import reference
    from tflock.config import VicsekParams
    from tflock.peers.numba_vicsek import vicsek_step

    rng = np.random.default_rng(3)
    x0, theta0 = rng.random((n, 2)) * box, rng.random(n) * 2 * math.pi
    x0[:4] = [[0.0, 0.0], [box - 1e-3, 0.5], [0.3, box - 1e-3], [box / 2, box / 2]]  # at the box edges
    params = VicsekParams(n=n, box=box, noise=0.0)
    for dtype, tol in ((np.float64, 1e-10), (np.float32, 1e-5)):
        x_start, theta_start = x0.astype(dtype), theta0.astype(dtype)
        ref_x, ref_theta = reference.vicsek_step(x_start.astype(np.float64), theta_start.astype(np.float64), 0,
                                                 params, seed=1)
        x, theta = vicsek_step(x_start, theta_start, box, params.radius, params.speed, 0.0)
        assert x.dtype == theta.dtype == dtype
        assert np.all((theta >= 0) & (theta < 2 * math.pi)) and np.all((x >= 0) & (x < box))
        assert np.abs(reference.wrap_pi(theta.astype(np.float64) - ref_theta)).max() < tol
        dx = x - ref_x
        assert np.abs(dx - box * np.round(dx / box)).max() < tol
    eta = 0.5
    _, noisy = vicsek_step(x0, theta0, box, params.radius, params.speed, eta)
    xi = reference.wrap_pi(noisy - ref_theta)
    assert np.abs(xi).max() <= eta / 2 + 1e-9 and xi.std() > 0.5 * eta / math.sqrt(12)


@pytest.mark.parametrize("log", [False, True])
def test_runs_pair_turns(monkeypatch, log):
    """Turns of plain steps and runs (and logged runs), all from the case's state: each run is compared with its own
    turn's plain steps, and a logged run with its turn's run. Here the machine drifts between turns (plain steps of 4
    to 16 ms); a run with metrics every step takes 1.25 times its turn's plain step, a logged one 1.5 times the run
    (2.5 times in one turn hit by a slow spell)."""
    import types

    import taichi as ti

    from tflock import bench

    pace = iter([(4, 1.5), (16, 1.5), (4, 1.5), (16, 2.5), (8, 1.5), (16, 1.5), (4, 1.5), (8, 1.5)])
    state = {"ms": 0.0, "factor": 1.0, "restores": 0, "starts": set(), "metrics_every": set()}
    clock = [0.0]  # the bench's perf_counter: steps take their time without sleeping

    def spend(ms):
        clock[0] += ms / 1e3

    class Log:
        every = metrics_every = bench.METRICS_NEVER

    class Model:
        step_index = 7

        def checkpoint(self):
            return {"start": self.step_index}

        def restore(self, arrays, step):
            state["starts"].add(step)
            if state["restores"] % (3 if log else 2) == 0:  # a turn: plain steps, a run (and a logged run)
                state["ms"], state["factor"] = next(pace)
            state["restores"] += 1

        def build_neighbours(self):
            pass

        def metrics(self):  # the start state's, untimed (bench.start_run)
            return {}

        def advance(self, steps):
            spend(state["ms"] * steps)

    class Config:
        log = Log()

    class Sim:
        model, config = Model(), Config()

        def step(self, steps):
            state["metrics_every"].add(self.config.log.metrics_every)
            frames = self.config.log.every == 1
            spend(1.25 * (state["factor"] if frames else 1.0) * state["ms"] * steps)

    monkeypatch.setattr(bench, "_written", lambda sim: None)
    monkeypatch.setattr(ti, "sync", lambda: None)
    monkeypatch.setattr(bench, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))
    sim = Sim()
    turns = bench._plain_and_run_steps(sim, repeats=3, metrics_every=1, log=log)
    assert len(turns.plain) == 3 * bench.LOG_TURNS == 24 and state["starts"] == {7}  # every turn from the state
    assert state["metrics_every"] == {1} and sim.config.log.metrics_every == bench.METRICS_NEVER
    if log:
        assert turns.logging_overhead == pytest.approx(0.5, abs=1e-9)
        assert turns.logged == pytest.approx(1.25 * 1.5 * 8, rel=1e-9)  # median of 7.5 7.5 7.5 15 15 30 30 50 ms
        assert turns.logged_range == pytest.approx((7.5, 50.0))
    else:
        assert turns.logged is None and turns.logging_overhead is None
    assert turns.run_overhead == pytest.approx(0.25, abs=1e-9)
    assert turns.run == pytest.approx(1.25 * 8, rel=1e-9) and turns.run_range == pytest.approx((5.0, 20.0))


def test_results_go_under_results_bench_by_default():
    """Beside reproduce's results/NAME, never into benchmarks/ (the committed reference set); test_docs checks that
    the README's `tflock bench` example writes there."""
    from tflock.bench import default_out

    prefix = default_out(0.0)
    assert prefix.parent.as_posix() == "results/bench" and prefix.name.startswith("bench-")


@pytest.mark.skipif(ARCH != "cpu", reason="the metrics pass sums the next step on the CPU's lane-wise path only")
def test_a_timed_run_starts_where_a_run_leaves_the_state(engine):
    """The bench's run starts as `tflock sim` finds a step: where the cadence took the state's metrics, their pass has
    summed the step's neighbours (the Vicsek model's sums, `potential`'s accelerations), which the step then skips;
    a timed run without it would sum them once more in its first step."""
    from tflock.bench import BenchCase, case_config, start_run
    from tflock.config import load_config
    from tflock.models.potential import Potential
    from tflock.models.vicsek import Vicsek

    precision = {"precision": engine.precision, "arch": "cpu", "threads": engine.threads}
    for cls in (Vicsek, Potential):
        config = load_config({**case_config(BenchCase(model=cls.name, n=6000)), "engine": precision})
        model = cls(config.params, config.seed, engine)
        model.advance(1)
        start = (model.checkpoint(), model.step_index)
        for metrics_every, frames in ((1, False), (4, True)):  # step 1: no metrics at a cadence of 4
            start_run(model, start, metrics_every, frames)
            if cls is Vicsek:
                summed = model._ready() == 2
            else:
                summed = model._next_step.summed == (model.step_index, model.grid.builds)
            assert summed == (metrics_every == 1), f"{cls.name}, metrics every {metrics_every}"


def test_a_case_that_fails_is_named_in_the_results(tmp_path, monkeypatch):
    """A case whose process fails is left out of the table and the CSV, and named with its error in the JSON: a
    results file says which cases it lacks (on an H100 a potential case once failed with the rest still timed)."""
    from tflock import bench

    real = bench.run_in_subprocess
    error = "bench case formation n=300 uniform failed: CUDA_ERROR_MISALIGNED_ADDRESS"

    def run(case, timeout_s=3600):
        if case.model == "formation":
            raise RuntimeError(error)
        return real(case, timeout_s)

    monkeypatch.setattr(bench, "run_in_subprocess", run)
    result = invoke_in(tmp_path, ["bench", "--models", "vicsek,formation", "--sizes", "300", "--states", "uniform",
                                  "--repeats", "2", "--no-peers", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "run.json").read_text())
    assert [r["case"]["model"] for r in data["results"]] == ["vicsek"]
    assert [(s["case"]["model"], s["case"]["n"], s["error"]) for s in data["skipped"]] == [("formation", 300, error)]
    with open(tmp_path / "run.csv") as f:
        assert [row["model"] for row in csv.DictReader(f)] == ["vicsek"]


def test_engine_labels_tell_apart_the_rows_of_several_engines() -> None:
    """`tflock bench --threads 1,2` printed two rows and drew one line with nothing to tell the thread counts
    apart: the table gets an engine column and the plot's legend a label, each the part of the engine that
    differs; none for one engine."""
    from types import SimpleNamespace

    from tflock.bench import engine_labels

    one, two = "cpu, 1 thread, f32, 8 lanes", "cpu, 2 threads, f32, 8 lanes"
    rows = [SimpleNamespace(engine=e) for e in (one, two, one)]
    assert engine_labels(rows) == {one: "1 thread", two: "2 threads"}
    assert engine_labels([SimpleNamespace(engine=one)] * 3) == {}
    f64 = "cpu, 2 threads, f64, 8 lanes"
    assert engine_labels([SimpleNamespace(engine=e) for e in (one, f64)]) == {one: "1 thread, f32",
                                                                                f64: "2 threads, f64"}
