"""How much work the Vicsek sums pass would do with other cell layouts (issue 26, target 4): a count, not a timing.

    python benchmarks/vicsek_cell_layouts.py N STEPS [--out FILE.json]

From the state of `tflock bench`'s Vicsek workload at N agents after STEPS steps (periodic box, density 2, R = 1),
the pass's lane iterations (over its lane blocks of 8 agents, the candidates each block scans: the agents of the
stencil's rows over the block's run of cells, what the kernel's inner loop runs over) for

* ``R``: today's cells of side R (3 x 3 stencil), a row's consecutive cells joined into a run while they hold at most
  8 agents, agents in id order within a cell;
* ``R/2``: cells of side R/2 (5 x 5 stencil), runs joined the same way (the candidate the issue names);
* ``R, x-sorted``: today's cells with each cell's agents sorted by x, each block scanning only the candidates within
  [its smallest x - R, its largest x + R] of each stencil row (whose cells, each sorted by x, lie in x order).

Runs are cut as :func:`tflock.neighbors.cut_runs` cuts them, less its rule on empty cells; the box's edge rows and
columns are left out of the x-sorted count (their spans wrap).
"""

import argparse
import json
import platform
import sys
import time

import numpy as np

from tflock.bench import BenchCase, case_config
from tflock.simulation import Simulation

LANES = 8


def runs_of(counts_row: np.ndarray) -> list[tuple[int, int, int]]:
    """(x0, x1, agents) of each run of cells [x0, x1) in one row of cell counts."""
    out, x0, side = [], 0, len(counts_row)
    while x0 < side:
        if counts_row[x0] == 0:
            x0 += 1
            continue
        x1, agents = x0 + 1, int(counts_row[x0])
        while x1 < side and agents + counts_row[x1] <= LANES:
            agents += int(counts_row[x1])
            x1 += 1
        out.append((x0, x1, agents))
        x0 = x1
    return out


def cells_of(x: np.ndarray, box: float, per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """Each agent's cell (column, row) for cells of side box / per_side, and the agents per cell (row, column)."""
    cell = np.minimum((x / (box / per_side)).astype(np.int64), per_side - 1)
    counts = np.bincount(cell[:, 1] * per_side + cell[:, 0], minlength=per_side * per_side)
    return cell, counts.reshape(per_side, per_side)


def stencil_iterations(x: np.ndarray, box: float, per_side: int, reach: int) -> dict[str, float]:
    """Lane iterations, blocks and lane use for cells of side box / per_side and a stencil of +-reach cells."""
    _, counts = cells_of(x, box, per_side)
    padded = np.pad(counts, reach, mode="wrap")  # periodic
    rows = sum(padded[reach + d: reach + d + per_side, :] for d in range(-reach, reach + 1))
    prefix = np.concatenate([np.zeros((per_side, 1), np.int64), np.cumsum(rows, axis=1)], axis=1)
    iterations = blocks = agents = 0
    for r in range(per_side):
        for x0, x1, a in runs_of(counts[r]):
            nb = -(-a // LANES)
            iterations += nb * (prefix[r, x1 + 2 * reach] - prefix[r, x0])  # padded columns x0 - reach .. x1 + reach
            blocks += nb
            agents += a
    return {"lane_iterations": float(iterations), "blocks": blocks, "lane_use": agents / (LANES * blocks)}


def x_sorted_iterations(x: np.ndarray, box: float, per_side: int, radius: float) -> dict[str, float]:
    """Lane iterations of cells of side R sorted by x, each block's scan cut to its x-window (inner cells only)."""
    cell, counts = cells_of(x, box, per_side)
    counts = counts.ravel()
    order = np.lexsort((x[:, 0], cell[:, 0], cell[:, 1]))  # row, then column, then x
    xs = x[order, 0]
    start = np.concatenate([[0], np.cumsum(counts)])
    iterations = today = blocks = 0
    for r in range(1, per_side - 1):
        for x0, x1, a in runs_of(counts[r * per_side: (r + 1) * per_side]):
            if x0 == 0 or x1 >= per_side:
                continue
            a0 = start[r * per_side + x0]
            spans = [(start[q * per_side + x0 - 1], start[q * per_side + x1 + 1]) for q in (r - 1, r, r + 1)]
            for i0 in range(0, a, LANES):
                lane_x = xs[a0 + i0: a0 + min(i0 + LANES, a)]
                lo, hi = lane_x.min() - radius, lane_x.max() + radius
                blocks += 1
                for s, e in spans:
                    today += e - s
                    iterations += np.searchsorted(xs[s:e], hi, "right") - np.searchsorted(xs[s:e], lo, "left")
    return {"lane_iterations": float(iterations), "blocks": blocks, "same_blocks_today": float(today)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("n", type=float)
    ap.add_argument("steps", type=int)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    n = int(a.n)
    sim = Simulation(case_config(BenchCase(model="vicsek", n=n, state="developed", develop_steps=a.steps, repeats=1)),
                     record=False)
    sim.model.advance(a.steps)
    x, box, radius = sim.model.state()["x"].astype(np.float64), sim.model.params.box, sim.model.params.radius
    side = int(box // radius)
    result = {"n": n, "steps": a.steps, "machine": platform.processor() or platform.machine(),
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "command": " ".join(sys.argv),
              "R": stencil_iterations(x, box, side, 1), "R/2": stencil_iterations(x, box, 2 * side, 2),
              "R, x-sorted": x_sorted_iterations(x, box, side, radius)}
    xs = result["R, x-sorted"]
    print(f"N = {n}, after {a.steps} steps: lane iterations, cells R {result['R']['lane_iterations'] / 1e6:.2f}M "
          f"(lane use {result['R']['lane_use']:.2f}); R/2 {result['R/2']['lane_iterations'] / 1e6:.2f}M "
          f"(lane use {result['R/2']['lane_use']:.2f}); R x-sorted, inner blocks "
          f"{xs['lane_iterations'] / 1e6:.2f}M against {xs['same_blocks_today'] / 1e6:.2f}M for the same blocks today")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
