"""Host copies of ndarrays without copy kernels (tflock.taichi_host) give what Taichi's own copy kernels give, and
the CPU's NumPy sums and non-finite guard give what their kernels (kept for GPU arches) give."""

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH
from taichi.lang._ndarray import ScalarNdarray

from tflock.guard import Guarded, first_non_finite, kernel_first_non_finite
from tflock.reductions import BLOCK, kernel_maximum, kernel_total, maximum, total
from tflock.taichi_host import host_array, host_view

DTYPES = [(ti.f32, np.float32), (ti.f64, np.float64), (ti.i32, np.int32), (ti.i64, np.int64),
          (ti.u8, np.uint8), (ti.u32, np.uint32)]
SHAPES = [(5,), (3, 7), (2, 3, 4)]


@ti.kernel
def _pattern(a: ti.types.ndarray()):
    for index in ti.grouped(a):
        k = 0
        for d in ti.static(range(index.n)):
            k = k * 31 + index[d]
        a[index] = (k * 7 % 251) * 0.5  # cast to the array's type on assignment


def _original(name: str):
    return getattr(ScalarNdarray, name).original


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("dtype", DTYPES, ids=[np.dtype(d[1]).name for d in DTYPES])
def test_copies_equal_taichi_own(engine, dtype, shape):
    ti_type, np_type = dtype
    a = ti.ndarray(ti_type, shape)
    _pattern(a)
    own = _original("_ndarray_to_numpy")(a)
    copied = a.to_numpy()
    assert copied.dtype == own.dtype and copied.shape == own.shape and np.array_equal(copied, own)
    assert own.any()  # the pattern is not all zeros: the comparison means something

    values = np.random.default_rng(1).uniform(-300.5, 300.5, shape)  # f64: cast as Taichi's copy kernel casts
    if np_type in (np.uint8, np.uint32):
        values = np.abs(values)
    b = ti.ndarray(ti_type, shape)
    _original("_ndarray_from_numpy")(b, values.astype(np_type) if np_type == np.uint8 else values)
    expected = _original("_ndarray_to_numpy")(b)
    b.fill(0)
    b.from_numpy(values.astype(np_type) if np_type == np.uint8 else values)
    assert np.array_equal(b.to_numpy(), expected)

    _original("fill")(b, 3)
    expected = _original("_ndarray_to_numpy")(b)
    b.fill(0)
    b.fill(3)
    assert np.array_equal(b.to_numpy(), expected)


def test_wrong_input_keeps_taichi_errors(engine):
    a = ti.ndarray(ti.f32, (4,))
    with pytest.raises(ValueError, match="Mismatch shape"):
        a.from_numpy(np.zeros(5, np.float32))
    with pytest.raises(TypeError):
        a.from_numpy([1.0, 2.0, 3.0, 4.0])


def test_host_view_shares_the_memory_on_the_cpu_only(engine):
    a = ti.ndarray(ti.i32, (2, 6))
    view = host_view(a)
    if ARCH != "cpu":
        assert view is None
        return
    _pattern(a)
    assert np.array_equal(view, _original("_ndarray_to_numpy")(a))  # a kernel's writes are seen
    view[1, 2] = -9
    assert _original("_ndarray_to_numpy")(a)[1, 2] == -9  # and the view's writes reach the ndarray
    assert host_view(ti.Vector.ndarray(2, ti.f32, 3)) is None  # elements that are vectors: Taichi's own copies


@pytest.mark.parametrize("dtype", [(ti.f32, np.float32), (ti.f64, np.float64), (ti.i32, np.int32)],
                         ids=["f32", "f64", "i32"])
def test_total_equals_the_kernel_sum(engine, dtype):
    ti_type, np_type = dtype
    n = 2 * BLOCK + 77
    rng = np.random.default_rng(2)
    if np_type == np.int32:  # over 2^31 in all, and in a block: both sums must stay exact
        values = rng.integers(2**29, 2**30, n + 5).astype(np.int32)
    else:
        values = rng.uniform(-1.0, 1.0, n + 5).astype(np_type)
    a = ti.ndarray(ti_type, n + 5)
    a.from_numpy(values)
    exact = float(values[:n].astype(np.float64 if np_type != np.int32 else np.int64).sum())
    tolerance = 1e-3 if np_type == np.float32 else 1e-9  # the kernel sums each block in the values' type
    assert total(a, n) == pytest.approx(exact, abs=tolerance)
    assert kernel_total(a, n) == pytest.approx(exact, abs=tolerance)
    if np_type == np.int32:
        assert total(a, n) == kernel_total(a, n) == exact


