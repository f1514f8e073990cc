"""Samiloglu-Gazi-Koku (papers/003): asynchronous updates with bounded delays, the three strategies, turn limits
and the bounded arena, checked against what the paper states (Assumption 1, sections III-V)."""

import math
from pathlib import Path

import numpy as np
import pytest

from tflock import reference as ref
from tflock.config import load_config

PAPERS = Path(__file__).parents[1] / "configs" / "papers"


def test_every_agent_updates_within_any_b_steps(make_sim):
    """Assumption 1(a), on the update draws the kernel recorded: at least one update in any B consecutive steps,
    and agents do skip updates (the run is asynchronous)."""
    bound = 6
    sim = make_sim(params={"n": 400, "box": 20.0, "async_bound": bound, "noise": 0.3}, steps=80)
    masks = []
    for _ in range(80):
        sim.step(1)
        masks.append(sim.model.updated_agents())
        assert sim.model.state()["omega"].max() <= bound
    masks = np.array(masks)  # (steps, n)
    windows = np.lib.stride_tricks.sliding_window_view(masks, bound, axis=0)  # (steps - B + 1, n, B)
    assert windows.any(axis=2).all()
    assert 0.2 < masks.mean() < 0.6  # mean update probability of this scheme for B = 6 is 2 / (B + 1) ~ 0.29
    with pytest.raises(AssertionError):  # the check has teeth: with B - 1 it must fail somewhere
        assert np.lib.stride_tricks.sliding_window_view(masks, bound - 2, axis=0).any(axis=2).all()


def test_every_delay_lies_in_the_last_b_steps():
    """Assumption 1(b): tau in (t - B, t], i.e. delays d = t - tau in {0, ..., B - 1}, all of them used."""
    bound = 10
    omega = np.ones(200, dtype=np.int64)
    seen = set()
    for t in range(30):
        update, delays = ref.async_draws(7, t, omega, bound)
        assert delays.min() >= 0 and delays.max() <= bound - 1
        seen.update(np.unique(delays).tolist())
        omega = np.where(update, 1, omega + 1)
        assert omega.max() <= bound
    assert seen == set(range(bound))


def test_strategy_2_leaves_three_agents_120_degrees_apart_unchanged(make_sim):
    """003 section 3.2: with relative angles, three mutual neighbours 120 degrees apart keep their headings
    (the wrapped differences cancel); averaging (strategy 1) does change them."""
    def run(rule):
        sim = make_sim(params={"n": 3, "box": 10.0, "radius": 5.0, "speed": 0.01, "noise": 0.0, "rule": rule,
                               "boundary": "open"}, steps=20)
        start = {"x": np.array([[0.0, 0.0], [0.5, 0.0], [0.25, 0.4]]),
                 "theta": np.radians([10.0, 130.0, 250.0])}
        sim.model.set_state(start, 0)
        sim.step(20)
        return sim.state()["theta"]

    assert np.abs(ref.wrap_pi(run("relative") - np.radians([10.0, 130.0, 250.0]))).max() < 1e-5
    assert np.abs(ref.wrap_pi(run("average") - np.radians([10.0, 130.0, 250.0]))).max() > 0.5


def e_theta_after(make_sim, max_turn, bound, steps):
    sim = make_sim(config=PAPERS / f"samiloglu-s3-unbounded-b{bound}.toml", steps=steps,
                   params={"max_turn_deg": max_turn}, log={"every": 1})
    sim.run()
    return sim.metrics()["e_theta"][-1]


@pytest.mark.parametrize("bound", [1, 10])
def test_smaller_turn_limit_slows_agreement(make_sim, bound):
    """003 section 5.1: e_theta(T) is larger for alpha = 1 degree than for alpha = 180 degrees."""
    assert e_theta_after(make_sim, 1.0, bound, 150) > e_theta_after(make_sim, 180.0, bound, 150) + 0.2


def test_asynchrony_slows_agreement(make_sim):
    """003 section 5.1.2: with delays and skipped updates agreement is worse than synchronous (seed-averaged)."""
    def mean_e_theta(bound):
        values = []
        for seed in range(4):
            sim = make_sim(config=PAPERS / f"samiloglu-s3-unbounded-b{bound}.toml", steps=20, seed=seed)
            sim.run()
            values.append(sim.metrics()["e_theta"][-1])
        return np.mean(values)

    assert mean_e_theta(10) > mean_e_theta(1)


@pytest.mark.parametrize("strategy", ["s1", "s2", "s3"])
def test_reflecting_arena_keeps_every_agent_inside(make_sim, strategy):
    sim = make_sim(config=PAPERS / f"samiloglu-{strategy}-bounded-b10.toml", steps=300)
    for _ in range(6):
        sim.step(50)
        x = sim.state()["x"]
        assert x.min() >= 0.0 and x.max() <= 100.0


def test_paper_configs_load_with_the_papers_settings():
    files = sorted(PAPERS.glob("samiloglu-*.toml"))
    assert len(files) == 12
    for path in files:
        cfg = load_config(path)
        p = cfg.params
        assert (p.n, p.box, p.radius, p.speed, p.noise) == (50, 100.0, 20.0, 1.0, 0.0)
        assert cfg.steps == (1000 if p.boundary == "reflecting" else 500)
        assert p.async_bound in (1, 10)
        assert p.rule == {"s1": "average", "s2": "relative", "s3": "vector"}[path.stem.split("-")[1]]


def test_strategy_1_drifts_toward_pi(make_sim):
    """003 section 3.1: averaging the angle values biases headings toward pi, which the circular mean shows
    (strategy 3 on the same start does not drift that way)."""
    def mean_heading(rule):
        headings = []
        for seed in range(6):
            sim = make_sim(params={"n": 50, "box": 100.0, "radius": 20.0, "speed": 1.0, "noise": 0.0,
                                   "rule": rule, "boundary": "open"}, steps=100, seed=seed)
            sim.run()
            headings.append(sim.metrics()["mean_heading"][-1])
        return np.abs(ref.wrap_pi(np.array(headings) - math.pi)).mean()

    assert mean_heading("average") < mean_heading("vector")


def test_recording_shows_which_agents_updated(make_sim):
    sim = make_sim(params={"n": 300, "box": 15.0, "async_bound": 5}, steps=10)
    sim.step(7)
    ids = np.arange(300)
    frame = sim.model.frame(ids, max_edges=0)
    updated = sim.model.updated_agents()
    brightness = frame.colors.max(axis=1).astype(float)  # (as uint8, 2 x 175 wrapped to 94)
    assert updated.any() and (~updated).any()
    # the updated agents at full brightness, the others paler and darker (tflock.models.vicsek.dimmed: at most
    # 0.45 x 255 + 0.55 x 110 = 175), so the updated ones stand out
    assert brightness[updated].min() == 255 and brightness[~updated].max() <= 176
    assert brightness[~updated].min() >= 100  # still visible (darkened alone to 30 %: a blue one's was 76)
    assert brightness[updated].min() > 1.4 * brightness[~updated].max()
