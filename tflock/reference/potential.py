"""NumPy oracle of the Tanner-Jadbabaie-Pappas potential-field model (DESIGN.md 3.3; papers/001): O(N^2), small N.

Straight from the equations: u_i of eq. (3) with V(r) = d^2 / r^2 + ln(r^2) (Definition 2), neighbours
|r_ij| < R (switching, section 5) or a fixed graph (section 4), one semi-implicit Euler step
v' = v + dt u(r, v), r' = r + dt v'. Arithmetic runs in the dtype of the inputs.
"""

from __future__ import annotations

import numpy as np

from tflock.models.potential_graphs import fixed_graph_edges
from tflock.models.potential_params import PotentialParams


def neighbour_matrix(x: np.ndarray, params: PotentialParams, edges: np.ndarray | None = None) -> np.ndarray:
    """A[i, j]: j in N_i. Switching: |r_ij| < R, j != i; fixed: the graph's edges (regardless of distance)."""
    n = len(x)
    if params.topology == "fixed":
        a = np.zeros((n, n), dtype=bool)
        a[edges[:, 0], edges[:, 1]] = True
        return a | a.T
    d = x[None, :, :] - x[:, None, :]
    a = (d * d).sum(axis=2) < x.dtype.type(params.radius) ** 2
    np.fill_diagonal(a, False)
    return a


def graph_edges(params: PotentialParams, seed: int) -> np.ndarray | None:
    """The fixed graph's edges (None for the switching topology)."""
    if params.topology != "fixed":
        return None
    return fixed_graph_edges(params.n, params.graph, seed, params.graph_p, params.graph_file)


def control(x: np.ndarray, v: np.ndarray, params: PotentialParams, edges: np.ndarray | None = None) -> np.ndarray:
    """u_i = - sum_{j in N_i} (v_i - v_j) - sum_{j in N_i} 2 (|r_ij|^2 - d^2) / |r_ij|^4 r_ij (eq. 3)."""
    a = neighbour_matrix(x, params, edges)
    r_ij = x[:, None, :] - x[None, :, :]
    r2 = (r_ij * r_ij).sum(axis=2)
    np.fill_diagonal(r2, 1)
    d2 = x.dtype.type(params.desired_distance) ** 2
    grad = 2 * (r2 - d2) / (r2 * r2)
    w = a.astype(x.dtype)
    align = (w[:, :, None] * (v[None, :, :] - v[:, None, :])).sum(axis=1)
    return align - ((w * grad)[:, :, None] * r_ij).sum(axis=1)


def potential_step(x: np.ndarray, v: np.ndarray, params: PotentialParams,
                   edges: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One semi-implicit Euler step: (x(t + dt), v(t + dt))."""
    dt = x.dtype.type(params.dt)
    v_new = v + dt * control(x, v, params, edges)
    return x + dt * v_new, v_new


def potential_metrics(x: np.ndarray, v: np.ndarray, params: PotentialParams,
                      edges: np.ndarray | None = None) -> dict[str, float]:
    """Energies, Lyapunov function (W, eq. 5, or Q, eq. 10, less N (N - 1) / 2 V(R)), velocity and graph metrics."""
    x, v = x.astype(np.float64), v.astype(np.float64)
    a = neighbour_matrix(x, params, edges)
    r2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(axis=2)
    np.fill_diagonal(r2, np.inf)
    d2, big_r2 = params.desired_distance**2, params.radius**2
    with np.errstate(divide="ignore"):
        pair_v = d2 / r2 + np.log(r2)
    if params.topology == "switching":
        pair_v = pair_v - (d2 / big_r2 + np.log(big_r2))
    potential = 0.5 * float(np.where(a, pair_v, 0.0).sum())
    speed = np.sqrt((v * v).sum(axis=1))
    mismatch = np.sqrt(((v - v.mean(axis=0)) ** 2).sum(axis=1))
    valency = a.sum(axis=1)
    kinetic = 0.5 * float((speed**2).sum())
    laplacian = np.diag(valency.astype(np.float64)) - a
    eig = np.linalg.eigvalsh(laplacian)
    nearest = float(np.sqrt(r2.min()))
    if params.n > 4096:
        nearest = min(nearest, params.radius)
    return {
        "velocity_mismatch_mean": float(mismatch.mean()), "velocity_mismatch_max": float(mismatch.max()),
        "speed_mean": float(speed.mean()), "speed_spread": float(speed.max() - speed.min()),
        "polarization": float(np.linalg.norm((v / speed[:, None]).mean(axis=0))),
        "kinetic_energy": kinetic, "potential_energy": potential, "W": kinetic + potential, "Q": kinetic + potential,
        "min_distance": nearest, "valency_mean": float(valency.mean()), "valency_min": float(valency.min()),
        "valency_max": float(valency.max()), "components": float((eig < 1e-9).sum()),
        "connected": float((eig < 1e-9).sum() == 1), "lambda2": float(eig[1]),
        **{f"valency_{i}": float(valency[i]) for i in range(len(x))},
        **{f"speed_{i}": float(speed[i]) for i in range(len(x))},
    }
