"""Sine, cosine and atan2 as branch-free polynomials, and an integer quotient without integer division, so that
loops over lanes of agents vectorise.

Taichi's ``ti.sin``/``ti.cos``/``ti.atan2`` call the C library one value at a time, which stops LLVM from
vectorising the loop around them (a lane-wise update of 8 agents then makes 24 scalar calls). These versions use
only arithmetic and selects, work element-wise on scalars and on ``ti.Vector`` lanes alike, and are accurate to a
few units in the last place at both precisions: measured against NumPy's float64 functions over [-7, 14]
(``tests/test_fastmath.py``), the largest errors are 6e-16 (f64) and 4e-7 (f32) for sine and cosine (f32 headings
in [0, 2 pi): 2e-7, where the C library's float32 functions err by 7e-8), 5e-16 and 3e-7 for atan2.

- sin/cos: x = k pi/2 + r with |r| <= pi/4 (at f32, r is computed in float64 and rounded once; at f64, pi/2 is
  split in two parts), Taylor polynomials of r to degree 15 (sine) and 16 (cosine), whose truncation error on
  |r| <= pi/4 is below 5e-17, then the quadrant k mod 4 picks and signs the pair.
- atan2: t = min(|x|, |y|) / max(|x|, |y|) in [0, 1]; for t > tan(pi/8), atan t = pi/4 + atan((t - 1) / (t + 1)),
  leaving |u| <= tan(pi/8); atan u = u P(u^2) with P of degree 11, a Chebyshev least-squares fit of atan(u)/u on
  u^2 in [0, tan^2(pi/8)] (relative error 3e-16 there); then the octant is undone. The signs come from x < 0 and
  y < 0, so atan2(+-0, -0) gives 0 (the C library gives +-pi): the two differ only for a zero vector.
- floor_quotient: a // b of 32-bit integers as the floor of their float64 quotient, on the CPU (GPU arches divide
  integers). x86 has no vector integer division, so `a // b` in a lane loop runs one scalar division per lane (a
  Vicsek update of 1e6 agents spent 5 of its 12 ms there). The float64 quotient is exact enough: for |a|, |b| < 2^31
  both are exact in float64, and where a/b is not an integer it lies at least 1/|b| from the nearest one, a relative
  gap of at least 1/|a| > 2^-31, far above the division's rounding (2^-53): its floor is the integer quotient.
"""

import math

import taichi as ti
from taichi.lang import impl

from tflock.taichi_host import CPU_ARCHES

_SIN = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(1, 8))  # r^3 .. r^15
_COS = tuple((-1) ** k / math.factorial(2 * k) for k in range(2, 9))  # r^4 .. r^16
_ATAN = (1.0, -0.33333333333334964, 0.20000000000344137, -0.14285714313804837, 0.11111112292175498,
         -0.09090937971888306, 0.07692737215373603, -0.06670487933999834, 0.05899920093377179,
         -0.052678056844797955, 0.043748953620923806, -0.024023056739491087)
_PIO2_HI = 1.5707963267948966  # float64(pi / 2)
_PIO2_LO = 6.123233995736766e-17  # pi / 2 - _PIO2_HI
_TAN_PI_8 = 0.41421356237309503


@ti.func
def _horner(z, coeffs: ti.template()):
    acc = z * 0.0 + coeffs[ti.static(len(coeffs) - 1)]
    for k in ti.static(range(len(coeffs) - 2, -1, -1)):
        acc = acc * z + coeffs[k]
    return acc


@ti.func
def sin_cos(x):
    """(sin x, cos x), element-wise."""
    k = ti.floor(x * (2.0 / math.pi) + 0.5)
    r = x * 0.0
    if ti.static(ti.lang.impl.get_runtime().default_fp == ti.f32):  # reduced in f64: exact for float32 input
        r = ti.cast(ti.cast(x, ti.f64) - ti.cast(k, ti.f64) * (0.5 * math.pi), ti.f32)
    else:
        r = (x - k * _PIO2_HI) - k * _PIO2_LO
    z = r * r
    s = r + r * z * _horner(z, ti.static(_SIN))
    c = 1.0 - 0.5 * z + z * z * _horner(z, ti.static(_COS))
    q = ti.cast(k, ti.i32) & 3
    sin_x = ti.select(q == 0, s, ti.select(q == 1, c, ti.select(q == 2, -s, -c)))
    cos_x = ti.select(q == 0, c, ti.select(q == 1, -s, ti.select(q == 2, -c, s)))
    return sin_x, cos_x


@ti.func
def atan2(y, x):
    """The angle of (x, y) in [-pi, pi], element-wise (0 for the zero vector)."""
    ax = ti.abs(x)
    ay = ti.abs(y)
    t = ti.min(ax, ay) / ti.select(ti.max(ax, ay) > 0, ti.max(ax, ay), 1.0)
    big = t > _TAN_PI_8
    u = ti.select(big, (t - 1.0) / (t + 1.0), t)
    a = u * _horner(u * u, ti.static(_ATAN))
    a = ti.select(big, a + 0.25 * math.pi, a)
    a = ti.select(ay > ax, 0.5 * math.pi - a, a)
    a = ti.select(x < 0, math.pi - a, a)
    return ti.select(y < 0, -a, a)


@ti.func
def floor_quotient(a, b):
    """a // b (floor division) for 32-bit integers with b >= 1 and |a| < 2^31, element-wise: on the CPU through
    float64 (exact: see the module); GPU arches keep the integer division (no x86 vector units there, and a float64
    division is slow on most GPUs)."""
    q = a * 0
    if ti.static(impl.current_cfg().arch in CPU_ARCHES):
        q = ti.cast(ti.floor(ti.cast(a, ti.f64) / ti.cast(b, ti.f64)), ti.i32)
    else:
        q = a // b
    return q


@ti.func
def opaque_copy(x, zero):
    """x, bit for bit, when the integer `zero` is 0 (it must be, at run time; the compiler must not know it): x's
    bits xor `zero`. Fast math's reassociation cannot see through it, so a sum that x ends is not regrouped with
    the terms x is added to (LLVM groups such sums by where their terms are computed, which differs where the same
    code is inlined into another loop)."""
    itype = ti.i32 if ti.static(ti.lang.impl.get_runtime().default_fp == ti.f32) else ti.i64
    return ti.bit_cast(ti.bit_cast(x, itype) ^ ti.cast(zero, itype), ti.lang.impl.get_runtime().default_fp)


@ti.kernel
def cos_sin(n: ti.i32, theta: ti.types.ndarray(), trig: ti.types.ndarray()):
    """trig[0] = cos theta, trig[1] = sin theta for n headings, by :func:`sin_cos`. The Vicsek and formation steps
    keep these for their next step; a state set from outside gets them here, bit for bit as a step writes them."""
    for s in range(n):
        sin_th, cos_th = sin_cos(theta[s])
        trig[0, s] = cos_th
        trig[1, s] = sin_th
