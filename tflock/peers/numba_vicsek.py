"""A parallel Numba cell-list Vicsek `vector` step, written the usual way: the peer of `tflock bench`.

Needs numba (the optional `bench` extra). One step of the periodic Vicsek model (Vicsek et al. 1995; the same
model as tflock's `vector` rule, DESIGN.md 3.1): every agent takes the direction of the summed unit vectors of
its neighbours within R, itself included, adds uniform noise in [-eta/2, eta/2], moves by v0 and wraps.

How it is written (what a competent Numba user would do, nothing tflock-specific):

1. cell index of every agent on a grid of `ncell x ncell` cells of side `box / ncell >= R` (prange);
2. counting sort of the agents by cell (one serial O(N) pass: histogram, prefix sum, scatter), then the
   positions and cos/sin of the headings gathered into cell order, so that a cell's agents are contiguous;
3. a prange loop over the (cell-sorted) agents that visits the 3 x 3 neighbouring cells, takes minimum-image
   displacements and sums the cos/sin of the agents within R (the agent itself at distance 0 included);
4. new heading atan2(sum sin, sum cos) + U[-eta/2, eta/2] (Numba's per-thread np.random inside prange), move,
   wrap into [0, box), written back in agent order.

`fastmath=True, cache=True`. The arithmetic runs in the dtype of the inputs (float32 or float64).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

TWO_PI = 2 * math.pi


@njit(parallel=True, fastmath=True, cache=True)
def _step(x, theta, box, radius, speed, noise, ncell, new_x, new_theta):  # pragma: no cover - compiled
    n = x.shape[0]
    real = x.dtype.type
    side = box / real(ncell)
    inv_side = real(1.0) / side
    half = real(0.5)
    two_pi = real(TWO_PI)
    reach = 1 if ncell >= 3 else 0  # below 3 cells a side the 3 x 3 stencil would visit a cell twice
    m = ncell * ncell

    # 1. cell of every agent
    cell = np.empty(n, np.int64)
    for i in prange(n):
        cx = min(int(x[i, 0] * inv_side), ncell - 1)
        cy = min(int(x[i, 1] * inv_side), ncell - 1)
        cell[i] = cx * ncell + cy

    # 2. counting sort by cell, then positions and unit vectors gathered in cell order
    start = np.zeros(m + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(m):
        start[c + 1] += start[c]
    fill = start[:m].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        c = cell[i]
        order[fill[c]] = i
        fill[c] += 1
    xs = np.empty(n, x.dtype)
    ys = np.empty(n, x.dtype)
    cs = np.empty(n, x.dtype)
    ss = np.empty(n, x.dtype)
    for k in prange(n):
        i = order[k]
        xs[k] = x[i, 0]
        ys[k] = x[i, 1]
        cs[k] = np.cos(theta[i])
        ss[k] = np.sin(theta[i])

    # 3-4. neighbours in the 3 x 3 cells, new heading, move, wrap
    r2 = radius * radius
    for k in prange(n):
        i = order[k]
        cx = cell[i] // ncell
        cy = cell[i] % ncell
        xi = xs[k]
        yi = ys[k]
        sx = real(0.0)
        sy = real(0.0)
        for ox in range(-reach, reach + 1):
            nx = (cx + ox) % ncell
            for oy in range(-reach, reach + 1):
                nc = nx * ncell + (cy + oy) % ncell
                for q in range(start[nc], start[nc + 1]):
                    dx = xs[q] - xi
                    dy = ys[q] - yi
                    dx -= box * np.round(dx / box)
                    dy -= box * np.round(dy / box)
                    if dx * dx + dy * dy <= r2:
                        sx += cs[q]
                        sy += ss[q]
        h = np.arctan2(sy, sx) + noise * (real(np.random.random()) - half)
        h -= two_pi * np.floor(h / two_pi)
        if h >= two_pi or h < 0:
            h = real(0.0)
        px = xi + speed * np.cos(h)
        py = yi + speed * np.sin(h)
        px -= box * np.floor(px / box)
        py -= box * np.floor(py / box)
        new_x[i, 0] = px if real(0.0) <= px < box else real(0.0)
        new_x[i, 1] = py if real(0.0) <= py < box else real(0.0)
        new_theta[i] = h


def vicsek_step(x: np.ndarray, theta: np.ndarray, box: float, radius: float, speed: float,
                noise: float) -> tuple[np.ndarray, np.ndarray]:
    """One periodic Vicsek `vector` step: x (n, 2) in [0, box), theta (n,) -> new (x, theta), headings in
    [0, 2 pi). Runs in x's dtype (float32 or float64) on numba's threads (`numba.set_num_threads`); the noise
    comes from numba's per-thread generators (not reproducible, as usual with np.random inside prange)."""
    x = np.ascontiguousarray(x)
    theta = np.ascontiguousarray(theta, dtype=x.dtype)
    real = x.dtype.type
    ncell = max(1, int(box // radius))  # cells of side box / ncell >= R
    new_x, new_theta = np.empty_like(x), np.empty_like(theta)
    _step(x, theta, real(box), real(radius), real(speed), real(noise), ncell if ncell >= 3 else 1, new_x, new_theta)
    return new_x, new_theta
