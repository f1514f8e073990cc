"""Where a Vicsek run's time goes beyond its kernels (on a GPU the host waits where it reads a result):

    python benchmarks/run_phases.py N STATE [ARCH]     (STATE: uniform | developed; ARCH: default cuda)

The bench's own run measurement at N agents; runs restored to the case's state against continued ones, whole and step
by step; Python's profile of a restored run; the inclusive time of each part of the metrics pass and the guard, each
call fenced by ``ti.sync()``; and three probes of the host round trip (a small ``to_numpy``, a kernel with a NumPy
argument, an allocation of N values)."""
import collections
import functools
import statistics
import sys
import time

import numpy as np
import taichi as ti
from kernel_profile import python_profile  # benchmarks/, this script's folder, is on sys.path
from taichi.lang._ndarray import ScalarNdarray

from tflock import components, metrics, observables, simulation
from tflock.bench import BenchCase, _plain_and_run_steps, case_config, start_run
from tflock.models import base, vicsek

N, STATE = int(float(sys.argv[1])), sys.argv[2]
ARCH = sys.argv[3] if len(sys.argv) > 3 else "cuda"
case = BenchCase(model="vicsek", n=N, state=STATE, develop_steps=300, repeats=10, arch=ARCH, peers=False)
t0 = time.perf_counter()
sim = simulation.Simulation(case_config(case), record=False)
model = sim.model
model.advance(1)
ti.sync()
print(f"== vicsek {N} {STATE} {ARCH}: setup+first step {time.perf_counter() - t0:.1f} s", flush=True)
if STATE == "developed":
    model.advance(300)
    ti.sync()


def timed(f):
    ti.sync()
    t = time.perf_counter()
    f()
    ti.sync()
    return 1e3 * (time.perf_counter() - t)


# 1. the bench's own measurement (no wrappers)
turns = _plain_and_run_steps(sim, 10, 1, False)
print(f"bench: plain median {statistics.median(turns.plain):.2f} ms, run {turns.run:.2f} ms "
      f"({turns.run_range[0]:.2f}-{turns.run_range[1]:.2f})", flush=True)
start = (model.checkpoint(), model.step_index)
sim.config.log.metrics_every = 1
sim.config.log.every = 10**9

# 2. restored run vs continued run, whole and step by step (no wrappers)
for label, restore in (("restored", True), ("continued", False), ("restored", True), ("continued", False)):
    if restore:
        start_run(model, start, 1, False)
    whole = timed(lambda: sim.step(10)) / 10
    per = [timed(lambda: sim.step(1)) for _ in range(5)]
    print(f"{label}: sim.step(10) {whole:.2f} ms/step; then single steps {[round(p, 1) for p in per]}", flush=True)
per_adv = [timed(lambda: model.advance(1)) for _ in range(5)]
per_met = [timed(model.metrics) for _ in range(5)]
per_guard = [timed(sim._guard) for _ in range(5)]
print(f"advance {[round(p, 2) for p in per_adv]}\nmetrics {[round(p, 2) for p in per_met]}\n"
      f"guard {[round(p, 2) for p in per_guard]}", flush=True)

# 3. cProfile of a restored run (where the host waits)
start_run(model, start, 1, False)
print(python_profile(lambda: sim.step(10), "cumulative", 30)[:6000], flush=True)

# 4. inclusive times of the metrics' and guard's parts, each call fenced by syncs
T = collections.defaultdict(list)


def wrap(owner, name):
    f = getattr(owner, name)
    label = f"{getattr(owner, '__name__', owner)}.{name}"

    @functools.wraps(f)
    def w(*a, **k):
        ti.sync()
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            ti.sync()
            T[label].append(1e3 * (time.perf_counter() - t))

    setattr(owner, name, w)


FENCED = [(vicsek, "orders_and_pairs"), (vicsek, "pairwise_errors"), (vicsek, "mean"), (metrics, "mean"),
          (metrics, "maximum"), (components, "total"), (metrics.NeighbourGraph, "compute"),
          (metrics.NeighbourGraph, "degrees"), (metrics.NeighbourGraph, "components"),
          (components.Components, "_by_pairs"), (components.Components, "_by_subcells"),
          (components.Components, "compute_with_degrees"), (observables.TransitionObservables, "compute"),
          (vicsek.Vicsek, "metrics"), (vicsek.Vicsek, "advance"), (base.Model, "first_non_finite"),
          (simulation.Simulation, "_guard"), (simulation.Simulation, "_keep_good"), (base.Model, "checkpoint"),
          (ScalarNdarray, "to_numpy"), (ScalarNdarray, "from_numpy")]
for owner, name in FENCED:
    wrap(owner, name)
for label, restore in (("restored", True), ("continued", False)):
    if restore:
        start_run(model, start, 1, False)
    T.clear()
    whole = timed(lambda: sim.step(10)) / 10
    print(f"-- fenced {label}: {whole:.2f} ms/step; per call: count, mean, max ms")
    for k, v in sorted(T.items(), key=lambda kv: -sum(kv[1])):
        print(f"   {k:45s} {len(v):4d} {statistics.fmean(v):8.2f} {max(v):8.2f}")

# 5. probes: a small to_numpy, a kernel with a NumPy argument, a large allocation
small = ti.ndarray(ti.i32, 3)
print(f"probe: 3-element to_numpy {statistics.median([timed(small.to_numpy) for _ in range(50)]):.3f} ms")


@ti.kernel
def touch(a: ti.types.ndarray(), b: ti.types.ndarray()):
    for i in range(1):
        b[i] = a[i] + 1


h = np.zeros(4, dtype=np.int32)
d = ti.ndarray(ti.i32, 4)
touch(h, d)
touch(d, d)
print(f"probe: kernel with a NumPy argument {statistics.median([timed(lambda: touch(h, d)) for _ in range(50)]):.3f} "
      f"ms, all ndarrays {statistics.median([timed(lambda: touch(d, d)) for _ in range(50)]):.3f} ms")
print(f"probe: ti.ndarray(i32, N) {statistics.median([timed(lambda: ti.ndarray(ti.i32, N)) for _ in range(5)]):.2f} ms",
      flush=True)
