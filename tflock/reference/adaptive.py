"""NumPy oracle of the Li-Wang adaptive-velocity model (DESIGN.md section 3.2; papers/002), plain O(N^2).

Straight from the equations, every pair tested, with the draws of :mod:`tflock.rng` under the keys the kernel
uses. Arithmetic runs in the dtype of the inputs (float32 arrays mirror an f32 kernel, float64 an f64 one).

- init: X uniform in [0, L)^d, raw directions uniform on the circle / sphere, then phi_i(0), d_i(0) from eq. (4)
  with the neighbours at X(0) (itself included), without noise;
- step k -> k+1: X_i(k+1) = X_i(k) + v0 c(phi_i(k)) d_i(k) (eqs. 5, 8), neighbours at X(k+1), m_i the mean of
  d_j(k) over them (eqs. 4, 7, 9), phi_i(k+1) = |m_i| (clamped to 1 against rounding), d_i(k+1) = m_i / |m_i|
  (d_i(k) kept when m_i = 0), then the noise of eq. (12) (2D) or its 3D cone version.
"""

from __future__ import annotations

import math

import numpy as np

from tflock.models.adaptive_params import AdaptiveParams, agreement_tolerance
from tflock.reference import components, displacements
from tflock.rng import Stream, uniform_np

TWO_PI = 2 * math.pi


def speed_coefficient(phi: np.ndarray, alpha: float | str, tol: float) -> np.ndarray:
    """c_alpha(phi) = phi^alpha (Fig. 2, eq. 11); for alpha = inf eq. (6): 1 where phi >= 1 - tol, else 0."""
    if alpha == "inf":
        return (phi >= 1 - tol).astype(phi.dtype)
    return np.power(phi, phi.dtype.type(alpha))


def initial_draws(params: AdaptiveParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """X(0) uniform in [0, L)^d and directions uniform on the circle (2D) or the sphere (3D), float64."""
    ids = np.arange(params.n)
    axes = (Stream.INIT_X, Stream.INIT_Y, Stream.INIT_Z)[: params.dim]
    x = np.stack([params.box * uniform_np(seed, 0, ids, s) for s in axes], axis=1)
    u = uniform_np(seed, 0, ids, Stream.INIT_HEADING)
    if params.dim == 2:
        theta = TWO_PI * u
        return x, np.stack([np.cos(theta), np.sin(theta)], axis=1)
    z = 1 - 2 * u  # Archimedes: z uniform in [-1, 1] and an independent azimuth give the uniform sphere
    azimuth = TWO_PI * uniform_np(seed, 0, ids, Stream.INIT_HEADING_2)
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    return x, np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)


def orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vectors n (rows) to right-handed bases (Duff et al. 2017, branchless)."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(z >= 0, 1.0, -1.0).astype(n.dtype)
    a = -1 / (sign + z)
    b = x * y * a
    b1 = np.stack([1 + sign * x * x * a, sign * b, -sign * x], axis=1)
    b2 = np.stack([b, sign + y * y * a, -y], axis=1)
    return b1, b2


def add_noise(d: np.ndarray, t: int, eta: float, seed: int) -> np.ndarray:
    """Noise at step t on unit directions d (rows).

    2D, eq. (12): rotate by xi = eta (2u - 1) ~ U[-eta, eta], u from ``Stream.NOISE``. 3D (not in the paper):
    a direction uniform in the spherical cap of half-angle eta around d: cos of the polar angle uniform in
    [cos eta, 1] (``Stream.NOISE``), azimuth uniform in [0, 2 pi) (``Stream.NOISE_2``), about the basis of
    :func:`orthonormal_basis`. Both reduce to d for eta = 0 and leave phi unchanged.
    """
    ids = np.arange(len(d))
    u = uniform_np(seed, t, ids, Stream.NOISE).astype(d.dtype)
    one = d.dtype.type(1)
    if d.shape[1] == 2:
        xi = d.dtype.type(eta) * (2 * u - one)
        c, s = np.cos(xi), np.sin(xi)
        return np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1)
    cos_eta = d.dtype.type(math.cos(eta))
    ct = cos_eta + (one - cos_eta) * u
    st = np.sqrt(np.maximum(0, one - ct * ct))
    azimuth = d.dtype.type(TWO_PI) * uniform_np(seed, t, ids, Stream.NOISE_2).astype(d.dtype)
    b1, b2 = orthonormal_basis(d)
    return ct[:, None] * d + (st * np.cos(azimuth))[:, None] * b1 + (st * np.sin(azimuth))[:, None] * b2


