"""Deterministic reductions of an ndarray's first n values (sums, means, maxima), the same whatever the thread count.

On the CPU NumPy reads the ndarray's own memory (no kernel to compile, no copy); on GPU arches a kernel reduces fixed
blocks of BLOCK values and NumPy reduces the blocks' results, so no array of n values is copied to the host. The
metrics' other passes share the blocks and the scratch arrays for their partial results.
"""

import functools
import math

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.taichi_host import host_view

#: values a block holds (a task of the reduction kernels)
BLOCK = 4096


def n_blocks(n: int) -> int:
    """Blocks of BLOCK values over n values (one at least)."""
    return max(1, math.ceil(n / BLOCK))


@functools.lru_cache(maxsize=16)
def scratch(shape: tuple[int, ...], dtype) -> ti.Ndarray:
    """An ndarray of this shape and dtype for a pass's partial results, made once and shared (making an ndarray
    costs about a millisecond in Taichi's front end): read it before the next pass of the same shape writes it."""
    return ti.ndarray(dtype, shape)


@ti.kernel
def _block_sums(values: ti.types.ndarray(), n: ti.i32, partial: ti.types.ndarray()):
    """partial[b] = sum of values over block b, in the type of `partial` (i64 sums of ints stay exact)."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            total = partial[blk] * 0
            for i in range(blk * BLOCK, ti.min(n, (blk + 1) * BLOCK)):
                total += values[i]
            partial[blk] = total


def total(values: ti.Ndarray, n: int) -> float:
    """Deterministic sum of ``values[:n]`` (ints exactly). On the CPU NumPy sums the ndarray's own memory (floats
    in f64): no kernel to compile, no copy; elsewhere a kernel sums blocks (floats in their own type, ints in i64)
    and NumPy adds the blocks."""
    view = host_view(values)
    if view is None:
        return kernel_total(values, n)
    return float(view[:n].sum(dtype=np.float64 if view.dtype.kind == "f" else np.int64))


def kernel_total(values: ti.Ndarray, n: int) -> float:
    """:func:`total` on GPU arches: block sums in a kernel, added in NumPy."""
    real = values.dtype in (ti.f32, ti.f64)
    partial = scratch((n_blocks(n),), values.dtype if real else ti.i64)
    _block_sums(values, n, partial)
    return float(partial.to_numpy().astype(np.float64 if real else np.int64).sum())


@ti.kernel
def _block_maxima(values: ti.types.ndarray(), n: ti.i32, partial: ti.types.ndarray()):
    """partial[b] = the largest of values over block b."""
    for t in range(partial.shape[0] * TASK_STRIDE):  # a block a task (tflock.cpu_tasks)
        blk = task_at(t)
        if blk >= 0:
            lo = blk * BLOCK
            most = values[lo]
            for i in range(lo + 1, ti.min(n, lo + BLOCK)):
                most = ti.max(most, values[i])
            partial[blk] = most


def mean(values: ti.Ndarray, n: int) -> float:
    """Deterministic mean of an (n,) ndarray: :func:`total` / n."""
    return total(values, n) / n


def maximum(values: ti.Ndarray, n: int) -> float:
    """Largest of ``values[:n]``: NumPy over the ndarray's memory on the CPU; elsewhere :func:`kernel_maximum`."""
    view = host_view(values)
    if view is None:
        return kernel_maximum(values, n)
    return float(view[:n].max())


def kernel_maximum(values: ti.Ndarray, n: int) -> float:
    """:func:`maximum` on GPU arches: each block's largest in a kernel, the largest of those in NumPy (no copy of
    the n values to the host)."""
    partial = scratch((n_blocks(n),), values.dtype)
    _block_maxima(values, n, partial)
    return float(partial.to_numpy().max())
