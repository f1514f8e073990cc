"""Kernel loops over a few heavy tasks (stripes of a grid, parts of a count) that run in parallel on the CPU.

Taichi 1.7's CPU backend hands a thread 512 to 1024 consecutive iterations of a kernel's top-level loop at a time
(its adaptive block size; neither ``ti.loop_config(block_dim=...)`` nor ``ti.init``'s ``cpu_block_dim_adaptive`` and
``default_cpu_block_dim`` change it in this build), so a loop over 16 stripes ran on one thread. A loop over
``tasks * TASK_STRIDE`` iterations whose task j is iteration j * TASK_STRIDE, the others doing nothing, puts each
task in a block of its own, and the blocks go to the threads as they come free::

    for t in range(tasks * TASK_STRIDE):
        j = task_at(t)
        if j >= 0:
            ...  # task j

The idle iterations cost about a nanosecond each. A loop over many light tasks (the rows of a grid) takes a stride
of its own, :func:`spread_shift`, just wide enough that its tasks fill SPREAD_ITERATIONS iterations: enough blocks
to share out evenly, few idle iterations.

The other way round, a small swarm's pass runs on the calling thread (:func:`one_thread`): the pool's master wakes
its workers for every top-level loop and waits for them, however few the iterations, which costs tens of
microseconds a loop on a 2-core VM (a 50-agent grid build of nine loops: 340-390 us, against 14-15 us serialized;
docs/performance.md), more than a small swarm's whole pass. A kernel takes the choice as a template argument and
puts ``ti.loop_config(serialize=serial)`` before its top-level loop, or runs a func of several such loops inside
``for _ in range(1)`` after ``ti.loop_config(serialize=True)``.
"""

import taichi as ti

from tflock.engine import current_engine

#: iterations of the top-level loop per task, TASK_STRIDE = 2^TASK_SHIFT: at least the largest block Taichi hands
#: a thread
TASK_SHIFT = 10
TASK_STRIDE = 1 << TASK_SHIFT

#: iterations a loop over light tasks is spread to (:func:`spread_shift`): 64 of Taichi's blocks of 512
SPREAD_ITERATIONS = 64 * 512

#: agents up to which a pass of a few operations an agent runs on the calling thread (:func:`one_thread`)
ONE_THREAD_AGENTS = 4096


def one_thread(n: int, limit: int = ONE_THREAD_AGENTS) -> bool:
    """Whether a CPU pass over n agents (at most `limit`) runs serialized on the calling thread (see the module);
    never on a GPU, whose one thread is slow."""
    engine = current_engine()
    return n <= limit and engine is not None and engine.arch == "cpu"


def spread_shift(tasks: int) -> int:
    """log2 of the stride that spreads `tasks` tasks over at least SPREAD_ITERATIONS iterations (0 when they fill
    them already, at most TASK_STRIDE's); see :func:`spread_task`."""
    shift = 0
    while (tasks << shift) < SPREAD_ITERATIONS and shift < TASK_SHIFT:
        shift += 1
    return shift


@ti.func
def spread_task(t, shift):
    """The task that iteration t of a loop over ``tasks << shift`` iterations runs, or -1 for none."""
    return ti.select(t & ((1 << shift) - 1) == 0, t >> shift, -1)


@ti.func
def task_at(t):
    """The task that iteration t of a loop over ``tasks * TASK_STRIDE`` iterations runs, or -1 for none."""
    return spread_task(t, TASK_SHIFT)
