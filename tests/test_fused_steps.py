"""Runs of steps between observations (Simulation.step hands the model advance(k)): the same trajectory bit for
bit as step by step, whatever the cadences, for the models and options the fused paths cover."""

import numpy as np
import pytest
from conftest import PRECISION, assert_same_run

from tflock.config import load_config
from tflock.models.potential import Potential


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
