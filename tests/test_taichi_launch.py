"""The kernel-call fast path (tflock.taichi_launch): the same compiled instance runs as through Taichi's own call,
so runs are bit-identical; signatures (template values, dtypes) pick their own instances."""

import numpy as np
import pytest
import taichi as ti
from conftest import PRECISION, assert_same_run
from taichi.lang.kernel_impl import Kernel


@ti.kernel
def _scaled(n: ti.i32, factor: float, negate: ti.template(), src: ti.types.ndarray(), dst: ti.types.ndarray()):
    for i in range(n):
        value = src[i] * factor
        if ti.static(negate):
            value = -value
        dst[i] = value


def test_signatures_pick_their_instances(cpu_engine):
    for dtype, real in ((ti.f32, np.float32), (ti.f64, np.float64)):
        src, dst = ti.ndarray(dtype, 4), ti.ndarray(dtype, 4)
        src.from_numpy(np.arange(4, dtype=real))
        for _ in range(3):  # the first call makes the plan, the next ones use it
            for negate in (False, True):
                _scaled(4, 2.5, negate, src, dst)
                expected = np.arange(4, dtype=real) * real(2.5) * (-1 if negate else 1)
                assert np.array_equal(dst.to_numpy(), expected)
    assert len(_scaled._primal._tflock_plans) == 4  # two dtypes x two template values, each planned once


def test_numpy_scalars_take_the_planned_path(cpu_engine):
    """NumPy scalar arguments (a model's host arithmetic yields them) are set by the plan, with the values Taichi's
    own call would set."""
    src, dst = ti.ndarray(ti.f64, 3), ti.ndarray(ti.f64, 3)
    src.from_numpy(np.array([1.0, -2.0, 3.5]))
    for factor in (np.float64(0.1), np.float32(0.1), np.int64(3), np.int32(-2)):
        for _ in range(2):
            _scaled(np.int64(3), factor, False, src, dst)
            assert np.array_equal(dst.to_numpy(), np.array([1.0, -2.0, 3.5]) * np.float64(factor))
    plans = [p for key, p in _scaled._primal._tflock_plans.items() if key[0] is np.int64]
    assert len(plans) == 4 and all(p.valid for p in plans)


def test_numpy_arrays_take_the_planned_path(cpu_engine):
    """C-contiguous NumPy arrays are set by the plan (read and written in place, as Taichi's own call does); other
    layouts take Taichi's own path, which copies a Fortran-ordered array and writes it back."""
    for real in (np.float32, np.float64):
        src, dst = np.arange(6, dtype=real), np.zeros(6, dtype=real)
        for _ in range(2):
            _scaled(6, 2.0, True, src, dst)
            assert np.array_equal(dst, -2.0 * np.arange(6, dtype=real))
            dst[:] = 0
    planned = [p for key, p in _scaled._primal._tflock_plans.items() if key[3][0] is np.ndarray]
    assert len(planned) == 2 and all(p.valid for p in planned)
    strided = np.zeros(12)[::2]  # not contiguous: Taichi's own path, which refuses it
    with pytest.raises(ValueError, match="contiguous"):
        _scaled(6, 1.0, False, np.arange(6.0), strided)


@pytest.mark.parametrize("model,params", [("vicsek", {"n": 100, "box": 7.0, "noise": 0.4}),
                                          ("potential", {"n": 40}), ("formation", {"fail_prob": 0.5})])
def test_runs_are_bit_identical_to_taichis_own_call(make_sim, monkeypatch, model, params):
    fast = make_sim(model=model, params=params, steps=25, seed=4, log={"metrics_every": 5})
    fast.run()
    monkeypatch.setattr(Kernel, "__call__", Kernel.__call__.original)
    plain = make_sim(model=model, params=params, steps=25, seed=4, log={"metrics_every": 5})
    plain.run()
    assert_same_run(fast, plain)


