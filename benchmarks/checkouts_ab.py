"""Small swarms' cost per step in two or more checkouts of tflock, interleaved round by round.

    git worktree add /tmp/filed 0156bdb      # e.g. the code when issue 32 was filed
    python benchmarks/checkouts_ab.py --tree filed=/tmp/filed --tree now=. --rounds 7 --steps 100 \
        --out benchmarks/small-swarms-ab/checkouts.json
    python benchmarks/checkouts_ab.py --tree before=/tmp/before --tree now=. --recorded \
        configs/papers/samiloglu-s1-bounded-b1.toml configs/papers/formation-s1-1.toml --repeats 3

Each checkout runs in a process of its own (its own ``tflock`` on ``PYTHONPATH``, its own kernels), set up once per
case: `tflock bench`'s workload (the model's default config at N agents, density kept; ``case_config``) with
metrics every 10 steps (``--metrics-every``), or a paper config without its recording, stepped 20 steps and saved.
``--case MODEL:N`` (repeatable) replaces the small-swarm cases, e.g. ``--case vicsek:1000000 --metrics-every 1
--steps 5`` for a large run's cost per step with metrics every step. Each round then
restores that state in every checkout in turn and times ``Simulation.step(steps)``, so the checkouts alternate
within seconds of each other. Prints and writes JSON: ms per step, median (min-max) over the rounds, and each
checkout's speed-up over the first one given.

With ``--recorded CONFIG ...`` it times paper configs as a user runs them instead: per repeat and checkout, a fresh
process builds ``Simulation(config, record=PATH)`` (its start-up) and times its ``run()`` and ``close()``, the
checkouts alternating; it prints and writes each one's seconds. With ``--cli`` too, each run is ``tflock sim
--config CONFIG --out PATH`` and the run's time is the wall time its summary reports less its start-up.
"""

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

CASES = [("vicsek", 10), ("vicsek", 100), ("vicsek", 1000), ("potential", 10), ("potential", 100),
         ("potential", 1000), ("configs/papers/tanner-fixed.toml", 10),
         ("configs/papers/samiloglu-s1-bounded-b1.toml", 50)]
READY = "ready"


def case_simulation(name: str, n: int, metrics_every: int = 10) -> Any:  # a Simulation of the tflock on the path
    """A case's Simulation, with no end in sight: a paper config without its recording, or `tflock bench`'s
    workload of a model at N agents with metrics every `metrics_every` steps."""
    from tflock.bench import BenchCase, case_config
    from tflock.simulation import Simulation

    if name.endswith(".toml"):
        return Simulation(name, steps=10**9, record=False)
    config = case_config(BenchCase(model=name, n=n))
    config["steps"] = 10**9
    config["log"] = {"metrics_every": metrics_every}
    return Simulation(config)


def worker(name: str, n: int, steps: int, metrics_every: int) -> None:
    """Set up one case, then time `steps` steps from the saved state for every "round" line on stdin."""
    import taichi as ti

    import tflock

    sim = case_simulation(name, n, metrics_every)
    sim.step(20)
    start = (sim.model.checkpoint(), sim.model.step_index)
    print(READY, Path(tflock.__file__).parent, flush=True)
    for line in sys.stdin:
        if line.strip() != "round":
            break
        sim.model.restore(*start)
        ti.sync()
        t0 = time.perf_counter()
        sim.step(steps)
        ti.sync()
        print(json.dumps(1e3 * (time.perf_counter() - t0) / steps), flush=True)
    sim.close()


def recorded_worker(config: str, out: str) -> None:
    """Build the simulation with its recording at `out`, then time run() and close(); print both times."""
    from tflock.simulation import Simulation

    t0 = time.perf_counter()
    sim = Simulation(config, record=out)
    t1 = time.perf_counter()
    sim.run()
    sim.close()
    print(json.dumps({"start_up_s": t1 - t0, "run_close_s": time.perf_counter() - t1}), flush=True)


