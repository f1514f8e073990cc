"""A shorter path from Python to a compiled Taichi 1.7 kernel, for small swarms' many small launches.

Each call of a kernel makes Taichi's Python front end work out, from every argument, which compiled instance to
run (``TaichiCallableTemplateMapper.extract``: a chain of ``isinstance`` tests per argument) and then set every
argument through a general recursive function (``Kernel.launch_kernel``). For tflock's step kernels (tens of
ndarrays and scalars each) that costs about 5-10 us an ndarray argument, 100-150 us a launch on this machine,
several times the arithmetic of a step at N <= 1000 (docs/performance.md, "Small swarms").

:func:`fast_launches` keeps, per kernel, a *plan* for each signature it has been called with: the signature is
the type of every argument, the value of every ``ti.template()`` argument and the dtype and rank of every ndarray,
everything Taichi's instance lookup reads for the arguments the plan admits. The first call with a signature goes
through Taichi's own path (compiling the instance, checking every argument); later calls with the same signature
set the arguments with one precomputed setter each and launch the same compiled kernel. The kernel run, and so
every result, is the same bit for bit; only the Python work around it shrinks.

On the CPU a plan also keeps launch contexts *bound* to the Taichi ndarrays it was called with: each ndarray is set
once, as the address, size and shape of its host memory (what Taichi's CPU launcher makes of an ndarray argument at
every launch), and a later call with the same ndarrays sets only its other arguments, its scalars only where their
values changed since that context's last launch. A model's step passes the same tens of ndarrays at every step, and
setting each argument through Taichi's bindings costs about a microsecond or more. A call that repeats the kernel's
last plan (the same argument types, template values and NumPy arrays' dtypes and ranks, its Taichi ndarrays those of
one of the plan's bound contexts) launches that context without working out its signature at all.

A plan is made only for plain calls: positional arguments, template values that are Python scalars or strings,
ndarray arguments that are Taichi scalar ndarrays without gradients or C-contiguous NumPy arrays of scalars (set as
Taichi sets them: their address, size and shape), scalar arguments of a primitive type (Python or NumPy scalars), no
return value and no autodiff or tape in use; every other call (fields, structs, keyword arguments, NumPy arrays
that are not C-contiguous, ...) takes Taichi's own path, every time.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
from taichi.lang import impl, kernel_impl
from taichi.lang._ndarray import ScalarNdarray
from taichi.lang.kernel_impl import Kernel
from taichi.lang.util import cook_dtype
from taichi.types import ndarray_type, primitive_types, template
from taichi.types.utils import is_signed

from tflock.taichi_host import CPU_ARCHES, host_view

#: launch contexts a plan keeps bound to sets of ndarrays (a model alternating buffers uses two or three)
BOUND_CONTEXTS = 8
_UNSET = object()  # a bound context's scalar not yet set
_TEMPLATE_VALUES = (bool, int, float, str, type(None))
#: scalar arguments a plan sets (NumPy's scalars too: a model's host arithmetic often yields them)
_SCALARS = (bool, int, float, np.float64, np.float32, np.int64, np.int32)


def _signature(kernel: Kernel, args: tuple) -> tuple | None:
    """The plan key of a call, or None where the call takes Taichi's own path."""
    key = []
    for arg, argument in zip(args, kernel.arguments, strict=True):
        kind = type(arg)
        if isinstance(argument.annotation, template):
            if kind not in _TEMPLATE_VALUES:
                return None
            key.append((kind, arg))
        elif kind is ScalarNdarray:
            if arg.grad is not None:
                return None
            key.append((kind, arg.dtype, len(arg.shape)))
        elif kind is np.ndarray:
            if not arg.flags.c_contiguous:
                return None
            key.append((kind, arg.dtype, arg.ndim))
        else:
            key.append(kind)
    return tuple(key)


