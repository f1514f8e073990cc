"""Plain NumPy versions of every model step and metric: the test oracle (O(N^2), small N only).

This module holds the shared geometry and the Vicsek family; other models have a submodule each
(``tflock.reference.adaptive``, ``tflock.reference.potential``, ...).

Written for clarity, straight from the equations in DESIGN.md section 3, with no neighbour grid: every pair is
tested. Random draws come from :mod:`tflock.rng` with the same keys the kernels use, so a kernel and this
reference started from the same state must agree step by step. Arithmetic runs in the dtype of the inputs
(pass float32 arrays to mirror an f32 kernel, float64 for f64).
"""

from __future__ import annotations

import math

import numpy as np

from tflock.config import VicsekParams
from tflock.reference.observables import transition_metrics_np
from tflock.rng import Stream, bernoulli_np, hash_np, pair_hash_np, randint_np, uniform_np

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


def topological_adjacency(x: np.ndarray, k: int, boundary: str, box: float) -> np.ndarray:
    """A[i, j] = j is one of the k agents nearest to i (j != i; Ballerini et al. 2008), distances by the boundary's
    metric, ties broken by the smaller agent id; squared distances computed in the dtype of x, as the kernel does."""
    d = displacements(x, boundary, box)
    d2 = (d * d).sum(axis=2)
    n = len(x)
    ids = np.arange(n)
    a = np.zeros((n, n), dtype=bool)
    for i in range(n):
        others = ids != i
        order = np.lexsort((ids[others], d2[i, others]))  # by distance, then by id
        a[i, ids[others][order[:k]]] = True
    return a


def neighbour_matrix(x: np.ndarray, params: VicsekParams) -> np.ndarray:
    """The neighbours of every agent by ``params.neighbours``: metric (within R) or topological (k nearest)."""
    if params.neighbours == "topological":
        return topological_adjacency(x, params.k, params.boundary, params.box)
    return adjacency(x, params.radius, params.boundary, params.box)


def unit_noise(seed: int, t: int, n: int, dim: int, dtype: type) -> np.ndarray:
    """Random unit vectors of the vectorial noise at step t, one per agent: at angle 2 pi u in 2D
    (u from ``Stream.NOISE``); uniform on the sphere in 3D (z = 1 - 2u, azimuth 2 pi v from ``Stream.NOISE_2``)."""
    ids = np.arange(n)
    u = uniform_np(seed, t, ids, Stream.NOISE).astype(dtype)
    if dim == 2:
        psi = dtype(TWO_PI) * u
        return np.stack([np.cos(psi), np.sin(psi)], axis=1)
    z = 1 - 2 * u
    azimuth = dtype(TWO_PI) * uniform_np(seed, t, ids, Stream.NOISE_2).astype(dtype)
    r = np.sqrt(np.maximum(0, 1 - z * z))
    return np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)


