"""Time the Vicsek `vector` step at large N (no logging): uniform start and developed flocks.

    python benchmarks/vicsek_step.py [--n 1000000] [--develop 300] [--repeats 20] [--threads 0]

Density 2 (box = sqrt(n / 2)), R = 1, v0 = 0.5, eta = 0.5, f32. Prints JSON with ms/step (median, min, max) of the
model step alone (grid build + update), the time to the first step (compile included), the time of one full
metrics evaluation (clusters included) and the mean neighbour count of each workload.
"""

import argparse
import json
import math
import platform
import statistics
import time

t_import = time.perf_counter()
import tflock  # noqa: E402
from tflock.engine import init_engine  # noqa: E402


def _time_steps(sim, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.model.advance(1)
        sim.sync()
        times.append(1e3 * (time.perf_counter() - t0))
    return times


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--develop", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0)
    a = ap.parse_args()
    engine = init_engine("cpu", a.threads, "f32")
    box = math.sqrt(a.n / 2)
    sim = tflock.Simulation(model="vicsek", steps=0, record=False,
                            params={"n": a.n, "box": box, "radius": 1.0, "speed": 0.5, "noise": 0.5})
    t0 = time.perf_counter()
    sim.model.advance(1)
    sim.sync()
    first = time.perf_counter() - t0
    import_to_first_step = time.perf_counter() - t_import
    uniform = _time_steps(sim, a.repeats)
    t0 = time.perf_counter()
    nb_uniform = sim.model.metrics()["mean_neighbors"]
    metrics_uniform = time.perf_counter() - t0
    sim.model.advance(a.develop)
    developed = _time_steps(sim, a.repeats)
    t0 = time.perf_counter()
    nb_developed = sim.model.metrics()["mean_neighbors"]
    metrics_developed = time.perf_counter() - t0

    def summary(ts: list[float], nb: float) -> dict:
        return {"ms_median": round(statistics.median(ts), 2), "ms_min": round(min(ts), 2),
                "ms_max": round(max(ts), 2), "mean_neighbors": round(nb, 1)}

    print(json.dumps({
        "n": a.n, "threads": engine.threads, "cpu": platform.processor() or platform.machine(),
        "first_step_s": round(first, 2), "import_to_first_step_s": round(import_to_first_step, 2),
        "uniform": {**summary(uniform, nb_uniform), "metrics_ms": round(1e3 * metrics_uniform, 1)},
        f"after_{a.develop}_steps": {**summary(developed, nb_developed),
                                     "metrics_ms": round(1e3 * metrics_developed, 1)},
    }, indent=1))


if __name__ == "__main__":
    main()
