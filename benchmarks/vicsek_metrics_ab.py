"""The lane-wise Vicsek metrics pass of an earlier commit against this tree's, interleaved in one process.

    python benchmarks/vicsek_metrics_ab.py --old COMMIT [--n 1e6] [--develop 0] [--rounds 9] [--out FILE.json]

The old commit's ``tflock/models/vicsek.py`` and ``tflock/lane_graph.py`` are read with ``git show`` into a
scratch folder and imported beside this tree's (the rest of tflock is this tree's). From `tflock bench`'s workload
(the default config at N agents, density kept; ``--develop`` steps first), per round, one after the other:

* **pass**: the metrics' neighbour pass with the components (``_neighbour_sums_graph``) and
  ``LaneComponents.finish``, old and new, on the same grid, with the plain neighbour pass for scale;
* **run**: from the same state, the plain step (``advance(1)``), and a run's step as ``tflock sim`` takes it with
  metrics every step (``metrics()``, ``advance(1)``, the non-finite check), old and new models.

Checks that both give the same metrics and the same trajectory, prints and writes JSON: ms, median (min-max) over
the rounds, and each run's step over its round's plain step.
"""

import argparse
import importlib
import inspect
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import taichi as ti

from tflock.bench import BenchCase, case_config, machine
from tflock.models import vicsek as new_vicsek
from tflock.simulation import Simulation
from tflock.space import boundary_code

ROOT = Path(__file__).resolve().parent.parent


def old_modules(commit: str, folder: Path):
    """The old commit's lane_graph and vicsek modules, imported from `folder` (vicsek importing that lane_graph)."""
    def show(path: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{path}"], check=True, capture_output=True,
                              text=True).stdout

    (folder / "old_lane_graph.py").write_text(show("tflock/lane_graph.py"))
    (folder / "old_vicsek.py").write_text(show("tflock/models/vicsek.py").replace("from tflock.lane_graph import",
                                                                                  "from old_lane_graph import"))
    sys.path.insert(0, str(folder))
    return importlib.import_module("old_lane_graph"), importlib.import_module("old_vicsek")


def timed(fn) -> float:
    ti.sync()
    t0 = time.perf_counter()
    fn()
    ti.sync()
    return 1e3 * (time.perf_counter() - t0)


def summary(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", required=True, help="the commit to compare with")
    parser.add_argument("--n", type=float, default=1e6)
    parser.add_argument("--develop", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    n = int(args.n)
    case = BenchCase(model="vicsek", n=n, state="developed" if args.develop else "uniform",
                     develop_steps=args.develop, repeats=args.rounds)
    sim = Simulation(case_config(case), record=False)
    new = sim.model
    new.advance(1 + args.develop)
    with tempfile.TemporaryDirectory() as tmp:
        old_graph, old_vicsek = old_modules(args.old, Path(tmp))
        old = old_vicsek.Vicsek(new.params, new.seed, sim.engine)
        start = (new.checkpoint(), new.step_index)
        old.restore(*start)
        old_metrics, new_metrics = old.metrics(), new.metrics()
        same_metrics = all(old_metrics[k] == new_metrics[k] or np.isnan(old_metrics[k]) and np.isnan(new_metrics[k])
                           for k in old_metrics)

        p, grid = new.params, new.grid
        g, boundary = grid.geometry, boundary_code(p.boundary)
        args_pass = (g.cells_per_side, p.radius, p.box, 0, boundary, grid.start, grid.runs(), grid.pos_sorted,
                     new.payload, new.sums)
        old_components = old_graph.LaneComponents(grid, sim.engine.threads)

        def graph_pass(module, components):
            kernel = module._neighbour_sums_graph
            serial = (components.stripes()[0] == 1,) if "serial" in inspect.signature(kernel).parameters else ()

            # finish takes R^2 in the run's precision, as the model passes it (R before 1c9ec64)
            squared = "r2" in inspect.signature(components.finish).parameters
            reach = float(grid.real(p.radius) ** 2) if squared else p.radius

            def run() -> None:
                kernel(*components.stripes(), *args_pass, components.parent, components.size, *serial)
                components.finish(reach, p.box, boundary)
            return run

        def plain(model):
            def run() -> float:
                model.restore(*start)
                return timed(lambda: model.advance(1))
            return run

        def run_step(model):
            def run() -> float:
                model.restore(*start)
                return timed(lambda: (model.metrics(), model.advance(1), model.first_non_finite()))
            return run

        new._ensure_grid()
        new_vicsek._headings(new.n_total, grid.order, new.theta, new.trig, new.payload)
        passes = {"plain pass": lambda: new_vicsek._neighbour_sums(g.total_buckets, *args_pass),
                  "old pass": graph_pass(old_vicsek, old_components),
                  "new pass": graph_pass(new_vicsek, new.components)}
        times: dict[str, list[float]] = {k: [] for k in passes}
        for _ in range(args.rounds + 1):  # the first round compiles
            for name, fn in passes.items():
                times[name].append(timed(fn))
        runs = {"old plain step": plain(old), "old run step": run_step(old), "new plain step": plain(new),
                "new run step": run_step(new)}
        times.update({k: [] for k in runs})
        for _ in range(args.rounds + 1):  # the first round compiles
            for name, fn in runs.items():
                times[name].append(fn())
        times = {k: v[1:] for k, v in times.items()}
        new.restore(*start)
        old.restore(*start)
        new.advance(3)
        old.advance(3)
        same_trajectory = all(np.array_equal(new.state()[k], old.state()[k]) for k in new.state())
    result = {"command": "python benchmarks/vicsek_metrics_ab.py " + " ".join(sys.argv[1:]), "machine": machine(),
              "date": time.strftime("%Y-%m-%d %H:%M"), "n": n, "develop_steps": args.develop, "rounds": args.rounds,
              "same_metrics": same_metrics, "same_trajectory": same_trajectory,
              "ms": {k: summary(v) for k, v in times.items()}}
    for who in ("old", "new"):
        ratios = [r / s for r, s in zip(times[f"{who} run step"], times[f"{who} plain step"], strict=True)]
        result[f"{who} run / plain"] = summary(ratios)
    for name, s in result["ms"].items():
        print(f"{name:16s} {s['median']:8.1f} ms ({s['min']:.1f}-{s['max']:.1f})")
    for who in ("old", "new"):
        s = result[f"{who} run / plain"]
        print(f"{who} run / plain   {s['median']:.2f} ({s['min']:.2f}-{s['max']:.2f})")
    print("same metrics:", same_metrics, "same trajectory:", same_trajectory)
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