def apply_boundary(x: np.ndarray, boundary: str, box: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions after a move, wrapped into [0, box) (periodic) or mirrored at the walls (reflecting), and the mask
    of the mirrored coordinates (whose velocity component changes sign)."""
    flip = np.zeros(x.shape, dtype=bool)
    if boundary == "periodic":
        x = x - box * np.floor(x / box)
        x = np.where((x >= box) | (x < 0), 0.0, x).astype(x.dtype)
    elif boundary == "reflecting":
        low, high = x < 0, x > box
        x = np.where(low, -x, np.where(high, 2 * box - x, x)).astype(x.dtype)
        flip = low | high
    return x, flip


def move(x: np.ndarray, theta: np.ndarray, speed: float, boundary: str, box: float, wrap: bool = True):
    """Unit-speed move along theta, then the boundary: wrap (periodic) or mirror position and heading (a reflected
    heading wrapped into [0, 2 pi) unless `wrap` is false)."""
    x, flip = apply_boundary(x + speed * np.stack([np.cos(theta), np.sin(theta)], axis=1), boundary, box)
    if boundary == "reflecting":
        theta = np.where(flip[:, 0], math.pi - theta, theta)
        theta = np.where(flip[:, 1], -theta, theta).astype(x.dtype)
        theta = wrap_two_pi(theta) if wrap else theta
    return x, theta


def desired_turn(theta: np.ndarray, a: np.ndarray, seen: np.ndarray, params: VicsekParams, t: int = 0,
                 seed: int = 0) -> np.ndarray:
    """phi_i of 003 eqs. (8)-(10) (Jadbabaie eqs. 2, 17): a[i, j] = 1 when j is a neighbour of i, seen[i, j] the
    heading of j that i uses (theta_j, or theta_j(tau) with delays). With vectorial noise (Gregoire-Chate) the
    unit vector of step t, weighted by eta (1 + n_i), joins the vector rule's sum."""
    count = a.sum(axis=1)
    if params.rule == "vector":  # 003 eq. (10)
        sx = (a * np.cos(seen)).sum(axis=1) + np.cos(theta)
        sy = (a * np.sin(seen)).sum(axis=1) + np.sin(theta)
        if params.noise_type == "vectorial":
            weight = theta.dtype.type(params.noise) * (1 + count)
            xi = unit_noise(seed, t, len(theta), 2, theta.dtype.type)
            sx, sy = sx + weight * xi[:, 0], sy + weight * xi[:, 1]
        return wrap_pi(np.arctan2(sy, sx) - theta)
    if params.rule == "average":  # 003 eq. (8), Jadbabaie eq. (2)
        return (theta + (a * seen).sum(axis=1)) / (1 + count) - theta
    if params.rule == "relative":  # 003 eqs. (5), (9)
        return (a * wrap_pi(seen - theta[:, None])).sum(axis=1) / (1 + count)
    return ((a * seen).sum(axis=1) - count * theta) / params.g  # laplacian, Jadbabaie eq. (17), G = gI


def turn_and_noise(theta: np.ndarray, phi: np.ndarray, t: int, params: VicsekParams, seed: int) -> np.ndarray:
    """Turn limit (003 eq. 7a), uniform noise in [-eta/2, eta/2] (angular noise; vectorial noise is in phi),
    headings wrapped into [0, 2 pi) (unless ``params.wrap_headings`` is false)."""
    alpha = math.radians(params.max_turn_deg)
    xi = 0.0
    if params.noise_type == "angular":
        xi = params.noise * (uniform_np(seed, t, np.arange(len(theta)), Stream.NOISE) - 0.5)
    new = (theta + np.clip(phi, -alpha, alpha) + xi).astype(theta.dtype)
    return wrap_two_pi(new) if params.wrap_headings else new


def vicsek_step(x: np.ndarray, theta: np.ndarray, t: int, params: VicsekParams, seed: int):
    """One synchronous step t -> t+1 of the Vicsek family in 2D (DESIGN.md 3.1), metric or topological
    neighbours, angular or vectorial noise; returns (x, theta) at t+1."""
    a = neighbour_matrix(x, params).astype(x.dtype)
    seen = np.broadcast_to(theta, a.shape)
    new = turn_and_noise(theta, desired_turn(theta, a, seen, params, t, seed), t, params, seed)
    if params.leader.enabled:
        new[0] = theta[0]
    return move(x, new, params.speed, params.boundary, params.box, params.wrap_headings)


def async_draws(seed: int, t: int, omega: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """003 Table 1: which agents update at step t (probability 1 / (B - Omega_i + 1)) and the delay d[i, j] in
    {0, ..., B - 1} with which i sees j (tau = t - d)."""
    n = len(omega)
    ids = np.arange(n)
    update = bernoulli_np(hash_np(seed, t, ids, Stream.UPDATE), bound - omega + 1)
    delays = randint_np(pair_hash_np(seed, t, ids[:, None], ids[None, :], Stream.DELAY), bound)
    return update, delays


def vicsek_step_async(hist_x: np.ndarray, hist_theta: np.ndarray, omega: np.ndarray, t: int, params: VicsekParams,
                      seed: int):
    """One step t -> t+1 with asynchronous updates and delayed views (003 Assumption 1, Table 1).

    hist_x (B+1, n, 2) and hist_theta (B+1, n) hold the state at step tau in slot tau mod (B + 1) (before t = 0:
    the initial state). Returns the new history (slot t+1 written), Omega and the mask of updated agents.
    """
    bound = params.async_bound
    ring = bound + 1
    x, theta = hist_x[t % ring], hist_theta[t % ring]
    n = len(theta)
    update, delays = async_draws(seed, t, omega, bound)
    if params.leader.enabled:
        update[0] = False
    slots = (t - delays) % ring
    cols = np.broadcast_to(np.arange(n), (n, n))
    seen_x = hist_x[slots, cols]  # (n, n, 2): x_j(tau_ij)
    seen_theta = hist_theta[slots, cols]
    d = seen_x - x[:, None, :]
    if params.boundary == "periodic":
        d = d - params.box * np.round(d / params.box)
    r = x.dtype.type(params.radius)
    a = ((d * d).sum(axis=2) <= r * r).astype(x.dtype)
    np.fill_diagonal(a, 0)
    new = turn_and_noise(theta, desired_turn(theta, a, seen_theta, params, t, seed), t, params, seed)
    new = np.where(update, new, theta).astype(theta.dtype)
    x_new, theta_new = move(x, new, params.speed, params.boundary, params.box, params.wrap_headings)
    hist_x, hist_theta = hist_x.copy(), hist_theta.copy()
    hist_x[(t + 1) % ring], hist_theta[(t + 1) % ring] = x_new, theta_new
    return hist_x, hist_theta, np.where(update, 1, omega + 1), update


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


def pairwise_errors(x: np.ndarray, theta: np.ndarray, boundary: str, box: float) -> tuple[float, float]:
    """003 section V: e_d mean pairwise distance, e_theta mean pairwise |wrap(theta_i - theta_j)| (all pairs)."""
    n = len(theta)
    upper = np.triu(np.ones((n, n), dtype=bool), k=1)
    d = displacements(x.astype(np.float64), boundary, box)
    dist = np.sqrt((d * d).sum(axis=2))[upper]
    th = theta.astype(np.float64)
    angle = np.abs(wrap_pi(th[None, :] - th[:, None]))[upper]
    return float(dist.mean()), float(angle.mean())


def pairwise_errors_sampled(x: np.ndarray, theta: np.ndarray, boundary: str, box: float, seed: int, step: int,
                            samples: int) -> tuple[float, float]:
    """:func:`pairwise_errors` estimated from `samples` ordered pairs of array elements (i, j), i != j, drawn
    uniformly from (seed, step, sample) as tflock.metrics does above its exact range."""
    n = len(theta)
    m = np.arange(samples)
    i = randint_np(hash_np(seed, step, m, Stream.PAIR_I), n)
    j = randint_np(hash_np(seed, step, m, Stream.PAIR_J), n - 1)
    j = j + (j >= i)
    x64 = x.astype(np.float64)
    d = x64[i] - x64[j]
    if boundary == "periodic":
        d -= box * np.round(d / box)
    th = theta.astype(np.float64)
    return float(np.sqrt((d * d).sum(axis=1)).mean()), float(np.abs(wrap_pi(th[i] - th[j])).mean())


def vicsek_metrics(x: np.ndarray, theta: np.ndarray, params: VicsekParams, previous_theta: np.ndarray,
                   updated: np.ndarray) -> dict[str, float]:
    """Every metric the Vicsek model reports, for state (x, theta) reached from headings `previous_theta` with
    the agents in `updated` having updated."""
    polarization, mean_heading = heading_order(theta)
    out = {"polarization": polarization, "mean_heading": mean_heading}
    out.update(graph_metrics(x, params.radius, params.boundary, params.box))
    out["e_d"], out["e_theta"] = pairwise_errors(x, theta, params.boundary, params.box)
    out["de_theta"] = float(np.abs(wrap_pi(theta.astype(np.float64) - previous_theta)).mean())
    out["updated"] = float(np.mean(updated))
    if params.leader.enabled:
        th = theta.astype(np.float64)
        out["leader_error"] = float(np.abs(wrap_pi(th[1:] - th[0])).mean()) if len(th) > 1 else 0.0
    direction = np.array([math.cos(mean_heading), math.sin(mean_heading)])
    out.update(transition_metrics_np(x, direction, params.boundary, params.box, params.radius))
    return out
