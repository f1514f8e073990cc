"""The search for the k nearest agent by agent and lane-wise, alternated in one process.

    python benchmarks/topological_search.py [--n 1e6] [--rounds 7] [--out benchmarks/topological-search-ab.json]

A uniform swarm of density 2 in a periodic box (the `tflock bench` workload of Vicsek at N), k = 6, f32, every core.
Per round, one after the other on the same positions:

* **scalar**: :func:`tflock.topological.nearest`, agent by agent, on the grid it is sized for (``CELL_FACTOR``);
* **lanes**: :func:`tflock.topological.find_nearest`, lane-wise, on its own grid (``LANE_CELL_FACTOR``), the
  search again of the lanes left uncertain included.

Both must give every agent the same neighbours in the same order (checked once, before the timed rounds). Prints
and writes JSON: seconds per search, median (min-max) over the rounds, their ratio, the share of agents the
lane-wise search had to search again, and the load average before and after.
"""

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import taichi as ti

from tflock.bench import machine
from tflock.engine import init_engine

K = 6
DENSITY = 2.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=float, default=1e6)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--out", type=Path, default=Path("results/topological-search-ab.json"))
    args = parser.parse_args()
    engine = init_engine("cpu")
    from tflock.neighbors import CellGrid
    from tflock.topological import cell_side, find_nearest, nearest

    n = int(args.n)
    box = (n / DENSITY) ** 0.5
    x = np.random.default_rng(0).uniform(0, box, (n, 2)).astype(np.float32)
    pos = ti.ndarray(ti.f32, (2, n))
    pos.from_numpy(np.ascontiguousarray(x.T))
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(np.arange(n, dtype=np.int32))
    grids = {}
    for name, lanes in (("scalar", False), ("lanes", True)):
        grid = CellGrid(n, 2, "periodic", box, cell_side(n, K, 2, box, lanes=lanes), np.float32)
        grid.build(pos, ids)
        grids[name] = (grid, ti.ndarray(ti.i32, (K, n)), ti.ndarray(ti.i32, n))

    def search(name: str) -> float:
        grid, nbr, rings = grids[name]
        g = grid.geometry
        start = time.perf_counter()
        if name == "scalar":
            nearest(n, n, box, g.cell_size, g.cells_per_side, g.n_buckets, K, g.boundary, 2, grid.start, grid.mixed,
                    grid.pos_sorted, grid.coords_sorted, grid.id_sorted, nbr, rings)
        else:
            find_nearest(grid, K, box, nbr, rings)
        ti.sync()
        return time.perf_counter() - start

    def neighbours(name: str) -> np.ndarray:
        grid, nbr, _ = grids[name]
        slots_to_ids = grid.id_sorted.to_numpy()
        out = np.empty((K, n), dtype=np.int64)
        out[:, slots_to_ids] = slots_to_ids[nbr.to_numpy()]
        return out

    load_before = os.getloadavg()
    for name in grids:  # compile, and check
        search(name)
    if not np.array_equal(neighbours("scalar"), neighbours("lanes")):
        raise SystemExit("the two searches gave different neighbours")
    rings = grids["lanes"][2].to_numpy()
    times: dict[str, list[float]] = {name: [] for name in grids}
    for _ in range(args.rounds):
        for name in grids:
            times[name].append(search(name))
    summary = {name: {"median_s": statistics.median(t), "min_s": min(t), "max_s": max(t), "all_s": t}
               for name, t in times.items()}
    result = {
        "command": " ".join(["python benchmarks/topological_search.py", *sys.argv[1:]]),
        "machine": machine(),
        "engine": engine.describe(),
        "n": n, "k": K, "density": DENSITY, "boundary": "periodic",
        "same_neighbours": True,
        "searched_again": float(np.mean(rings > 2)),
        "load_before": load_before, "load_after": os.getloadavg(),
        "results": summary,
        "ratio_of_medians": summary["scalar"]["median_s"] / summary["lanes"]["median_s"],
    }
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    for name, s in summary.items():
        print(f"{name}: {s['median_s']:.3f} s ({s['min_s']:.3f}-{s['max_s']:.3f})")
    print(f"ratio {result['ratio_of_medians']:.1f}x; searched again {result['searched_again']:.2%}; "
          f"load {load_before[0]:.1f} -> {result['load_after'][0]:.1f}")


if __name__ == "__main__":
    main()
