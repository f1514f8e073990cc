"""Plain NumPy versions of every model step and metric: the test oracle (O(N^2), small N only).

Written for clarity, straight from the equations in DESIGN.md section 3, with no neighbour grid: every pair is
tested. Random draws come from :mod:`tflock.rng` with the same keys the kernels use, so a kernel and this
reference started from the same state must agree step by step. Arithmetic runs in the dtype of the inputs
(pass float32 arrays to mirror an f32 kernel, float64 for f64).
"""

from __future__ import annotations

import math

import numpy as np

from tflock.config import VicsekParams
from tflock.rng import Stream, uniform_np

TWO_PI = 2 * math.pi


def wrap_pi(a: np.ndarray) -> np.ndarray:
    """Angles into [-pi, pi)."""
    return a - TWO_PI * np.floor((a + math.pi) / TWO_PI)


def wrap_two_pi(a: np.ndarray) -> np.ndarray:
    """Angles into [0, 2 pi)."""
    a = a - TWO_PI * np.floor(a / TWO_PI)
    return np.where((a >= TWO_PI) | (a < 0), 0.0, a).astype(a.dtype)


def displacements(x: np.ndarray, boundary: str, box: float) -> np.ndarray:
    """d[i, j] = x_j - x_i, by the minimum image convention in a periodic box; shape (n, n, dim)."""
    d = x[None, :, :] - x[:, None, :]
    if boundary == "periodic":
        d = d - box * np.round(d / box)
    return d


def adjacency(x: np.ndarray, radius: float, boundary: str, box: float) -> np.ndarray:
    """A[i, j] = |x_j - x_i| <= R and j != i (DESIGN.md section 2)."""
    d = displacements(x, boundary, box)
    r = x.dtype.type(radius)
    a = (d * d).sum(axis=2) <= r * r
    np.fill_diagonal(a, False)
    return a


def move(x: np.ndarray, theta: np.ndarray, speed: float, boundary: str, box: float):
    """Unit-speed move along theta, then the boundary: wrap (periodic) or mirror position and heading."""
    x = x + speed * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    if boundary == "periodic":
        x = x - box * np.floor(x / box)
        x = np.where((x >= box) | (x < 0), 0.0, x).astype(x.dtype)
    elif boundary == "reflecting":
        low, high = x < 0, x > box
        x = np.where(low, -x, np.where(high, 2 * box - x, x)).astype(x.dtype)
        flip = low | high
        theta = np.where(flip[:, 0], math.pi - theta, theta)
        theta = wrap_two_pi(np.where(flip[:, 1], -theta, theta).astype(x.dtype))
    return x, theta


def vicsek_step(x: np.ndarray, theta: np.ndarray, t: int, params: VicsekParams, seed: int):
    """One synchronous step t -> t+1 of the Vicsek family (DESIGN.md 3.1); returns (x, theta) at t+1."""
    n = len(theta)
    a = adjacency(x, params.radius, params.boundary, params.box).astype(x.dtype)
    count = a.sum(axis=1)
    if params.rule == "vector":  # 003 eq. (10)
        sx = a @ np.cos(theta) + np.cos(theta)
        sy = a @ np.sin(theta) + np.sin(theta)
        phi = wrap_pi(np.arctan2(sy, sx) - theta)
    elif params.rule == "average":  # 003 eq. (8), Jadbabaie eq. (2)
        phi = (theta + a @ theta) / (1 + count) - theta
    elif params.rule == "relative":  # 003 eqs. (5), (9)
        phi = (a * wrap_pi(theta[None, :] - theta[:, None])).sum(axis=1) / (1 + count)
    else:  # laplacian, Jadbabaie eq. (17) with G = gI
        phi = (a @ theta - count * theta) / params.g
    alpha = math.radians(params.max_turn_deg)
    xi = params.noise * (uniform_np(seed, t, np.arange(n), Stream.NOISE) - 0.5)
    new = wrap_two_pi((theta + np.clip(phi, -alpha, alpha) + xi).astype(x.dtype))
    if params.leader.enabled:
        new[0] = theta[0]
    return move(x, new, params.speed, params.boundary, params.box)


def heading_order(theta: np.ndarray) -> tuple[float, float]:
    """Polarization |mean (cos, sin)| and circular mean heading in [0, 2 pi)."""
    c, s = np.cos(theta.astype(np.float64)).mean(), np.sin(theta.astype(np.float64)).mean()
    return float(math.hypot(c, s)), float(math.atan2(s, c) % TWO_PI)


def components(a: np.ndarray) -> np.ndarray:
    """Connected-component label of each vertex of the boolean adjacency matrix (breadth-first search)."""
    n = len(a)
    label = np.full(n, -1)
    for root in range(n):
        if label[root] >= 0:
            continue
        label[root] = root
        frontier = np.array([root])
        while frontier.size:
            nxt = np.flatnonzero(a[frontier].any(axis=0) & (label < 0))
            label[nxt] = root
            frontier = nxt
    return label


def graph_metrics(x: np.ndarray, radius: float, boundary: str, box: float) -> dict[str, float]:
    """Clusters, largest-cluster fraction S and neighbour counts of the R-graph."""
    a = adjacency(x, radius, boundary, box)
    _, sizes = np.unique(components(a), return_counts=True)
    degree = a.sum(axis=1)
    return {"clusters": float(len(sizes)), "largest_cluster": sizes.max() / len(x),
            "mean_neighbors": float(degree.mean()), "max_neighbors": float(degree.max())}


def vicsek_metrics(x: np.ndarray, theta: np.ndarray, params: VicsekParams) -> dict[str, float]:
    """Every metric the Vicsek model reports."""
    polarization, mean_heading = heading_order(theta)
    out = {"polarization": polarization, "mean_heading": mean_heading}
    out.update(graph_metrics(x, params.radius, params.boundary, params.box))
    if params.leader.enabled:
        th = theta.astype(np.float64)
        out["leader_error"] = float(np.abs(wrap_pi(th[1:] - th[0])).mean()) if len(th) > 1 else 0.0
    return out
