"""Host copies of Taichi 1.7 ndarrays on the CPU without a copy kernel.

Taichi copies an ndarray to or from NumPy (``to_numpy``, ``from_numpy``, and ``fill`` for types other than
f32/i32/u32) with a kernel of its own, compiled for every dtype and rank it meets. On the CPU an ndarray lives in
host memory, so a NumPy view of that memory does the same copy with no kernel: a run compiles none of these
instantiations before its first step (each costs tens of milliseconds however small), and a copy runs at memory
speed.

:func:`host_view` gives that view (CPU, scalar elements; ``None`` elsewhere), :func:`host_array` the view or else a
copy; :func:`copy_on_host` makes ``to_numpy``, ``from_numpy`` and ``fill`` of such ndarrays use it. The values are
the same: a plain copy, and NumPy's assignment casts as Taichi's copy kernels do (round to nearest, truncation
toward zero for integers).
GPU arches and ndarrays of vectors or matrices keep Taichi's own code.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from typing import Any

import numpy as np
from taichi._lib import core as _ti_core
from taichi.lang import impl
from taichi.lang._ndarray import ScalarNdarray
from taichi.lang.util import to_numpy_type

CPU_ARCHES = (_ti_core.Arch.x64, _ti_core.Arch.arm64)


#: swarms of at most this many agents take their small passes over the state (counts, sums) in NumPy on host views
#: (:func:`small_host_view`): on the CPU a kernel launch costs more than such a pass
SMALL_SWARM_MAX = 4096


def host_view(array: Any) -> np.ndarray | None:
    """A NumPy array over ``array``'s own memory (writes go to the ndarray), or None where there is none to
    share (GPU arches, elements that are vectors or matrices). Valid while ``array`` lives and until the next
    kernel writes it."""
    if type(array) is not ScalarNdarray:
        return None
    view = array.__dict__.get("_tflock_view")  # made once: an ndarray's memory stays where it is
    if view is None:
        if impl.current_cfg().arch not in CPU_ARCHES:
            return None
        shape = tuple(array.arr.total_shape())
        dtype = np.dtype(to_numpy_type(array.dtype))
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if nbytes == 0:
            return np.zeros(shape, dtype)
        address = impl.get_runtime().prog.get_ndarray_data_ptr_as_int(array.arr)
        memory = (ctypes.c_char * nbytes).from_address(address)
        view = array.__dict__["_tflock_view"] = np.frombuffer(memory, dtype=dtype).reshape(shape)
    impl.get_runtime().prog.synchronize()  # CPU launches return when done; this keeps it so (0.6 us; the runtime's
    # sync() also materializes pending fields, 4 us, which a view of an ndarray does not need)
    return view


def small_host_view(array: Any, agents: int) -> np.ndarray | None:
    """:func:`host_view` of an array of a swarm of at most :data:`SMALL_SWARM_MAX` agents, else None: where a pass
    is done in NumPy rather than by a kernel."""
    return host_view(array) if agents <= SMALL_SWARM_MAX else None


def host_array(array: Any) -> np.ndarray:
    """``array``'s values as NumPy: its :func:`host_view` where there is one (no copy), else a copy."""
    view = host_view(array)
    return view if view is not None else array.to_numpy()


def _to_numpy(original: Callable[[Any], np.ndarray]) -> Callable[[Any], np.ndarray]:
    def to_numpy(self: Any) -> np.ndarray:
        view = host_view(self)
        return original(self) if view is None else view.copy()

    return to_numpy


def _from_numpy(original: Callable[[Any, Any], None]) -> Callable[[Any, Any], None]:
    def from_numpy(self: Any, arr: Any) -> None:
        view = host_view(self)
        if view is None or not isinstance(arr, np.ndarray) or arr.shape != view.shape:
            original(self, arr)  # Taichi's own copy, and its errors for a wrong type or shape
        else:
            view[...] = arr

    return from_numpy


def _fill(original: Callable[[Any, Any], None]) -> Callable[[Any, Any], None]:
    def fill(self: Any, val: Any) -> None:
        view = host_view(self)
        if view is None:
            original(self, val)
        else:
            view[...] = val

    return fill


def copy_on_host() -> None:
    """Make CPU ndarrays of scalars copy through :func:`host_view` (idempotent)."""
    for name, wrap in (("_ndarray_to_numpy", _to_numpy), ("_ndarray_from_numpy", _from_numpy), ("fill", _fill)):
        original = getattr(ScalarNdarray, name)
        if not hasattr(original, "original"):
            patched = wrap(original)
            patched.original = original  # type: ignore[attr-defined]
            setattr(ScalarNdarray, name, patched)
