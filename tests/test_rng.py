"""The counter-based generator: Taichi and NumPy agree bit for bit, and the draws look uniform."""

import numpy as np
import taichi as ti

from tflock.rng import hash_np, hash_ti, uniform_np, uniform_ti


@ti.kernel
def _draw(out_hash: ti.types.ndarray(), out_u: ti.types.ndarray(), seed: ti.u32, step: ti.i32, stream: ti.i32):
    for i in range(out_hash.shape[0]):
        out_hash[i] = hash_ti(seed, step, i, stream)
        out_u[i] = uniform_ti(seed, step, i, stream)


def test_kernel_and_numpy_draws_are_identical(engine):
    n = 10000
    h = ti.ndarray(ti.u32, n)
    u = ti.ndarray(ti.f64 if engine.precision == "f64" else ti.f32, n)
    for seed, step, stream in [(0, 0, 0), (2**32 - 1, 123456, 5), (42, 7, 9)]:
        _draw(h, u, seed, step, stream)
        assert np.array_equal(h.to_numpy(), hash_np(seed, step, np.arange(n), stream))
        assert np.array_equal(u.to_numpy(), uniform_np(seed, step, np.arange(n), stream).astype(u.to_numpy().dtype))


def test_uniform_draws_are_uniform_and_keys_independent():
    u = uniform_np(3, 10, np.arange(200000), 5)
    assert u.min() >= 0 and u.max() < 1
    counts, _ = np.histogram(u, bins=20, range=(0, 1))
    assert np.abs(counts / 10000 - 1).max() < 0.05
    other = uniform_np(3, 11, np.arange(200000), 5)
    assert abs(np.corrcoef(u, other)[0, 1]) < 0.01
    assert not np.array_equal(u, uniform_np(4, 10, np.arange(200000), 5))
    assert not np.array_equal(u, uniform_np(3, 10, np.arange(200000), 6))
