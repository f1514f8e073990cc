"""Where a run's time goes, kernel by kernel: Taichi's kernel profiler over 10 steps of ``tflock sim``'s loop (metrics
every step, or every K steps with ``--metrics-every K``; the non-finite guard, no recording), then Python's profiler
over 10 more. ``--metrics-every 1000000`` profiles the plain steps (the first of them may still take the neighbour
sums a metrics pass before it ran for it: Vicsek's graph pass then shows once).

    python benchmarks/kernel_profile.py MODEL N [--arch cpu|cuda|vulkan] [--metrics-every K]

The model's default config at N agents (the bench's scaling of lengths: same density), from the uniform start, one
step and three more with metrics before the profiled ones (compiles). The first line gives the profiled steps' ms a
step: the profiler times each launch, so it is above what an unprofiled run costs (``tflock bench``'s run column).
"""

import argparse
import cProfile
import io
import pstats
import time
from collections.abc import Callable

import taichi as ti


def python_profile(run: Callable[[], object], order: str, lines: int) -> str:
    """Python's profile of `run` until the GPU has finished its work (ti.sync), the first `lines` functions by
    `order` ("tottime", "cumulative")."""
    profile = cProfile.Profile()
    profile.enable()
    run()
    ti.sync()
    profile.disable()
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats(order).print_stats(lines)
    return out.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model")
    parser.add_argument("n", type=float)
    parser.add_argument("--arch", default="cpu")
    parser.add_argument("--metrics-every", type=int, default=1,
                        help="metrics every K steps (1, a run's default; 1000000: the plain steps alone)")
    args = parser.parse_args()
    init = ti.init
    ti.init = lambda *a, **k: init(*a, **{**k, "kernel_profiler": True})  # tflock.engine calls ti.init

    from tflock.bench import BenchCase, case_config
    from tflock.simulation import Simulation

    case = BenchCase(model=args.model, n=int(args.n), state="uniform", develop_steps=0, repeats=3, arch=args.arch)
    sim = Simulation(case_config(case), record=False)
    sim.model.advance(1)
    sim.config.log.metrics_every = args.metrics_every
    sim.step(3)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    start = time.perf_counter()
    sim.step(10)
    ti.sync()
    print(args.model, case.n, "ms/step (profiled)", round((time.perf_counter() - start) * 100, 2))
    ti.profiler.print_kernel_profiler_info()
    ti.profiler.clear_kernel_profiler_info()
    print(python_profile(lambda: sim.step(10), "tottime", 18))


if __name__ == "__main__":
    main()
