"""The lane-wise search for the k nearest (tflock.topological.find_nearest on a 2D box grid on the CPU) against the
O(N^2) NumPy reference and the scalar search: the same agents in the same order and the same rings, in periodic and
reflecting boxes, with ties on a lattice, agents crowded at the box's edges, a batch of replicas, and agents whose
lanes cannot settle their k nearest from rings 0 and 1 and are searched again."""

import numpy as np
import pytest
from conftest import ARCH
from test_topological import K, kernel_neighbours, reference_neighbours

BOXES = ["periodic", "reflecting"]


def check(engine, x: np.ndarray, boundary: str, box: float, replicas: int = 1) -> np.ndarray:
    """Assert the lane-wise search gives the reference's neighbours (per replica) and the scalar search's rings;
    return the rings."""
    got, rings = kernel_neighbours(engine, x, K, boundary, box, replicas, lanes=True)
    m = len(x) // replicas
    for r in range(replicas):
        want = reference_neighbours(x[r * m:(r + 1) * m], K, boundary, box) + r * m
        np.testing.assert_array_equal(got[r * m:(r + 1) * m], want)
    _, scalar_rings = kernel_neighbours(engine, x, K, boundary, box, replicas)
    np.testing.assert_array_equal(rings, scalar_rings)
    return rings


pytestmark = pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise search runs on the CPU")


@pytest.mark.parametrize("boundary", BOXES)
def test_uniform_and_crowded_edges(engine, boundary):
    """A uniform swarm with a quarter of its agents in thin strips along the four walls (or periodic edges), and a
    few stragglers in an empty corner region whose lanes need more rings (searched again)."""
    rng = np.random.default_rng(3)
    box = 16.0
    x = rng.uniform(0, box, (500, 2))
    x = x[(x[:, 0] > 6) | (x[:, 1] > 6)]  # an empty corner ...
    x[:4] = rng.uniform(1, 5, (4, 2))  # ... with stragglers in it
    edge = rng.uniform(0, box, (150, 2))
    axis = rng.integers(0, 2, len(edge))
    edge[np.arange(len(edge)), axis] = np.where(rng.random(len(edge)) < 0.5, rng.uniform(0, 0.05, len(edge)),
                                                box - rng.uniform(1e-6, 0.05, len(edge)))
    x = np.concatenate([x, edge]).astype(engine.real)
    rings = check(engine, x, boundary, box)
    assert rings.max() > 2  # the stragglers' searches went beyond ring 1: searched again


@pytest.mark.parametrize("boundary", BOXES)
def test_lattice_ties(engine, boundary):
    """On a square lattice most candidates tie: the order is by id, as the scalar search's."""
    side = 9
    xs, ys = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5)
    x = np.stack([xs.ravel(), ys.ravel()], axis=1)
    x = x[np.random.default_rng(4).permutation(len(x))].astype(engine.real)
    check(engine, x, boundary, float(side))


@pytest.mark.parametrize("boundary", BOXES)
def test_replicas(engine, boundary):
    """Three replicas, each a uniform swarm in the same box: each agent's neighbours come from its own replica."""
    rng = np.random.default_rng(6)
    box = 6.0
    x = np.concatenate([rng.uniform(0, box, (60, 2)) for _ in range(3)]).astype(engine.real)
    check(engine, x, boundary, box, replicas=3)


@pytest.mark.parametrize("boundary", BOXES)
@pytest.mark.parametrize("n, box", [(7, 20.0), (30, 5.0)])
def test_few_cells(engine, boundary, n, box):
    """Grids of 1 to 3 cells a side, where rings 0 and 1 hold every cell (a periodic row is visited once whole)."""
    x = np.random.default_rng(n).uniform(0, box, (n, 2)).astype(engine.real)
    check(engine, x, boundary, box)
