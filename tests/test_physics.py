"""What the papers prove or report, checked on the kernels (assertions a wrong model would fail)."""

import math

import numpy as np
import pytest

from tflock import reference as ref


def headings(sim):
    return sim.state()["theta"].astype(np.float64)


def test_average_complete_graph_converges_to_initial_mean(make_sim):
    """Jadbabaie Theorem 1 with a complete graph and no noise: every heading becomes the arithmetic mean of the
    initial headings in one step and stays there (the circular mean, what `vector` would give, differs)."""
    sim = make_sim(params={"n": 64, "box": 5.0, "radius": 50.0, "speed": 0.1, "noise": 0.0, "rule": "average",
                           "boundary": "open"}, steps=30)
    theta0 = headings(sim)
    mean0 = theta0.mean()
    circular0 = math.atan2(np.sin(theta0).mean(), np.cos(theta0).mean()) % (2 * math.pi)
    assert abs(mean0 - circular0) > 0.05  # the test can tell the two means apart
    sim.run()
    theta = headings(sim)
    assert np.abs(theta - mean0).max() < 1e-5


def test_laplacian_with_g_above_n_converges_on_a_fixed_connected_graph(make_sim):
    """Jadbabaie eqs. (17)-(20), G = gI with g > n: on a connected graph the headings agree, and since the
    Laplacian of an undirected graph is symmetric the agreed value is the initial average."""
    n = 120
    sim = make_sim(params={"n": n, "box": 6.0, "radius": 1.6, "speed": 0.0, "noise": 0.0, "rule": "laplacian",
                           "g": n + 1.0, "boundary": "periodic"}, steps=400)
    assert sim.metrics()["clusters"][0] == 1  # connected R-graph (speed 0: it never changes)
    theta0 = headings(sim)
    sim.run()
    theta = headings(sim)
    assert theta.max() - theta.min() < 1e-4 * (theta0.max() - theta0.min())
    assert theta.mean() == pytest.approx(theta0.mean(), abs=1e-4)


def test_leader_following_converges_to_leader_heading(make_sim):
    """Jadbabaie Theorem 4: followers linked to the leader all end with its heading theta0."""
    sim = make_sim(params={"n": 80, "box": 8.0, "radius": 4.0, "speed": 0.05, "noise": 0.0, "rule": "average",
                           "boundary": "open", "leader": {"enabled": True, "heading_deg": 250.0}}, steps=1500)
    assert sim.metrics()["leader_error"][0] > 1.0
    sim.run()
    theta = headings(sim)
    assert theta[0] == pytest.approx(math.radians(250.0), abs=1e-6)  # the leader never updates
    assert np.abs(ref.wrap_pi(theta - math.radians(250.0))).max() < 1e-3
    assert sim.metrics()["leader_error"][-1] < 1e-3


def test_vector_orders_at_low_noise_and_not_at_full_noise(make_sim):
    """Vicsek 1995: polarization near 1 at low noise and density, ~1/sqrt(N) at eta = 2 pi."""
    common = {"n": 1500, "box": 20.0, "radius": 1.0, "speed": 0.2, "rule": "vector", "boundary": "periodic"}
    ordered = make_sim(params={**common, "noise": 0.2}, steps=600, seed=3)
    ordered.run()
    disordered = make_sim(params={**common, "noise": 2 * math.pi}, steps=200, seed=3)
    disordered.run()
    assert ordered.metrics()["polarization"][-1] > 0.9
    assert disordered.metrics()["polarization"][-20:].mean() < 0.1


def test_turn_limit_bounds_every_turn(make_sim):
    """Samiloglu eq. (7a): without noise, no agent turns more than alpha per step."""
    sim = make_sim(params={"n": 500, "box": 10.0, "radius": 1.5, "speed": 0.2, "noise": 0.0, "rule": "vector",
                           "max_turn_deg": 4.0}, steps=20)
    before = headings(sim)
    largest = 0.0
    for _ in range(20):
        sim.step(1)
        after = headings(sim)
        largest = max(largest, float(np.abs(ref.wrap_pi(after - before)).max()))
        before = after
    assert largest <= math.radians(4.0) + 1e-6
    assert largest > math.radians(3.9)  # the limit binds


def test_smaller_turn_limit_slows_agreement(make_sim):
    def polarization_after(max_turn):
        sim = make_sim(params={"n": 400, "box": 8.0, "radius": 2.0, "speed": 0.1, "noise": 0.0, "rule": "vector",
                               "max_turn_deg": max_turn}, steps=15, seed=5)
        sim.run()
        return sim.metrics()["polarization"][-1]

    assert polarization_after(2.0) < polarization_after(30.0) - 0.1


def test_reflecting_box_keeps_agents_inside(make_sim):
    sim = make_sim(params={"n": 300, "box": 5.0, "radius": 0.5, "speed": 0.4, "noise": 1.0,
                           "boundary": "reflecting"}, steps=200)
    for _ in range(10):
        sim.step(20)
        x = sim.state()["x"]
        assert x.min() >= 0.0 and x.max() <= 5.0