def cli_run(tree: Path, config: str, out: Path) -> dict:
    """`tflock sim --config CONFIG --out OUT` of a checkout, as a user runs it: the start-up and the wall time its
    summary reports, the run (their difference: the steps, metrics, frames and closing the files) and the process's
    own wall time (imports included)."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "tflock", "sim", "--config", str(tree / config), "--out", str(out)],
                          cwd=tree, env={**os.environ, "PYTHONPATH": str(tree), "COLUMNS": "200"},
                          capture_output=True, text=True, check=True)
    process = time.perf_counter() - t0
    summary = done.stdout + done.stderr
    start_up, wall = (float(re.search(rf"{name}\s*│\s*([0-9.]+) s", summary).group(1))
                      for name in ("start-up", "wall time"))
    return {"start_up_s": start_up, "run_close_s": round(wall - start_up, 3), "wall_s": wall,
            "process_s": round(process, 3)}


def run_recorded(trees: dict[str, Path], config: str, repeats: int, scratch: Path, cli: bool = False) -> dict:
    """`repeats` runs of a paper config with its recording in each checkout, alternating; `cli`: each run is
    :func:`cli_run`."""
    row: dict = {"config": config, **{label: [] for label in trees}}
    for _ in range(repeats):
        for label, tree in trees.items():
            out = scratch / f"{label}.rrd"
            for old in (out, out.with_suffix(".metrics.csv")):
                old.unlink(missing_ok=True)
            if cli:
                row[label].append(cli_run(tree, config, out))
                continue
            done = subprocess.run([sys.executable, __file__, "--recorded-worker", str(tree / config), str(out)],
                                  cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True,
                                  text=True, check=True)
            row[label].append(json.loads(done.stdout.strip().splitlines()[-1]))
    return row


def _reply(proc: subprocess.Popen) -> str:
    """The worker's next line of its own (Taichi prints a banner to stdout first)."""
    while True:
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError("a worker stopped; run it alone to see why")
        if line.startswith(READY) or line[:1].isdigit():
            return line.strip()


def run_case(trees: dict[str, Path], name: str, n: int, rounds: int, steps: int, metrics_every: int = 10) -> dict:
    procs = {}
    for label, tree in trees.items():
        case = str(tree / name) if name.endswith(".toml") else name
        procs[label] = subprocess.Popen(
            [sys.executable, __file__, "--worker", case, str(n), str(steps), str(metrics_every)], cwd=tree,
            env={**os.environ, "PYTHONPATH": str(tree)}, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, text=True)
    for label, proc in procs.items():  # each checkout runs its own code
        package = Path(_reply(proc).split(" ", 1)[1])
        if not package.is_relative_to(trees[label]):
            raise RuntimeError(f"{label} imported tflock from {package}, not from {trees[label]}")
    times: dict[str, list[float]] = {label: [] for label in trees}
    for r in range(rounds + 1):  # round 0 warms up (compiles what the first steps did not): not kept
        for label, proc in procs.items():
            proc.stdin.write("round\n")
            proc.stdin.flush()
            value = float(_reply(proc))
            if r:
                times[label].append(value)
    for proc in procs.values():
        proc.stdin.write("stop\n")
        proc.stdin.flush()
        proc.wait()
    row: dict = {"case": name, "n": n}
    for label, values in times.items():
        row[label] = {"median": statistics.median(values), "min": min(values), "max": max(values)}
    first = next(iter(trees))
    row["speedup_over_" + first] = {label: row[first]["median"] / row[label]["median"] for label in trees}
    return row


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--recorded-worker":
        recorded_worker(sys.argv[2], sys.argv[3])
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("--tree", action="append", required=True, help="label=path of a checkout (two or more)")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--recorded", nargs="+", default=None, metavar="CONFIG",
                    help="time these configs with their recordings (run + close) instead of the step cases")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each recorded config per checkout")
    ap.add_argument("--cli", action="store_true", help="with --recorded: run each as `tflock sim --config CONFIG`")
    ap.add_argument("--case", action="append", default=None, metavar="MODEL:N",
                    help="a step case instead of the small-swarm ones (repeatable)")
    ap.add_argument("--metrics-every", type=int, default=10, help="the step cases' metrics cadence")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    cases = CASES if a.case is None else [(c.split(":")[0], int(float(c.split(":")[1]))) for c in a.case]
    trees = {label: Path(path).resolve() for label, path in (t.split("=", 1) for t in a.tree)}
    load = [round(v, 2) for v in os.getloadavg()]
    rows = []
    if a.recorded:
        with tempfile.TemporaryDirectory() as scratch:
            for config in a.recorded:
                row = run_recorded(trees, config, a.repeats, Path(scratch), a.cli)
                rows.append(row)
                what = "tflock sim, wall - start-up" if a.cli else "run + close"
                print(f"{Path(config).stem:28s} {what}, s: " + "  ".join(
                    f"{label} " + ", ".join(f"{r['run_close_s']:.2f}" for r in row[label]) for label in trees),
                    flush=True)
    for name, n in [] if a.recorded else cases:  # the step cases, unless recorded configs were asked for
        row = run_case(trees, name, n, a.rounds, a.steps, a.metrics_every)
        rows.append(row)
        first = next(iter(trees))
        print(f"{Path(name).stem:28s} N={n:7d} " + "  ".join(
            f"{label} {row[label]['median']:.3f} ({row[label]['min']:.3f}-{row[label]['max']:.3f})"
            f" {row['speedup_over_' + first][label]:.2f}x" for label in trees), flush=True)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({
            "command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"),
            "load_average": {"start": load, "end": [round(v, 2) for v in os.getloadavg()]},
            "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
            "trees": {label: str(path) for label, path in trees.items()}, "results": rows}, indent=1))


if __name__ == "__main__":
    main()
