"""Batched replicas (tflock.ensemble): a batch reproduces its replicas run one by one, bit for bit.

Replica r of a batch must hold exactly the state of the lone run with seed + r after every step (same random
keys, same neighbours in the same order), and its metrics must be those of that run (the per-replica reductions
sum in another order: equal to rounding).
"""

import numpy as np
import pytest
from conftest import PRECISION

from tflock.config import load_config
from tflock.ensemble import run_replicas
from tflock.models import model_class

METRIC_RTOL = 1e-9 if PRECISION == "f64" else 2e-5
REPLICAS = 3


def config(model, **params):
    overrides = {f"params.{k}": v for k, v in params.items()}
    overrides.update({"engine.precision": PRECISION, "seed": 11, "steps": 12, "log.metrics_every": 4})
    return load_config(model=model, overrides=overrides)


def assert_batch_matches_lone_runs(cfg, engine, steps=12, **model_args):
    cls = model_class(cfg.model)
    batch = cls(cfg.params, cfg.seed, engine, replicas=REPLICAS, **model_args)
    lone = [cls(cfg.params, cfg.seed + r, engine, **model_args) for r in range(REPLICAS)]
    n = cfg.params.n
    for _ in range(steps):
        batch.advance(1)
        for model in lone:
            model.advance(1)
        state = batch.state()
        for r, model in enumerate(lone):
            for key, value in model.state().items():
                if key.startswith("history"):  # (ring, n, ...): the replica's slice along axis 1
                    got = state[key][:, r * n:(r + 1) * n]
                else:
                    got = state[key][r * n:(r + 1) * n]
                np.testing.assert_array_equal(got, value, err_msg=f"replica {r}, {key}")
    per_replica = batch.replica_metrics()
    for r, model in enumerate(lone):
        for name, value in model.metrics().items():
            np.testing.assert_allclose(per_replica[name][r], value, rtol=METRIC_RTOL, atol=1e-12, err_msg=name)


def test_vicsek_batch_beyond_4096_agents_names_its_exact_pair_errors_as_the_lone_run(engine):
    """Replicas of 2000 agents, 6000 in the batch: each replica's e_d and e_theta are exact (EXACT_PAIRS_MAX counts
    a replica's agents) and named as the lone run names them, not e_d_est (a sweep's table once split one metric
    across two columns by the replica count)."""
    cfg = config("vicsek", n=2000, box=31.6, noise=0.5)
    assert_batch_matches_lone_runs(cfg, engine, steps=2)


@pytest.mark.parametrize("boundary", ["periodic", "reflecting", "open"])
@pytest.mark.parametrize("rule", ["vector", "relative"])
def test_vicsek_batch_equals_lone_runs(engine, boundary, rule):
    cfg = config("vicsek", n=30, box=4.0, noise=0.8, boundary=boundary, rule=rule, max_turn_deg=60.0)
    assert_batch_matches_lone_runs(cfg, engine)


def test_vicsek_batch_with_leader_and_asynchrony(engine):
    cfg = config("vicsek", n=30, box=4.0, noise=0.3, boundary="reflecting", rule="average", async_bound=3,
                 **{"leader.enabled": True, "leader.heading_deg": 45.0})
    assert_batch_matches_lone_runs(cfg, engine)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("boundary", ["periodic", "open"])
def test_vicsek_batch_topological_vectorial(engine, boundary, dim):
    cfg = config("vicsek", n=30, box=4.0 if dim == 2 else 2.5, noise=0.5, boundary=boundary, neighbours="topological",
                 k=6, noise_type="vectorial", dim=dim)
    assert_batch_matches_lone_runs(cfg, engine)


def test_vicsek_3d_batch_equals_lone_runs(engine):
    cfg = config("vicsek", n=30, box=2.5, noise=0.8, boundary="reflecting", dim=3, max_turn_deg=40.0)
    assert_batch_matches_lone_runs(cfg, engine)


@pytest.mark.parametrize("boundary", ["open", "periodic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_adaptive_batch_equals_lone_runs(engine, boundary, dim):
    cfg = config("adaptive", n=40, box=5.0, noise=0.3, alpha=2.0, boundary=boundary, dim=dim)
    assert_batch_matches_lone_runs(cfg, engine)


def test_adaptive_transient_time_per_replica(engine):
    """tau is tracked for each replica of a batch as for its lone run."""
    cfg = config("adaptive", n=60, box=5.0, speed=1.0, alpha=16.0, noise=0.0)
    cls = model_class("adaptive")
    batch = cls(cfg.params, cfg.seed, engine, replicas=REPLICAS)
    batch.advance(40)
    lone_tau = []
    for r in range(REPLICAS):
        model = cls(cfg.params, cfg.seed + r, engine)
        model.advance(40)
        lone_tau.append(model.metrics()["tau"])
    assert np.all(np.isfinite(lone_tau))
    np.testing.assert_array_equal(batch.replica_metrics()["tau"], lone_tau)


@pytest.mark.parametrize("model, params", [
    ("adaptive", {"n": 40, "box": 5.0, "noise": 0.2}),
    ("vicsek", {"n": 30, "box": 4.0, "noise": 0.5}),
    ("potential", {"n": 6}),  # not batched: replicas run one by one
])
def test_run_replicas_equals_simulations(cpu_engine, model, params, monkeypatch):
    """Each table of run_replicas is the Simulation.metrics() table of the run with seed + r, also when the
    replicas are split over several batches."""
    import tflock.ensemble
    from tflock import Simulation

    cfg = config(model, **params)
    monkeypatch.setattr(tflock.ensemble, "BATCH_AGENTS", 2 * cfg.params.n)  # batches of 2 and 1
    done = []
    tables = run_replicas(cfg, REPLICAS, progress=done.append)
    assert done[-1] == REPLICAS * cfg.steps and done == sorted(done)
    assert len(tables) == REPLICAS
    for r, table in enumerate(tables):
        simulation = Simulation(cfg.model_copy(update={"seed": cfg.seed + r}))
        simulation.run()
        expected = simulation.metrics()
        assert list(table) == list(expected)
        np.testing.assert_array_equal(table["step"], [0, 4, 8, 12])
        for name, column in expected.items():
            np.testing.assert_allclose(table[name], column, rtol=METRIC_RTOL, atol=1e-12, err_msg=name)


def test_a_batch_that_turns_non_finite_stops_naming_the_replica(cpu_engine):
    """The non-finite guard of a lone run also watches a batch, at its metrics steps: agents flying at nearly the
    largest float leave the float range at step 2, found at the metrics step after it, in replica 0 (the first)."""
    from tflock.simulation import NumericalFaultError

    largest = np.finfo(np.float32 if PRECISION == "f32" else np.float64).max
    cfg = config("vicsek", n=10, boundary="open", box=1.0, speed=float(0.9 * largest)).model_copy(
        update={"steps": 6, "log": config("vicsek").log.model_copy(update={"metrics_every": 3})})
    with pytest.raises(NumericalFaultError, match=r"^numerical fault in vicsek at step 3: replica 0 \(seed 11\), "
                       r"agent \d+ has a non-finite position \(the replicas are checked every log.metrics_every = 3"):
        run_replicas(cfg, REPLICAS)
