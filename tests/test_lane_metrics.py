"""Vicsek metrics taken by the lane-wise neighbour pass (tflock.lane_graph) against the NumPy reference.

The lane-wise CPU step's metrics() runs the next step's neighbour pass early and finds the R-graph's clusters and
neighbour counts in it; these tests compare every such metric with the O(N^2) reference on states that stress the
cluster search (one cluster over the whole box, hundreds of small ones, neighbours across the periodic wrap and
across stripes), check that the stripes do not change the partition, and that taking metrics leaves the trajectory
bit-identical. The sampled pair errors are checked against the same draws made in NumPy.
"""

import math

import numpy as np
import pytest
from conftest import ARCH, PRECISION

from tflock import lane_graph
from tflock import reference as ref
from tflock.config import load_config
from tflock.lane_graph import LaneComponents
from tflock.metrics import EXACT_PAIRS_MAX, SAMPLED_PAIRS, pairwise_errors
from tflock.models.vicsek import Vicsek
from tflock.space import boundary_code

pytestmark = pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise pass runs on the CPU arch only")

# (n, box, boundary, rule): mean degree about 0.8 (many small clusters), about 7 (a few large ones), about 60 (one
# cluster), each boundary and each way the pass sums (vectors, angles)
CASES = [(500, 45.0, "periodic", "vector"), (500, 45.0, "reflecting", "average"), (2500, 34.0, "periodic", "average"),
         (2500, 34.0, "reflecting", "vector"), (3000, 12.5, "periodic", "vector"), (3000, 12.5, "reflecting", "vector")]


def config(n, box, boundary="periodic", rule="vector", noise=0.3, **extra):
    return load_config(overrides={"params.n": n, "params.box": box, "params.radius": 1.0, "params.speed": 0.3,
                                  "params.noise": noise, "params.rule": rule, "params.boundary": boundary,
                                  "seed": 11, "engine.precision": PRECISION, **extra})


def expected_graph(model):
    p = model.params
    return ref.graph_metrics(model.state()["x"].astype(np.float64), p.radius, p.boundary, p.box)


def assert_graph_metrics(got, expected):
    assert got["clusters"] == expected["clusters"]
    assert got["largest_cluster"] == pytest.approx(expected["largest_cluster"], abs=1e-12)
    assert got["max_neighbors"] == expected["max_neighbors"]
    assert got["mean_neighbors"] == pytest.approx(expected["mean_neighbors"], abs=1e-9)


@pytest.fixture
def striped(monkeypatch):
    """Swarms of these tests' sizes cut into stripes, as larger ones are (a small swarm is one stripe)."""
    monkeypatch.setattr(lane_graph, "ONE_STRIPE_MAX", 0)


@pytest.mark.parametrize(("n", "box", "boundary", "rule"), CASES)
def test_lane_wise_metrics_match_reference(engine, striped, n, box, boundary, rule):
    cfg = config(n, box, boundary, rule)
    model = Vicsek(cfg.params, cfg.seed, engine)
    assert model.components is not None  # the lane-wise path
    for _ in range(3):  # the initial state, then states with aligned clusters
        got = model.metrics()
        assert_graph_metrics(got, expected_graph(model))
        theta = model.state()["theta"]
        polarization, mean_heading = ref.heading_order(theta)
        assert got["polarization"] == pytest.approx(polarization, abs=1e-6)
        assert math.cos(got["mean_heading"] - mean_heading) == pytest.approx(1.0, abs=1e-6)
        model.advance(10)


