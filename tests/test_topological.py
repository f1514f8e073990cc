"""The k nearest neighbours on the cell grid (tflock.topological) against the O(N^2) NumPy reference: the same
agents in the same order (nearest first, equal distances by the smaller id), in 2D and 3D, in every boundary, in
swarms that need many rings (stragglers in open space, a few agents in a big box, k close to n), on a lattice where
most distances tie, and in a batch of replicas that must never see each other."""

import numpy as np
import pytest
import taichi as ti
from conftest import PRECISION

from tflock import reference as ref
from tflock.neighbors import CellGrid
from tflock.topological import cell_side, find_nearest, nearest

BOUNDARIES = ["periodic", "reflecting", "open"]


def kernel_neighbours(engine, x: np.ndarray, k: int, boundary: str, box: float, replicas: int = 1,
                      lanes: bool = False):
    """(agent ids of the k nearest, nearest first, in agent order: shape (n, k); rings searched per agent), by
    :func:`nearest` or (`lanes`) :func:`find_nearest`."""
    n, dim = x.shape
    real = engine.real
    grid = CellGrid(n, dim, boundary, box, cell_side(n // replicas, k, dim, box), real, replicas)
    pos = ti.ndarray(ti.f64 if PRECISION == "f64" else ti.f32, (dim, n))
    pos.from_numpy(np.ascontiguousarray(x.T, dtype=real))
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(np.arange(n, dtype=np.int32))
    grid.build(pos, ids)
    g = grid.geometry
    nbr = ti.ndarray(ti.i32, (k, n))
    rings = ti.ndarray(ti.i32, n)
    if lanes:
        find_nearest(grid, k, box, nbr, rings)
    else:
        nearest(n, n // replicas, box, g.cell_size, g.cells_per_side, g.n_buckets, k, g.boundary, dim, grid.start,
                grid.mixed, grid.pos_sorted, grid.coords_sorted, grid.id_sorted, nbr, rings)
    id_sorted = grid.id_sorted.to_numpy()
    out = np.empty((n, k), dtype=np.int64)
    out[id_sorted] = id_sorted[nbr.to_numpy()].T
    found = np.empty(n, dtype=np.int64)
    found[id_sorted] = rings.to_numpy()
    return out, found


def reference_neighbours(x: np.ndarray, k: int, boundary: str, box: float) -> np.ndarray:
    """The k nearest of every agent from the reference adjacency, ordered by (squared distance, id)."""
    a = ref.topological_adjacency(x, k, boundary, box)
    d = ref.displacements(x, boundary, box)
    d2 = (d * d).sum(axis=2)
    out = np.empty((len(x), k), dtype=np.int64)
    for i in range(len(x)):
        j = np.flatnonzero(a[i])
        out[i] = j[np.lexsort((j, d2[i, j]))]
    return out


#: n, box; every case takes k = 6 (each k is a kernel of its own to compile, and the code is the same for all k)
CASES = {
    "uniform": (300, 10.0),
    "few cells": (50, 10.0),
    "dense": (200, 3.0),
    "k = n - 1": (7, 20.0),
}
K = 6


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("dim", [2, 3])
def test_nearest_matches_reference(engine, dim, boundary, case):
    (n, box), k = CASES[case], K
    rng = np.random.default_rng(dim * 100 + len(case))
    x = rng.uniform(0, box, (n, dim)).astype(engine.real)
    if boundary == "open":
        x[:4] *= 6  # stragglers: their searches cross many empty rings
    got, rings = kernel_neighbours(engine, x, k, boundary, box)
    np.testing.assert_array_equal(got, reference_neighbours(x, k, boundary, box))
    if boundary == "open":
        assert rings.max() > 5


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_ties_go_to_the_smaller_id(engine, boundary):
    """On a square lattice (exact coordinates) most candidates tie: the order is by id, whatever the cells."""
    side = 7
    xs, ys = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5)
    x = np.stack([xs.ravel(), ys.ravel()], axis=1)
    perm = np.random.default_rng(1).permutation(len(x))  # ids not in lattice order
    x = x[perm].astype(engine.real)
    got, _ = kernel_neighbours(engine, x, K, boundary, float(side))
    np.testing.assert_array_equal(got, reference_neighbours(x, K, boundary, float(side)))


def test_replicas_never_see_each_other(engine):
    """A batch of three replicas stacked at the same place: each agent's neighbours come from its own replica and
    are those of the replica alone."""
    n, box, k = 40, 4.0, K
    rng = np.random.default_rng(5)
    systems = [rng.uniform(0, box, (n, 2)).astype(engine.real) for _ in range(3)]
    got, _ = kernel_neighbours(engine, np.concatenate(systems), k, "periodic", box, replicas=3)
    for r, x in enumerate(systems):
        np.testing.assert_array_equal(got[r * n:(r + 1) * n] - r * n, reference_neighbours(x, k, "periodic", box))


def test_uniform_swarm_needs_two_rings(engine):
    """The cell side makes the first ring enough for nearly every agent of a uniform swarm (the cost the benchmark
    measures follows this)."""
    rng = np.random.default_rng(2)
    box = 40.0
    x = rng.uniform(0, box, (3200, 2)).astype(engine.real)
    _, rings = kernel_neighbours(engine, x, K, "periodic", box)
    assert np.mean(rings <= 2) > 0.9