@pytest.mark.parametrize("dtype", [(ti.f32, np.float32), (ti.f64, np.float64), (ti.i32, np.int32)],
                         ids=["f32", "f64", "i32"])
def test_maximum_equals_the_kernel_maximum(engine, dtype):
    """The largest of the first n values (all negative, the largest in the last, partial block), whatever lies past
    n: NumPy's on the ndarray's memory and the block kernel's (GPU arches) alike."""
    ti_type, np_type = dtype
    n = 2 * BLOCK + 77
    values = -np.random.default_rng(3).uniform(10.0, 1000.0, n + 5).astype(np_type)
    values[n - 3] = -1
    values[n:] = 5  # past n: not counted
    a = ti.ndarray(ti_type, n + 5)
    a.from_numpy(values)
    assert maximum(a, n) == kernel_maximum(a, n) == -1.0
    assert kernel_maximum(a, 1) == float(values[0])


@pytest.mark.parametrize("wide", [False, True], ids=["f32", "f64"])
def test_guard_finds_what_its_kernel_finds(engine, wide):
    real = np.float64 if wide else np.float32
    huge = np.finfo(real).max / 2
    n = 300
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(np.random.default_rng(3).permutation(n).astype(np.int32))
    slot_of = {int(agent): s for s, agent in enumerate(ids.to_numpy())}
    pos = ti.ndarray(ti.f64 if wide else ti.f32, (2, n))
    rows = ti.ndarray(ti.f64 if wide else ti.f32, (3, n))
    heading = ti.ndarray(ti.f64 if wide else ti.f32, n)

    def guarded():
        return [Guarded("position", pos), Guarded("heading", rows, (1, 2)), Guarded("velocity", rows, (2, 3)),
                Guarded("speed", heading)]

    def put(array, index, value):
        values = array.to_numpy()
        values[index] = value
        array.from_numpy(values.astype(real))

    cases = [
        [],  # all finite
        [(pos, (1, slot_of[40]), np.inf)],
        [(pos, (0, slot_of[40]), np.nan), (rows, (1, slot_of[12]), -np.inf)],  # a later array, a smaller agent
        [(rows, (0, slot_of[3]), np.nan), (rows, (2, slot_of[8]), np.nan)],  # row 0 is not guarded
        [(rows, (1, slot_of[8]), np.nan), (rows, (2, slot_of[8]), np.inf)],  # a tie: the first quantity
        [(heading, slot_of[0], np.nan), (pos, (1, slot_of[0]), np.nan)],
        [(pos, (0, slice(0, 3)), huge)],  # finite values whose sum overflows: still finite
    ]
    expected = [None, (40, "position"), (12, "heading"), (8, "velocity"), (8, "heading"), (0, "position"), None]
    for case, want in zip(cases, expected, strict=True):
        for array in (pos, rows, heading):
            array.fill(0.5)
        for array, index, value in case:
            put(array, index, value)
        assert first_non_finite(guarded(), ids) == want
        assert kernel_first_non_finite(guarded(), ids) == want


def test_host_array_is_the_view_or_a_copy(engine):
    """host_array: the ndarray's own memory where a host view exists (writes reach the ndarray), else a copy; the
    values either way."""
    array = ti.ndarray(ti.f32, (3, 5))
    array.from_numpy(np.arange(15, dtype=np.float32).reshape(3, 5))
    values = host_array(array)
    np.testing.assert_array_equal(values, np.arange(15, dtype=np.float32).reshape(3, 5))
    view = host_view(array)
    assert (view is not None) == (ARCH == "cpu")
    if view is not None:
        assert values is view  # no copy, the same view each time