def neighbourhoods(x: np.ndarray, params: AdaptiveParams) -> np.ndarray:
    """Gamma[i, j] = |X_j - X_i| <= R, itself included (minimum image when periodic)."""
    d = displacements(x, params.boundary, params.box)
    r = x.dtype.type(params.radius)
    return (d * d).sum(axis=2) <= r * r


def align(x: np.ndarray, d: np.ndarray, t: int, params: AdaptiveParams, seed: int, noise: bool = True):
    """phi_i and d_i from eq. (4) / (7), (9) with the neighbours at positions x, then the noise of step t."""
    gamma = neighbourhoods(x, params).astype(d.dtype)
    m = (gamma @ d) / gamma.sum(axis=1)[:, None]
    norm = np.sqrt((m * m).sum(axis=1))
    phi = np.minimum(norm, d.dtype.type(1))
    safe = np.where(norm > 0, norm, d.dtype.type(1))
    new = np.where((norm > 0)[:, None], m / safe[:, None], d)
    if noise and params.noise > 0:
        new = add_noise(new, t, params.noise, seed)
    return new, phi


def initial_state(params: AdaptiveParams, seed: int, real: type = np.float64) -> dict[str, np.ndarray]:
    """The paper's initial state: phi_i(0), d_i(0) from eq. (4) with the neighbours at X(0) (no noise)."""
    x, raw = initial_draws(params, seed)
    x, raw = x.astype(real), raw.astype(real)
    d, phi = align(x, raw, 0, params, seed, noise=False)
    return {"x": x, "d": d, "phi": phi}


def adaptive_step(x: np.ndarray, d: np.ndarray, phi: np.ndarray, t: int, params: AdaptiveParams, seed: int):
    """One step k = t -> t+1 (eqs. 5, 8-9, 12); returns (x, d, phi) at t+1."""
    tol = agreement_tolerance(x.dtype.itemsize)
    c = speed_coefficient(phi, params.alpha, tol)
    x = x + x.dtype.type(params.speed) * c[:, None] * d
    if params.boundary == "periodic":
        box = x.dtype.type(params.box)
        x = x - box * np.floor(x / box)
        x = np.where((x >= box) | (x < 0), 0, x).astype(d.dtype)
    d, phi = align(x, d, t, params, seed)
    return x, d, phi


def adaptive_metrics(x: np.ndarray, d: np.ndarray, phi: np.ndarray, params: AdaptiveParams) -> dict[str, float]:
    """Phi_theta (eq. 3), Phi_v (eq. 2), C_alpha (eq. 11), mean speed / v0 and the R-graph metrics."""
    c = speed_coefficient(phi, params.alpha, agreement_tolerance(x.dtype.itemsize)).astype(np.float64)
    d64 = d.astype(np.float64)
    gamma = neighbourhoods(x, params)
    np.fill_diagonal(gamma, False)
    _, sizes = np.unique(components(gamma), return_counts=True)
    degree = gamma.sum(axis=1)
    return {
        "phi_theta": float(np.linalg.norm(d64.mean(axis=0))),
        "phi_v": float(np.linalg.norm((c[:, None] * d64).mean(axis=0))),
        "c_alpha": float(c.mean()),
        "mean_speed": float((c * np.linalg.norm(d64, axis=1)).mean()),
        "clusters": float(len(sizes)),
        "largest_cluster": float(sizes.max() / len(x)),
        "mean_neighbors": float(degree.mean()),
        "max_neighbors": float(degree.max()),
    }
