"""The non-finite guard: the first agent whose position, heading or velocity is nan or infinite.

One pass over each guarded state array finds the smallest agent id holding a non-finite value: NumPy over the
array's memory on the CPU, a parallel kernel on GPU arches (a bit test on the exponent: Taichi's fast math folds
float comparisons with nan away). Arrays kept in cell order map their slots to agent ids through the model's
``ids`` array.
"""

import functools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import taichi as ti

from tflock.taichi_host import host_view

NO_AGENT = 2**31 - 1


class Guarded(NamedTuple):
    """A state array the guard checks: agents along its last axis, ``rows`` [lo, hi) of its first axis (None: all)."""

    quantity: str  # position, heading or velocity
    array: ti.Ndarray
    rows: tuple[int, int] | None = None


@ti.func
def _non_finite(v, wide: ti.template()):
    """nan or +-inf: every exponent bit set."""
    bad = False
    if ti.static(wide):
        bad = (ti.bit_cast(v, ti.u64) & ti.u64(0x7FF0000000000000)) == ti.u64(0x7FF0000000000000)
    else:
        bad = (ti.bit_cast(v, ti.u32) & ti.u32(0x7F800000)) == ti.u32(0x7F800000)
    return bad


@ti.kernel
def _first_bad_row(a: ti.types.ndarray(), lo: ti.i32, rows: ti.template(), wide: ti.template(),
                   ids: ti.types.ndarray(), out: ti.types.ndarray(), k: ti.i32):
    out[k] = NO_AGENT
    for s in range(a.shape[1]):
        bad = 0
        for r in ti.static(range(rows)):  # unrolled: the loop over agents vectorises
            bad |= ti.select(_non_finite(a[lo + r, s], wide), 1, 0)
        if bad:
            ti.atomic_min(out[k], ids[s])


@ti.kernel
def _first_bad(a: ti.types.ndarray(), wide: ti.template(), ids: ti.types.ndarray(), out: ti.types.ndarray(),
               k: ti.i32):
    out[k] = NO_AGENT
    for s in range(a.shape[0]):
        if _non_finite(a[s], wide):
            ti.atomic_min(out[k], ids[s])


@functools.lru_cache(maxsize=4)
def _results(m: int) -> ti.Ndarray:
    return ti.ndarray(ti.i32, m)


def first_non_finite(guarded: Sequence[Guarded], ids: ti.Ndarray) -> tuple[int, str] | None:
    """``(agent, quantity)`` of the smallest agent id with a non-finite value in any guarded array (the first
    quantity in ``guarded`` order for that agent), or None when all are finite. ``ids[s]`` is the agent at slot
    ``s`` of the arrays (models keep agents in cell order)."""
    ids_view = host_view(ids)
    if ids_view is None:
        return kernel_first_non_finite(guarded, ids)
    found = []
    for g in guarded:  # CPU: NumPy over the arrays' own memory (no kernel to compile, no copy)
        view = host_view(g.array)
        lo, hi = g.rows or (0, view.shape[0])
        values = view if view.ndim == 1 else view[lo:hi]
        with np.errstate(over="ignore", invalid="ignore"):
            total = values.sum()
        if np.isfinite(total):  # nan and inf carry through a sum: all finite (a sum that overflows looks closer)
            found.append(NO_AGENT)
            continue
        bad = ~np.isfinite(values)
        if view.ndim > 1:
            bad = bad.any(axis=0)
        found.append(int(ids_view[bad].min()) if bad.any() else NO_AGENT)
    return _first(found, guarded)


def _first(found: Sequence[int], guarded: Sequence[Guarded]) -> tuple[int, str] | None:
    """The smallest agent of each array's smallest bad agents, with the first such array's quantity."""
    k = int(np.argmin(found))
    return None if found[k] == NO_AGENT else (int(found[k]), guarded[k].quantity)


def kernel_first_non_finite(guarded: Sequence[Guarded], ids: ti.Ndarray) -> tuple[int, str] | None:
    """:func:`first_non_finite` on GPU arches: one parallel pass over each array."""
    out = _results(len(guarded))
    for k, g in enumerate(guarded):
        wide = g.array.dtype == ti.f64
        if len(g.array.shape) == 1:
            _first_bad(g.array, wide, ids, out, k)
        else:
            lo, hi = g.rows or (0, g.array.shape[0])
            _first_bad_row(g.array, lo, hi - lo, wide, ids, out, k)
    return _first(out.to_numpy(), guarded)
