"""Small swarms' cost per step before and after issue 32, interleaved in one process.

    python benchmarks/small_swarms.py [--rounds 7] [--steps 100] [--out benchmarks/small-swarms-ab.json]

Each case is `tflock bench`'s workload (the model's default config at N agents, density kept; `tflock.bench.
case_config`) with metrics every 10 steps, or a paper config. Per round, from the same state, the same steps run
four ways, one after the other:

* **before**: Taichi's own kernel call path and the step loop as it was (``advance(1)`` every step, the guard and
  the metrics at their steps), the code of main before issue 32 (the old loop is copied below), and the lane-wise
  steps as one launch per kernel (``vicsek.FUSED_MAX_AGENTS = potential.FUSED_MAX_N = 0``);
* **launches**: tflock's kernel call path (:mod:`tflock.taichi_launch`) and ``Simulation.step`` (the steps between
  two observations as one ``advance(k)``), each step still its own launches (a fixed graph's too);
* **after**: as ``launches``, with runs of steps in one launch each (Vicsek's ``_lane_wise_steps``, potential's
  ``_lane_steps`` and, on a fixed graph, ``_steps_fixed``);
* **numpy** (at N <= 1000): the plain NumPy step of the same model (:mod:`tflock.reference`), without metrics.

Prints and writes JSON: ms per step, median (min-max) over the rounds, and the ratios of the medians.
"""

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import taichi as ti
from checkouts_ab import case_simulation
from taichi.lang.kernel_impl import Kernel

import tflock.models.potential as potential
import tflock.models.vicsek as vicsek
from tflock.bench import machine
from tflock.simulation import Simulation

CASES = [("vicsek", 10), ("vicsek", 100), ("vicsek", 1000), ("potential", 10), ("potential", 100),
         ("potential", 1000), ("configs/papers/tanner-fixed.toml", 10),
         ("configs/papers/samiloglu-s1-bounded-b1.toml", 50)]


def old_step(sim: Simulation, steps: int) -> None:
    """Simulation.step before issue 32: one advance(1) per step (no checkpoints here)."""
    for _ in range(steps):
        if sim._frame_due(sim.model.step_index + 1):
            sim.model.draw_next(sim._selected)
        sim.model.advance(1)
        t = sim.model.step_index
        last = t == sim.config.steps
        full = last or sim._metrics_due(t)
        if full or sim._frame_due(t):
            sim._guard(full)
        sim._observe(force=last)


def numpy_step(sim: Simulation):
    """The plain NumPy step of the model on its current state (a closure), or None."""
    model = sim.model
    state = model.state()
    if model.name == "vicsek" and model.params.async_bound == 1:
        from tflock.reference import vicsek_step

        return lambda: vicsek_step(state["x"], state["theta"], model.step_index, model.params, model.seed)
    if model.name == "potential":
        from tflock.reference.potential import graph_edges, potential_step

        edges = graph_edges(model.params, model.seed)
        return lambda: potential_step(state["x"], state["v"], model.params, edges)
    return None


def timed(fn, steps: int) -> float:
    ti.sync()
    t0 = time.perf_counter()
    fn(steps)
    ti.sync()
    return 1e3 * (time.perf_counter() - t0) / steps


def run_case(name: str, n: int, rounds: int, steps: int) -> dict:
    sim = case_simulation(name, n)
    fast = Kernel.__call__
    sim.step(20)
    start = (sim.model.checkpoint(), sim.model.step_index)
    peer = numpy_step(sim)
    fused = vicsek.FUSED_MAX_AGENTS, potential.FUSED_MAX_N
    ways = ("before", "launches", "after")
    times: dict[str, list[float]] = {"before": [], "launches": [], "after": [], "numpy": []}
    for r in range(rounds + 1):  # round 0 warms up (compiles the fused kernels, makes the call plans): not kept
        for way in ways:
            sim.model.restore(*start)
            Kernel.__call__ = fast.original if way == "before" else fast
            vicsek.FUSED_MAX_AGENTS, potential.FUSED_MAX_N = fused if way == "after" else (0, 0)
            step = (lambda k: old_step(sim, k)) if way == "before" else sim.step
            try:
                times[way].append(timed(step, steps))
            finally:
                Kernel.__call__ = fast
                vicsek.FUSED_MAX_AGENTS, potential.FUSED_MAX_N = fused
        if peer is not None and r:
            times["numpy"].append(timed(lambda k: [peer() for _ in range(k)], max(1, steps // 10)))
    sim.close()
    for way in ways:
        times[way] = times[way][1:]
    out = {"case": name, "n": n, "metrics_every": sim.config.log.metrics_every}
    for way, values in times.items():
        if values:
            out[way] = {"median": statistics.median(values), "min": min(values), "max": max(values)}
    out["speedup"] = out["before"]["median"] / out["after"]["median"]
    out["launches_over_after"] = out["launches"]["median"] / out["after"]["median"]
    if "numpy" in out:
        out["numpy_over_after"] = out["numpy"]["median"] / out["after"]["median"]
    return out


def _spread(row: dict, way: str) -> str:
    if way not in row:
        return "-"
    return f"{row[way]['median']:.3f} ({row[way]['min']:.3f}-{row[way]['max']:.3f})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    rows = []
    load = [round(v, 2) for v in os.getloadavg()]  # 1, 5 and 15 minutes
    for name, n in CASES:
        row = run_case(name, n, a.rounds, a.steps)
        rows.append(row)
        print(f"{name} n={n}: before {_spread(row, 'before')} launches {_spread(row, 'launches')} "
              f"after {_spread(row, 'after')} ms/step, {row['speedup']:.2f}x, {row['launches_over_after']:.2f}x; "
              f"numpy {_spread(row, 'numpy')}", flush=True)
    if a.out is not None:
        payload = {"command": "python " + " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"),
                   "load_average": {"start": load, "end": [round(v, 2) for v in os.getloadavg()]},
                   "machine": machine(), "python": platform.python_version(), "numpy": np.__version__,
                   "results": rows}
        a.out.write_text(json.dumps(payload, indent=1) + "\n")


if __name__ == "__main__":
    main()
