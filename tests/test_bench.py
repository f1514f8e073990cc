"""`tflock bench` at tiny sizes: the cases run, the peers are timed, the results are written as data."""

import csv
import importlib.util
import json
import math
import subprocess
import sys

import numpy as np
import pytest

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
        assert r["logged_ms_median"] > 0
        assert r["logging_overhead"] > -1.0  # its definition is checked in test_logging_overhead_pairs_turns
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
    assert "agent-steps/s" in proc.stdout


@pytest.mark.parametrize("args,key", [(["--sizes", "0"], "--sizes"), (["--models", "boids"], "--models"),
                                      (["--states", "hot"], "--states"), (["--set", "params.boxx=3"], "params.boxx"),
                                      (["--set", "params.n=3"], "--set"), (["--set", "engine.threads=1"], "--set")])
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


def test_logging_overhead_pairs_turns(monkeypatch):
    """Turns of plain steps and a logging run, all from the case's state: the overhead compares each logging run with
    its own turn's plain steps (here the machine drifts between turns, plain steps of 4 to 16 ms, and a logging run
    takes 1.5 times its turn's plain step, 2.5 times in one turn hit by a slow spell)."""
    import time

    import taichi as ti

    from tflock import bench

    pace = iter([(4, 1.5), (16, 1.5), (4, 1.5), (16, 2.5), (8, 1.5), (16, 1.5), (4, 1.5), (8, 1.5)])
    state = {"ms": 0.0, "factor": 1.0, "restores": 0, "starts": set()}  # this turn's ms per plain step, and so on

    class Model:
        step_index = 7

        def checkpoint(self):
            return {"start": self.step_index}

        def restore(self, arrays, step):
            state["starts"].add(step)
            if state["restores"] % 2 == 0:  # a new turn
                state["ms"], state["factor"] = next(pace)
            state["restores"] += 1

        def build_neighbours(self):
            pass

        def advance(self, steps):
            time.sleep(state["ms"] * steps / 1e3)

    class Sim:
        model = Model()

        def step(self, steps):
            time.sleep(state["factor"] * state["ms"] * steps / 1e3)

    monkeypatch.setattr(bench, "_written", lambda sim: None)
    monkeypatch.setattr(ti, "sync", lambda: None)
    plain, logged, overhead = bench._plain_and_logged_steps(Sim(), repeats=3)
    assert len(plain) == 3 * bench.LOG_TURNS == 24 and state["starts"] == {7}  # every turn from the case's state
    assert overhead == pytest.approx(0.5, abs=0.05)
    assert logged == pytest.approx(1.5 * 8, rel=0.1)  # the logging runs' median: 6 6 6 12 12 24 24 40 ms a step


def test_results_go_under_results_bench_by_default():
    """Beside reproduce's results/NAME, never into benchmarks/ (the committed reference set); test_docs checks that
    the README's `tflock bench` example writes there."""
    from tflock.bench import default_out

    prefix = default_out(0.0)
    assert prefix.parent.as_posix() == "results/bench" and prefix.name.startswith("bench-")