def _setter(annotation: Any, kind: type, index: tuple[int]) -> Callable[[Any, Any], None] | None:
    """How to set one argument of the admitted kinds on a launch context, or None."""
    if kind is ScalarNdarray and isinstance(annotation, ndarray_type.NdarrayType):
        return lambda ctx, v: ctx.set_arg_ndarray(index, v.arr)
    if kind is np.ndarray and isinstance(annotation, ndarray_type.NdarrayType):
        if annotation.dtype is not None and id(annotation.dtype) not in primitive_types.type_ids:
            return None  # an ndarray of vectors or matrices: Taichi strips the element's axes from the shape
        return lambda ctx, v: ctx.set_arg_external_array_with_shape(index, int(v.ctypes.data), v.nbytes, v.shape, 0)
    if kind not in _SCALARS:
        return None
    if id(annotation) in primitive_types.real_type_ids:
        return lambda ctx, v: ctx.set_arg_float(index, float(v))
    if id(annotation) in primitive_types.integer_type_ids:
        if is_signed(cook_dtype(annotation)):
            return lambda ctx, v: ctx.set_arg_int(index, int(v))
        return lambda ctx, v: ctx.set_arg_uint(index, int(v))
    return None


class _Bound:
    """A launch context of one plan whose ndarray arguments are set once, as the addresses of their host memory
    (on the CPU an ndarray lives there and stays where it is). Holds its ndarrays weakly: a context whose ndarrays
    died is never launched again."""

    def __init__(self, plan: _Plan, arrays: tuple) -> None:
        self.refs = tuple(weakref.ref(array) for array in arrays)
        self.ctx = plan.t_kernel.make_launch_context()
        self.scalars: list[Any] = [_UNSET] * len(plan.scalar_setters)  # the values the context holds
        for slot, array in zip(plan.array_slots, arrays, strict=True):
            view = host_view(array)
            self.ctx.set_arg_external_array_with_shape((slot,), int(view.ctypes.data), view.nbytes, view.shape, 0)

    def holds(self, arrays: tuple) -> bool:
        return all(ref() is array for ref, array in zip(self.refs, arrays, strict=True))