def test_bound_contexts_follow_their_ndarrays(cpu_engine):
    """On the CPU a plan binds a launch context to the ndarrays it was called with: each call still reads and
    writes the ndarrays it is given, whether they are ones it met before, new ones (more than it keeps bound), or
    new ones that took a dead one's id."""
    from tflock.taichi_launch import BOUND_CONTEXTS

    src = ti.ndarray(ti.f32, 5)
    src.from_numpy(np.arange(5, dtype=np.float32))
    kept = [ti.ndarray(ti.f32, 5) for _ in range(BOUND_CONTEXTS + 2)]
    for factor in (1.0, 2.0, 3.0):  # every ndarray met again after more than BOUND_CONTEXTS others
        for dst in kept:
            dst.fill(0.0)
            _scaled(5, factor, False, src, dst)
            assert np.array_equal(dst.to_numpy(), np.arange(5, dtype=np.float32) * factor)
    for trial in range(20):  # short-lived ndarrays: CPython hands a dead one's id to the next one often
        dst = ti.ndarray(ti.f32, 5)
        _scaled(5, float(trial), True, src, dst)
        assert np.array_equal(dst.to_numpy(), -np.arange(5, dtype=np.float32) * np.float32(trial))
        del dst
    plans = [p for key, p in _scaled._primal._tflock_plans.items() if key[1] is float and p.bound is not None]
    assert plans and all(len(p.bound) <= BOUND_CONTEXTS for p in plans)


def test_repeated_calls_skip_the_signature_only_when_it_holds(cpu_engine, monkeypatch):
    """A call that repeats the last call's plan (its ndarrays bound, the same argument types, template values and
    NumPy arrays' dtypes and ranks) launches without working out its signature; any change takes the full path and
    its own instance."""
    import tflock.taichi_launch as launch

    worked_out = []
    signature = launch._signature
    monkeypatch.setattr(launch, "_signature", lambda kernel, args: worked_out.append(1) or signature(kernel, args))
    src = ti.ndarray(ti.f32, 4)
    src.from_numpy(np.arange(4, dtype=np.float32))
    # a signature's first call plans it, its second binds the ndarrays; then only a changed scalar value follows
    new_signature, repeat = [True, True, False], [False, False, False]
    calls = {(2.0, False, np.float32): new_signature, (3.0, False, np.float32): repeat,
             (3.0, True, np.float32): new_signature, (3.0, True, np.float64): new_signature,
             (np.float64(0.5), True, np.float64): new_signature, (4, True, np.float64): new_signature,
             (5, True, np.float64): repeat}
    for (factor, negate, real), expected in calls.items():
        full_path = []
        for _ in range(3):
            dst = np.zeros(4, dtype=real)
            before = len(worked_out)
            _scaled(4, factor, negate, src, dst)
            full_path.append(len(worked_out) > before)
            assert np.array_equal(dst, (np.arange(4, dtype=np.float32) * np.float32(factor) * (-1 if negate else 1))
                                  .astype(real))
        assert full_path == expected, (factor, negate, real)


@ti.kernel
def _signed(x: float, y: ti.i32, out: ti.types.ndarray()):
    out[0] = ti.atan2(x, -1.0)  # pi for +0.0, -pi for -0.0
    out[1] = x * y


def test_bound_contexts_set_what_changed(cpu_engine):
    """A bound context keeps the scalars of its last launch and sets those that changed: every call computes from
    the values it is given, repeated or not, a signed zero and a nan included."""
    out = ti.ndarray(ti.f64 if PRECISION == "f64" else ti.f32, 2)
    real = np.float64 if PRECISION == "f64" else np.float32
    for x, y in [(2.0, 3), (2.0, 3), (2.0, 4), (0.0, 4), (-0.0, 4), (-0.0, 4), (0.0, 4), (float("nan"), 1),
                 (float("nan"), 1), (np.float64(2.0), 3), (np.float32(1.5), 2), (1.5, 2)]:
        _signed(x, y, out)
        got = out.to_numpy()
        assert got[0] == pytest.approx(real(np.arctan2(real(x), -1.0)), nan_ok=True), (x, y)
        assert np.array_equal(got[1], real(x) * real(y), equal_nan=True), (x, y)
