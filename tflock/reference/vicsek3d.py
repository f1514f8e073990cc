"""NumPy oracle of the 3D Vicsek model (:mod:`tflock.models.vicsek3d`), plain O(N^2).

Straight from the step the model's docstring states, every pair tested, with the draws of :mod:`tflock.rng` under
the keys the kernel uses. Arithmetic runs in the dtype of the inputs (float32 arrays mirror an f32 kernel).
"""

from __future__ import annotations

import math

import numpy as np

from tflock.config import VicsekParams
from tflock.reference import apply_boundary, graph_metrics, neighbour_matrix, unit_noise
from tflock.reference.adaptive import add_noise, initial_draws, orthonormal_basis
from tflock.reference.observables import transition_metrics_np


def initial_state(params: VicsekParams, seed: int) -> dict[str, np.ndarray]:
    """Positions uniform in [0, L)^3, directions uniform on the sphere (float64)."""
    x, d = initial_draws(params, seed)
    return {"x": x, "d": d}


def turn_toward(d: np.ndarray, target: np.ndarray, alpha: float) -> np.ndarray:
    """Each row of d turned toward the unit row of `target` by at most `alpha` radians (003 eq. 7 in 3D): the
    target itself when it is within alpha, else d rotated by alpha in the plane of the two (for a target exactly
    opposite d, the plane of d and the first vector of its orthonormal basis)."""
    one = d.dtype.type(1)
    c = (d * target).sum(axis=1)
    w = target - c[:, None] * d
    norm = np.sqrt((w * w).sum(axis=1))
    b1, _ = orthonormal_basis(d)
    w = np.where((norm > 0)[:, None], w / np.where(norm > 0, norm, one)[:, None], b1)
    cos_a, sin_a = d.dtype.type(math.cos(alpha)), d.dtype.type(math.sin(alpha))
    return np.where((c < cos_a)[:, None], cos_a * d + sin_a * w, target)


def move(x: np.ndarray, d: np.ndarray, speed: float, boundary: str, box: float) -> tuple[np.ndarray, np.ndarray]:
    """x + v0 d, then the boundary: wrap (periodic) or mirror the coordinate and flip that direction component."""
    x, flip = apply_boundary(x + x.dtype.type(speed) * d, boundary, box)
    return x, np.where(flip, -d, d)


def vicsek3d_step(x: np.ndarray, d: np.ndarray, t: int, params: VicsekParams, seed: int):
    """One synchronous step t -> t+1; returns (x, d) at t+1."""
    real = d.dtype.type
    a = neighbour_matrix(x, params).astype(d.dtype)
    m = d + a @ d
    if params.noise_type == "vectorial":
        weight = real(params.noise) * (1 + a.sum(axis=1))
        m = m + weight[:, None] * unit_noise(seed, t, len(d), 3, real)
    norm = np.sqrt((m * m).sum(axis=1))
    new = np.where((norm > 0)[:, None], m / np.where(norm > 0, norm, real(1))[:, None], d)
    if params.max_turn_deg < 180:
        new = turn_toward(d, new, math.radians(params.max_turn_deg))
    if params.noise_type == "angular":
        new = add_noise(new, t, params.noise / 2, seed)
    return move(x, new, params.speed, params.boundary, params.box)


def vicsek3d_metrics(x: np.ndarray, d: np.ndarray, previous_d: np.ndarray, params: VicsekParams) -> dict[str, float]:
    """Polarization |mean d|, the R-graph metrics, the mean angle turned at the last step and the transition's
    observables."""
    d64, p64 = d.astype(np.float64), previous_d.astype(np.float64)
    cos_turn = np.clip((d64 * p64).sum(axis=1) / np.linalg.norm(d64, axis=1) / np.linalg.norm(p64, axis=1), -1, 1)
    out = {"polarization": float(np.linalg.norm(d64.mean(axis=0)))}
    out.update(graph_metrics(x, params.radius, params.boundary, params.box))
    out["de_theta"] = float(np.arccos(cos_turn).mean())
    out.update(transition_metrics_np(x, d64.mean(axis=0), params.boundary, params.box, params.radius))
    return out