class _Plan:
    """The compiled instance of one signature and one setter per non-template argument; on the CPU, launch contexts
    bound to the sets of ndarrays it was called with (the last :data:`BOUND_CONTEXTS`)."""

    def __init__(self, kernel: Kernel, args: tuple) -> None:
        instance, _ = kernel.mapper.lookup(args)
        self.key = (kernel.func, instance, kernel.autodiff_mode)
        self.t_kernel = kernel.compiled_kernels[self.key]
        prog = kernel.runtime.prog
        self.compiled = prog.compile_kernel(prog.config(), prog.get_device_caps(), self.t_kernel)
        self.setters: list[tuple[int, Callable[[Any, Any], None]]] = []  # every non-template argument's
        self.array_positions: list[int] = []  # where the Taichi ndarrays are among the arguments
        self.array_slots: list[int] = []  # and among the kernel's parameters
        self.scalar_setters: list[tuple[int, Callable[[Any, Any], None]]] = []  # set when their values change
        self.external_setters: list[tuple[int, Callable[[Any, Any], None]]] = []  # NumPy arrays: at every launch
        self.bound: dict[tuple[int, ...], _Bound] | None = {} if impl.current_cfg().arch in CPU_ARCHES else None
        self.valid = kernel.return_type is None and not getattr(kernel, "has_print", False)
        self.types = tuple(map(type, args))  # what a call with bound ndarrays must match besides (see `matches`)
        self.templates: list[tuple[int, Any]] = []  # the template arguments' positions and values
        self.externals: list[tuple[int, Any, int]] = []  # the NumPy arrays' positions, dtypes and ranks
        slot = 0
        for position, (arg, argument) in enumerate(zip(args, kernel.arguments, strict=True)):
            if isinstance(argument.annotation, template):
                self.templates.append((position, arg))
                continue
            if type(arg) is np.ndarray:
                self.externals.append((position, arg.dtype, arg.ndim))
            setter = _setter(argument.annotation, type(arg), (slot,))
            if setter is None:
                self.valid = False
                return
            self.setters.append((position, setter))
            if type(arg) is ScalarNdarray:
                self.array_positions.append(position)
                self.array_slots.append(slot)
            elif type(arg) is np.ndarray:
                self.external_setters.append((position, setter))
            else:
                self.scalar_setters.append((position, setter))
            slot += 1

    def matches(self, args: tuple) -> bool:
        """Whether a call has this plan's signature, given that its Taichi ndarrays are those of one of the plan's
        bound contexts (the same objects, so of the dtypes and ranks the plan admitted): the same argument types,
        template values and NumPy arrays' dtypes and ranks (C-contiguous)."""
        if tuple(map(type, args)) != self.types:
            return False
        for position, value in self.templates:
            if args[position] != value:
                return False
        for position, dtype, ndim in self.externals:
            array = args[position]
            if array.dtype != dtype or array.ndim != ndim or not array.flags.c_contiguous:
                return False
        return True

    def launch(self, kernel: Kernel, args: tuple, bound_only: bool = False) -> bool:
        """Launch the call; with `bound_only`, only where its ndarrays have a bound context (False: not launched)."""
        if self.bound is None:
            if bound_only:
                return False
            ctx = self.t_kernel.make_launch_context()
            for position, setter in self.setters:
                setter(ctx, args[position])
        else:
            arrays = tuple([args[p] for p in self.array_positions])
            key = tuple(map(id, arrays))
            bound = self.bound.get(key)
            if bound is None or not bound.holds(arrays):  # new ndarrays, or a dead one's id taken by a new one
                if bound_only:
                    return False
                if len(self.bound) >= BOUND_CONTEXTS:
                    del self.bound[next(iter(self.bound))]
                bound = self.bound[key] = _Bound(self, arrays)
            ctx = bound.ctx
            held = bound.scalars
            for k, (position, setter) in enumerate(self.scalar_setters):
                value = args[position]
                if value is held[k] or (value == held[k] and value != 0):  # a launch leaves its scalars as set
                    continue  # (a zero is set again: -0.0 == 0.0; a nan too: nan != nan)
                setter(ctx, value)
                held[k] = value
            for position, setter in self.external_setters:
                setter(ctx, args[position])
        kernel.runtime.prog.launch_kernel(self.compiled, ctx)
        return True


def _fast_call(original: Callable[..., Any]) -> Callable[..., Any]:
    def call(self: Kernel, *args: Any, **kwargs: Any) -> Any:
        runtime = self.runtime
        if (kwargs or len(args) != len(self.arguments) or runtime.fwd_mode_manager or runtime.target_tape
                or self.autodiff_mode != kernel_impl.AutodiffMode.NONE):
            return original(self, *args, **kwargs)
        last = self.__dict__.get("_tflock_last")  # the plan of the last planned call: most calls repeat it
        if (last is not None and last.matches(args) and self.compiled_kernels.get(last.key) is last.t_kernel
                and last.launch(self, args, bound_only=True)):
            return None
        signature = _signature(self, args)
        if signature is None:
            return original(self, *args)
        plans = self.__dict__.setdefault("_tflock_plans", {})
        plan = plans.get(signature)
        if plan is not None and self.compiled_kernels.get(plan.key) is plan.t_kernel:
            if not plan.valid:
                return original(self, *args)
            self._tflock_last = plan
            plan.launch(self, args)
            return None
        result = original(self, *args)  # compiles the instance and checks every argument
        plans[signature] = _Plan(self, args)
        if plans[signature].valid:
            self._tflock_last = plans[signature]
        return result

    call.original = original  # type: ignore[attr-defined]
    return call


def fast_launches() -> None:
    """Make repeated plain kernel calls skip Taichi's per-call argument analysis (idempotent)."""
    original = Kernel.__call__
    if not hasattr(original, "original"):
        Kernel.__call__ = _fast_call(original)
