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
"""

import taichi as ti

#: iterations of the top-level loop per task, TASK_STRIDE = 2^TASK_SHIFT: at least the largest block Taichi hands
#: a thread
TASK_SHIFT = 10
TASK_STRIDE = 1 << TASK_SHIFT

#: iterations a loop over light tasks is spread to (:func:`spread_shift`): 64 of Taichi's blocks of 512
SPREAD_ITERATIONS = 64 * 512


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