def test_clusters_joined_across_the_periodic_wrap(engine):
    """Agents in a line across the box's corner: one cluster only through the wrap in x and in y."""
    cfg = config(40, 20.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    t = np.arange(40, dtype=np.float64)
    x = np.stack([(10.0 + 0.5 * t) % 20.0, (10.0 + 0.5 * t) % 20.0], axis=1)  # steps of 0.71 < R
    model.set_state({"x": x, "theta": np.zeros(40)}, 0)
    got = model.metrics()
    assert got["clusters"] == 1.0 and got["largest_cluster"] == 1.0
    assert_graph_metrics(got, expected_graph(model))


@pytest.mark.parametrize("teeth", [2, 3])
def test_an_agent_joining_separate_sets(engine, teeth):
    """Lines of agents whose tips lie 0.95 R around one agent, further than R from each other: each line is a set
    of its own until that agent, whose near candidates (in its stripe, before it) carry two labels (joined as its
    block settles) or three (its candidates re-read); it joins them into one cluster. Lone agents 1.4 R apart fill
    the rest of the box, enough agents for cells of side R."""
    points = [(10.0, 10.0)]
    for a in np.radians([200.0, 340.0, 270.0][:teeth]):  # each line runs outward from its tip, 0.5 apart
        points += [(10.0 + (0.95 + 0.5 * j) * math.cos(a), 10.0 + (0.95 + 0.5 * j) * math.sin(a)) for j in range(3)]
    lone = [(0.5 + 1.4 * i, y + 1.4 * j) for i in range(14) for j in range(5) for y in (0.5, 12.5)]
    x = np.array(points + lone)
    cfg = config(len(x), 20.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.set_state({"x": x, "theta": np.zeros(len(x))}, 0)
    assert model.grid.geometry.cells_per_side == 20
    got = model.metrics()
    assert got["clusters"] == 1 + len(lone)
    assert got["largest_cluster"] == len(points) / len(x)
    assert_graph_metrics(got, expected_graph(model))


@pytest.mark.parametrize("threads", [1, 2, 3, 7])
def test_stripes_do_not_change_the_partition(engine, monkeypatch, threads):
    cfg = config(2500, 34.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(12)
    expected = expected_graph(model)
    model.components = LaneComponents(model.grid, threads)
    assert model.components.stripes()[0] == 1  # a small swarm: one stripe
    assert_graph_metrics(model.metrics(), expected)
    monkeypatch.setattr(lane_graph, "ONE_STRIPE_MAX", 0)
    model.invalidate()
    assert model.components.stripes()[0] == min(lane_graph.STRIPES_PER_THREAD * threads, 34 // 4)
    assert_graph_metrics(model.metrics(), expected)


@pytest.mark.parametrize("threads", [2, 7])
def test_clusters_across_every_stripe(engine, monkeypatch, threads):
    """Two zigzag lines along the slowest axis (across every layer, so every stripe edge), one of them closed
    through the periodic wrap, among lone agents: the stripes' edge joins (parallel, lock-free) bring each line's
    size to its root; the counts and the largest cluster are the reference's."""
    monkeypatch.setattr(lane_graph, "ONE_STRIPE_MAX", 0)
    side = 40.0
    ys = np.arange(0.0, side, 0.6)  # steps under R along y, through the wrap for the first line
    first = [(5.0 + 0.3 * (k % 2), y) for k, y in enumerate(ys)]
    second = [(25.0 + 0.3 * (k % 2), y) for k, y in enumerate(ys[:40])]  # 39 steps: it ends inside the box
    lone = [(12.0 + 1.5 * i, 0.7 + 1.5 * j) for i in range(5) for j in range(26)] + \
           [(31.0 + 1.5 * i, 0.7 + 1.5 * j) for i in range(5) for j in range(26)]
    x = np.array(first + second + lone)
    cfg = config(len(x), side)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.components = LaneComponents(model.grid, threads)
    model.set_state({"x": x, "theta": np.zeros(len(x))}, 0)
    assert model.components.stripes()[0] > 2
    got = model.metrics()
    assert got["clusters"] == 2 + len(lone)
    assert got["largest_cluster"] == len(first) / len(x)
    assert_graph_metrics(got, expected_graph(model))


def test_roots_counted_on_the_host_and_by_the_kernel_agree(engine, monkeypatch):
    """A small swarm's components are counted in NumPy on the host memory of the pass's parents; the kernel's count
    (SMALL_SWARM_MAX = 0) gives the same numbers: many clusters, several stripes."""
    import tflock.taichi_host as taichi_host

    monkeypatch.setattr(lane_graph, "ONE_STRIPE_MAX", 0)
    cfg = config(2500, 34.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(12)
    host = model.metrics()
    assert model.components.stripes()[0] > 1 and host["clusters"] > 1
    monkeypatch.setattr(taichi_host, "SMALL_SWARM_MAX", 0)
    model.invalidate()
    kernel = model.metrics()
    assert (host["clusters"], host["largest_cluster"]) == (kernel["clusters"], kernel["largest_cluster"])


@pytest.mark.parametrize("extra", [{}, {"params.noise_type": "vectorial"}, {"params.neighbours": "topological"}],
                         ids=["angular", "vectorial", "topological"])
def test_metrics_leave_the_trajectory_unchanged(engine, extra):
    """Bit for bit, also with vectorial noise (the early pass must leave the counts the noise weight uses) and with
    topological neighbours (whose step takes its own sums: metrics() must not make it skip them)."""
    cfg = config(2500, 34.0, **extra)
    observed, plain = Vicsek(cfg.params, cfg.seed, engine), Vicsek(cfg.params, cfg.seed, engine)
    for _ in range(12):
        observed.metrics()
        observed.advance(1)
    observed.metrics()
    plain.advance(12)
    for key, value in plain.state().items():
        assert np.array_equal(observed.state()[key], value), key


@pytest.mark.parametrize("boundary", ["periodic", "reflecting"])
def test_sampled_pair_errors_are_the_documented_draws(engine, boundary):
    n = EXACT_PAIRS_MAX + 904
    cfg = config(n, 60.0, boundary)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(3)
    p = model.params
    got = pairwise_errors(model.pos, model.theta, n, p.box, boundary_code(boundary), 2, model.seed, model.step_index)
    x, theta = model.pos.to_numpy().T, model.theta.to_numpy()  # array order: the order the samples index
    expected = ref.pairwise_errors_sampled(x, theta, boundary, p.box, model.seed, model.step_index, SAMPLED_PAIRS)
    assert got == pytest.approx(expected, rel=1e-6)
    exact = ref.pairwise_errors(x, theta, boundary, p.box)
    assert got == pytest.approx(exact, rel=0.02)  # an estimate of the mean over all pairs


@pytest.mark.parametrize("boundary", ["periodic", "reflecting", "open"])
def test_small_swarms_orders_and_pairs_in_one_launch(engine, boundary):
    """Up to SMALL_GRAPH_MAX agents the heading sums and e_d, e_theta come from one launch on one thread: the
    reference's values, and bit for bit those of the two parallel passes."""
    from tflock.metrics import SMALL_GRAPH_MAX, heading_order, orders_and_pairs

    for n in (2, 37, SMALL_GRAPH_MAX):
        cfg = config(n, 6.0, boundary, **{"params.async_bound": 2})
        model = Vicsek(cfg.params, cfg.seed, engine)
        model.advance(4)
        p, code = model.params, boundary_code(boundary)
        got = orders_and_pairs(model.theta, model.pos, n, 0.5, p.box, code, 2, model.seed, model.step_index)
        parallel = (heading_order(model.theta, n, 0.5),
                    pairwise_errors(model.pos, model.theta, n, p.box, code, 2, model.seed, model.step_index))
        assert got == parallel, n
        x, theta = model.pos.to_numpy().T, model.theta.to_numpy()
        assert got[1] == pytest.approx(ref.pairwise_errors(x, theta, boundary, p.box), rel=1e-5)
        unit = np.stack([np.cos(theta), np.sin(theta)], axis=1).astype(np.float64)
        assert got[0][0] == pytest.approx(np.hypot(*unit.mean(axis=0)), abs=1e-5)
