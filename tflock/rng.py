"""Counter-based random numbers: hash(seed, step, agent, stream) -> uniform in [0, 1).

Every random draw in tflock (initial conditions and noise) is a pure function of its key, computed the same way
in Taichi kernels and in NumPy (the test oracle), so a run does not depend on the thread count or the backend
and the reference sees exactly the draws the kernel saw. The mixer is Chris Wellons' ``lowbias32`` integer hash,
chained over the four key words. Uniforms keep 24 bits, so f32 and f64 runs see identical values.
"""


from enum import IntEnum

import numpy as np
import taichi as ti

from tflock.fastmath import floor_quotient

_M1 = 0x7FEB352D
_M2 = 0x846CA68B
_INV_2_24 = 1.0 / 16777216.0


class Stream(IntEnum):
    """Stream ids: one per kind of draw, so no two uses of randomness share a key."""

    INIT_X = 0
    INIT_Y = 1
    INIT_Z = 2
    INIT_HEADING = 3
    INIT_HEADING_2 = 4
    NOISE = 5
    NOISE_2 = 6
    UPDATE = 7
    DELAY = 8
    SUBSET = 9
    PAIR_I = 10
    PAIR_J = 11


def _mix_np(x: np.ndarray) -> np.ndarray:
    x = x ^ (x >> np.uint32(16))
    x = x * np.uint32(_M1)
    x = x ^ (x >> np.uint32(15))
    x = x * np.uint32(_M2)
    return x ^ (x >> np.uint32(16))


def hash_np(seed: int, step: int | np.ndarray, agent: int | np.ndarray, stream: int) -> np.ndarray:
    """32-bit hash of the key (NumPy, vectorised over step and agent)."""
    with np.errstate(over="ignore"):
        u = np.uint32
        h = _mix_np(np.asarray(stream, dtype=u))
        h = _mix_np(np.asarray(agent, dtype=np.int64).astype(u) + h)
        h = _mix_np(np.asarray(step, dtype=np.int64).astype(u) + h)
        return _mix_np(u(seed) + h)


def uniform_np(seed: int, step: int | np.ndarray, agent: int | np.ndarray, stream: int) -> np.ndarray:
    """Uniform draws in [0, 1) with 24-bit resolution, as float64 (exactly representable in float32)."""
    return (hash_np(seed, step, agent, stream) >> np.uint32(8)).astype(np.float64) * _INV_2_24


def pair_hash_np(seed: int, step: int, agent: int | np.ndarray, other: int | np.ndarray, stream: int) -> np.ndarray:
    """Hash of a key with two agents (e.g. the delay with which `agent` sees `other`)."""
    with np.errstate(over="ignore"):
        other_mix = _mix_np(np.asarray(other, dtype=np.int64).astype(np.uint32))
        return _mix_np(hash_np(seed, step, agent, stream) + other_mix)


def randint_np(h: np.ndarray, bound: int) -> np.ndarray:
    """Integer in [0, bound) from a hash: floor(u * bound) computed exactly in integers (bound < 2^31)."""
    return ((h >> np.uint32(8)).astype(np.int64) * bound) >> 24


def bernoulli_np(h: np.ndarray, k: np.ndarray | int) -> np.ndarray:
    """True with probability 1/k (k >= 1): u < 1/k decided exactly in integers, as the kernels do."""
    return (h >> np.uint32(8)).astype(np.int64) * np.asarray(k, dtype=np.int64) < (1 << 24)


@ti.func
def _mix_ti(x):
    x ^= x >> ti.u32(16)
    x *= ti.u32(_M1)
    x ^= x >> ti.u32(15)
    x *= ti.u32(_M2)
    x ^= x >> ti.u32(16)
    return x


@ti.func
def hash_ti(seed, step, agent, stream):
    """Taichi twin of :func:`hash_np`; arguments are cast to u32."""
    h = _mix_ti(ti.cast(stream, ti.u32))
    h = _mix_ti(ti.cast(agent, ti.u32) + h)
    h = _mix_ti(ti.cast(step, ti.u32) + h)
    return _mix_ti(ti.cast(seed, ti.u32) + h)


@ti.func
def uniform_ti(seed, step, agent, stream):
    """Taichi twin of :func:`uniform_np`, in the default float type."""
    return ti.cast(hash_ti(seed, step, agent, stream) >> ti.u32(8), float) * _INV_2_24


@ti.func
def pair_hash_ti(seed, step, agent, other, stream):
    """Taichi twin of :func:`pair_hash_np`."""
    return _mix_ti(hash_ti(seed, step, agent, stream) + _mix_ti(ti.cast(other, ti.u32)))


@ti.func
def randint_ti(h, bound):
    """Taichi twin of :func:`randint_np`."""
    return ti.cast((ti.cast(h >> ti.u32(8), ti.i64) * bound) >> 24, ti.i32)


@ti.func
def bernoulli_ti(h, k):
    """Taichi twin of :func:`bernoulli_np`."""
    return ti.cast(h >> ti.u32(8), ti.i64) * k < (1 << 24)


@ti.func
def replica_key(seed, agent, per_replica):
    """Key words (seed, agent) of agent id `agent` in a batch of replicas of `per_replica` agents each.

    Replica r draws with seed + r and its local id, exactly what a lone run with seed + r draws, so a batch
    reproduces its replicas run one by one (and one replica of n agents keeps the plain key).
    """
    r = floor_quotient(agent, per_replica)
    return ti.cast(seed, ti.u32) + ti.cast(r, ti.u32), agent - r * per_replica
