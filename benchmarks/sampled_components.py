"""Whether a Vicsek state has a giant cluster for a giant-skipping components algorithm (Afforest: Sutton, Ben-Nun &
Barak, IPDPS 2018) to skip: the R-graph's clusters, and what linking each agent to its first k neighbours at smaller
slots (the grid's cell order, as a half-stencil pass meets them) joins.

    python benchmarks/sampled_components.py N STEPS

The default config at N agents (the bench's scaling: density 2), after STEPS steps from the uniform start. Prints the
edges, the clusters and the largest one's share of the agents, and for k = 1, 2, 3 the sampled components, the share
of agents outside the sampled giant and of blocks of 8 consecutive slots holding one such agent (the blocks a
giant-skipping pass would still label). Needs scipy (``pip install -e '.[bench]'``).
"""

import sys

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tflock.bench import BenchCase, case_config
from tflock.simulation import Simulation


def components(n: int, u: np.ndarray, v: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the graph of n nodes and edges (u, v): their number and each node's label."""
    return connected_components(coo_matrix((np.ones(len(u)), (u, v)), shape=(n, n)), directed=False)


def main() -> None:
    n, steps = int(float(sys.argv[1])), int(sys.argv[2])
    sim = Simulation(case_config(BenchCase(model="vicsek", n=n, state="uniform", develop_steps=0, repeats=1)),
                     record=False)
    sim.model.advance(steps)
    model = sim.model
    box, radius = model.params.box, model.params.radius
    x = model.pos.to_numpy().T.astype(np.float64) % box
    per_side = int(box // radius)
    cell = (x * per_side / box).astype(np.int64).clip(0, per_side - 1)
    order = np.lexsort((np.arange(n), cell[:, 0], cell[:, 1]))  # cells row by row, agents by id within a cell
    slot = np.empty(n, dtype=np.int64)
    slot[order] = np.arange(n)
    pairs = cKDTree(x, boxsize=box).query_pairs(radius, output_type="ndarray")
    lo, hi = np.sort(slot[pairs], axis=1).T
    count, labels = components(n, lo, hi)
    print(f"N {n}, step {steps}: {len(lo)} edges (mean degree {2 * len(lo) / n:.1f}), {count} clusters, the largest "
          f"{np.bincount(labels).max() / n:.4f} of the agents")
    by_agent = np.lexsort((lo, hi))
    hi, lo = hi[by_agent], lo[by_agent]
    first = np.flatnonzero(np.r_[True, hi[1:] != hi[:-1]])
    rank = np.arange(len(hi)) - np.repeat(first, np.diff(np.r_[first, len(hi)]))  # 0: an agent's first neighbour
    for k in (1, 2, 3):
        kept = rank < k
        sampled, labels = components(n, hi[kept], lo[kept])
        outside = labels != np.argmax(np.bincount(labels))
        blocks = np.add.reduceat(outside.astype(np.int64), np.arange(0, n, 8)) > 0
        print(f"  k = {k}: {sampled} sampled components; outside the sampled giant {outside.mean():.3f} of the agents, "
              f"{blocks.mean():.3f} of the blocks of 8")


if __name__ == "__main__":
    main()
