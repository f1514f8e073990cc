"""The branch-free polynomial sin/cos/atan2 of tflock.fastmath against NumPy's float64 functions, and its integer
quotient against NumPy's floor division.

The lane-wise Vicsek step uses them instead of the C library's, so their error enters every heading; the bounds
below are a few units in the last place of the session's precision (the oracle tests then bound whole steps).
"""

import math

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH, PRECISION

from tflock.fastmath import atan2, cos_sin, floor_quotient, sin_cos

F64 = PRECISION == "f64"
REAL = np.float64 if F64 else np.float32
ULP = np.finfo(REAL).eps  # spacing at 1


@ti.kernel
def _evaluate(x: ti.types.ndarray(), y: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(x.shape[0]):
        s, c = sin_cos(x[i])
        out[0, i] = s
        out[1, i] = c
        out[2, i] = atan2(y[i], x[i])


@ti.kernel
def _evaluate_lanes(x: ti.types.ndarray(), y: ti.types.ndarray(), out: ti.types.ndarray()):
    for b in range(x.shape[0] // 8):
        vx = ti.Vector([x[8 * b + k] for k in ti.static(range(8))])
        vy = ti.Vector([y[8 * b + k] for k in ti.static(range(8))])
        s, c = sin_cos(vx)
        a = atan2(vy, vx)
        for k in ti.static(range(8)):
            out[0, 8 * b + k] = s[k]
            out[1, 8 * b + k] = c[k]
            out[2, 8 * b + k] = a[k]


def _inputs() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    specials = np.array([0.0, math.pi / 4, math.pi / 2, math.pi, 1.5 * math.pi, 2 * math.pi, -math.pi, 1e-9, -1e-9,
                         np.nextafter(2 * math.pi, 0)])
    x = np.concatenate([rng.uniform(-7.0, 14.0, 200_000), rng.uniform(-1e-3, 1e-3, 20_000), specials, -specials])
    y = rng.uniform(-3.0, 3.0, len(x))
    y[:40] = np.array([0.0, 1.0, -1.0, 2.0, -0.5] * 8)  # on the axes and diagonals of atan2's octants
    x[:40] = np.array([1.0, 0.0, 0.0, 2.0, 0.5, -1.0, 1.0, -1.0, -2.0, 0.5] * 4)
    n = len(x) // 8 * 8
    return x[:n].astype(REAL), y[:n].astype(REAL)


# the 8-lane forms run only in the CPU's lane-wise kernels; Taichi 1.7's SPIR-V backend (Vulkan) cannot compile them
CPU_ONLY = pytest.mark.skipif(ARCH != "cpu", reason="the 8-lane forms run in the CPU's lane-wise kernels only")


@pytest.mark.parametrize("evaluate", [_evaluate, pytest.param(_evaluate_lanes, marks=CPU_ONLY)],
                         ids=["scalar", "lanes"])
def test_polynomials_match_numpy(engine, evaluate):
    x, y = _inputs()
    out = np.zeros((3, len(x)), dtype=REAL)
    evaluate(x, y, out)
    xs, ys = x.astype(np.float64), y.astype(np.float64)
    bound = 8 * ULP if F64 else 4 * ULP
    assert np.abs(out[0] - np.sin(xs)).max() < bound
    assert np.abs(out[1] - np.cos(xs)).max() < bound
    heading = (xs >= 0) & (xs < 2 * math.pi)  # the step's headings (f32: the C library's float32 sine errs by 0.6)
    assert np.abs(out[:2, heading] - np.stack([np.sin(xs), np.cos(xs)])[:, heading]).max() < (8 if F64 else 2) * ULP
    assert np.abs(out[2] - np.arctan2(ys, xs)).max() < 8 * ULP
    assert np.all(np.abs(out[:2]) <= 1.0)


@CPU_ONLY
def test_scalar_and_lanes_agree_bit_for_bit(engine):
    """The vectorised lanes compute exactly what the scalar code does (the step and set_state's cos/sin agree)."""
    x, y = _inputs()
    a = np.zeros((3, len(x)), dtype=REAL)
    b = np.zeros((3, len(x)), dtype=REAL)
    _evaluate(x, y, a)
    _evaluate_lanes(x, y, b)
    assert np.array_equal(a, b)


@pytest.mark.skipif(ARCH != "cpu", reason="GPU arches run the general kernel, which keeps no cos/sin")
@pytest.mark.parametrize("boundary", ["periodic", "reflecting"])
def test_step_keeps_cos_sin_of_the_headings(engine, boundary):
    """The lane-wise Vicsek step stores cos/sin of each new heading for the next step (reflecting walls turn the
    heading after the move); they equal what set_state computes from the headings, bit for bit, so a state set
    from outside continues exactly as one the step wrote."""
    from tflock.config import load_config
    from tflock.models.vicsek import Vicsek

    cfg = load_config(overrides={"params.n": 2000, "params.box": 10.0, "params.speed": 0.4,
                                 "params.boundary": boundary, "engine.precision": PRECISION})
    model = Vicsek(cfg.params, cfg.seed, engine)
    assert model.lane_wise
    model.advance(30)
    kept = model.trig.to_numpy().copy()
    cos_sin(model.n_total, model.theta, model.trig)
    assert np.array_equal(kept, model.trig.to_numpy())


def test_formation_step_keeps_cos_sin_of_the_headings(engine):
    """The formation step keeps cos/sin of each new heading (on every arch) for the next step's gather; they equal
    what set_state computes from the headings (cos_sin), bit for bit, so a resumed run continues exactly as the one
    that saved it. A step on the C library's cos/sin instead of the polynomials fails here."""
    from tflock.config import load_config
    from tflock.models.formation import THETA, Formation

    cfg = load_config(model="formation", overrides={"params.n": 2000, "params.noise_deg": 2.0,
                                                    "engine.precision": PRECISION})
    model = Formation(cfg.params, cfg.seed, engine)
    model.advance(20)
    kept = model.trig.to_numpy().copy()
    cos_sin(cfg.params.n, np.ascontiguousarray(model.f[model.cur].to_numpy()[THETA]), model.trig)
    assert np.array_equal(kept, model.trig.to_numpy())


@ti.kernel
def _quotients(blocks: ti.i32, a: ti.types.ndarray(), b: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(blocks):  # as lanes, the way the CPU's steps call it (the count passed: Vulkan's shaders take no
        # floor division of an ndarray's shape)
        va = ti.Vector([a[8 * i + k] for k in ti.static(range(8))])
        vb = ti.Vector([b[8 * i + k] for k in ti.static(range(8))])
        q = floor_quotient(va, vb)
        for k in ti.static(range(8)):
            out[8 * i + k] = q[k]


def test_floor_quotient_is_floor_division(engine):
    """Exact for b >= 1 and |a| < 2^31 (what its callers pass: agent ids and replica sizes): quotients within one of
    an integer near the top of the range (a = q b - 1, q b, q b + 1 with b large and with b small), negative
    dividends, and random pairs; a replica's key depends on it."""
    rng = np.random.default_rng(0)
    top = 2**31 - 1
    b = np.concatenate([rng.integers(1, top, 4000), rng.integers(1, 100, 4000), np.full(8, top), np.arange(1, 9)])
    q = rng.integers(0, top // b + 1)
    a = np.clip(q * b + rng.integers(-1, 2, b.size), -top, top)
    a[: b.size // 4] = rng.integers(-top, top, b.size // 4)
    a[-8:] = [top, top - 1, -top, 0, 1, -1, top, 7]
    a, b = a.astype(np.int32), b.astype(np.int32)
    out = np.zeros(a.size, dtype=np.int32)
    _quotients(a.size // 8, a, b, out)
    np.testing.assert_array_equal(out, a.astype(np.int64) // b)
