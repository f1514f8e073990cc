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

The idle iterations cost about a nanosecond each.
"""

import taichi as ti

#: iterations of the top-level loop per task: at least the largest block Taichi hands a thread
TASK_STRIDE = 1024


@ti.func
def task_at(t):
    """The task that iteration t of a loop over ``tasks * TASK_STRIDE`` iterations runs, or -1 for none."""
    return ti.select(t % TASK_STRIDE == 0, t // TASK_STRIDE, -1)
