"""The components pass of a lane-wise metrics step, alone, at N agents from saved states (issue 26).

    python benchmarks/components_pass.py [--model vicsek|potential] [--n 1e6] [--develop 300] [--passes 10]
                                         [--states DIR]

From `tflock bench`'s workload (the default config at N agents, density kept), the uniform start (after one step)
and the state after ``--develop`` more steps are saved once as ``DIR/<model>-<n>-<state>.npz`` and restored for
every later call, so that two checkouts time the same states: run it in each, one after the other, e.g.
``PYTHONPATH=<worktree> python benchmarks/components_pass.py``. Per state it prints the median and the fastest of
``--passes`` timed passes (one untimed first), each the model's components kernel and ``LaneComponents.finish``
(its joins across stripes and the count), and the clusters found (the same in every checkout that finds them).
"""

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import taichi as ti

from tflock.bench import BenchCase, case_config
from tflock.models import vicsek as vicsek_model
from tflock.simulation import Simulation


def saved_state(model, path: Path, steps: int) -> None:
    """Restore the state saved at `path`, or make it (`steps` steps from the model's start) and save it."""
    if not path.exists():
        model.advance(steps)
        np.savez(path, step=model.step_index, **model.state())
    saved = np.load(path)
    model.set_state({k: saved[k] for k in saved.files if k != "step"}, int(saved["step"]))
    model._ensure_grid()


def vicsek_pass(model):
    """Vicsek's metrics neighbour pass with the components, and its finish (the sorted headings made once)."""
    grid = model.grid
    vicsek_model._headings(model.n_total, grid.order, model.theta, model.trig, model.payload)
    return model._components_pass


def potential_pass(model):
    """`potential`'s components pass (pair sums of the earlier candidates, labels), and its finish."""
    return model._components_pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("vicsek", "potential"), default="vicsek")
    parser.add_argument("--n", type=float, default=1e6)
    parser.add_argument("--develop", type=int, default=None, help="steps to the developed state (300 Vicsek, 100 "
                                                                    "potential, as the bench's cases)")
    parser.add_argument("--passes", type=int, default=10)
    parser.add_argument("--states", type=Path, default=Path("/tmp/tflock-components-states"))
    args = parser.parse_args()
    n = int(args.n)
    develop = args.develop if args.develop is not None else (300 if args.model == "vicsek" else 100)
    args.states.mkdir(parents=True, exist_ok=True)
    sim = Simulation(case_config(BenchCase(model=args.model, n=n, state="uniform", develop_steps=0, repeats=3)),
                     record=False)
    model = sim.model
    start = (model.checkpoint(), model.step_index)
    for state, steps in (("uniform", 1), (f"after-{develop}", 1 + develop)):
        model.restore(*start)
        saved_state(model, args.states / f"{args.model}-{n}-{state}.npz", steps)
        run = (vicsek_pass if args.model == "vicsek" else potential_pass)(model)
        times = []
        for _ in range(args.passes + 1):
            ti.sync()
            t0 = time.perf_counter()
            clusters = run()
            times.append(1e3 * (time.perf_counter() - t0))
        print(f"{args.model} {state:10s} pass {statistics.median(times[1:]):6.2f} ms (fastest {min(times[1:]):.2f})"
              f"  clusters, largest: {clusters}")


if __name__ == "__main__":
    main()
