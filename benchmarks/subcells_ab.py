"""One `tflock bench` case (4 turns) with the metrics' components pass on CUDA switched as chosen: prints one JSON
line.

    python benchmarks/subcells_ab.py VARIANT MODEL N STATE [BOX]     (ARCH=cpu in the environment for the CPU)

VARIANT: ``cpu-switch`` (the CPU's switch to the sub-cell pass, at 3 agents a sub-cell: CUDA's until 2026-11-28),
``pairs`` (the pairs pass always) or ``now`` (the arch's own switch, tflock.components.SUBCELL_OCCUPANCY); BOX:
``params.box`` of the default config before the bench scales it to N (the density). Each case in its own process;
``benchmarks/cuda-subcells-ab.jsonl`` holds the runs of 2026-11-28 (their ``default`` is today's ``cpu-switch``)."""
import json
import os
import sys

from tflock import bench, components

variant, model, n, state = sys.argv[1], sys.argv[2], int(float(sys.argv[3])), sys.argv[4]
overrides = (f"params.box={sys.argv[5]}",) if len(sys.argv) > 5 else ()
arch = os.environ.get("ARCH", "cuda")
if variant == "pairs":
    components.SUBCELL_OCCUPANCY[arch] = (float("inf"), float("inf"))
elif variant == "cpu-switch":
    components.SUBCELL_OCCUPANCY[arch] = components.SUBCELL_OCCUPANCY["cpu"]
bench.LOG_TURNS = 4
case = bench.BenchCase(model=model, n=n, state=state, develop_steps=300 if model == "vicsek" else 100, repeats=10,
                       arch=arch, peers=False, overrides=overrides)
r = bench.run_case(case)
print(json.dumps({"variant": variant, "model": model, "n": n, "state": state, "overrides": overrides,
                  "step": r.ms_median, "run": r.run_ms_median, "run_min": r.run_ms_min, "run_max": r.run_ms_max,
                  "metrics": r.metrics_ms, "neighbours": r.mean_neighbors}))
