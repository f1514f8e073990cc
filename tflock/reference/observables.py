"""NumPy oracle of :mod:`tflock.observables`: box counts, slab profiles and the transition metrics of a state."""

import numpy as np

from tflock.observables import band_statistics, gnf_levels, number_fluctuations, profile_bins


def box_counts_np(x: np.ndarray, box: float, m: int) -> np.ndarray:
    """Reference of :func:`tflock.observables.box_counts` for one system, positions x (n, d) in the dtype the
    kernel uses."""
    cells = np.clip((x * x.dtype.type(m / box)).astype(np.int64), 0, m - 1)
    counts = np.zeros((m,) * x.shape[1], dtype=np.int64)
    np.add.at(counts, tuple(cells[:, a] for a in range(x.shape[1] - 1, -1, -1)), 1)
    return counts


def axis_profile_np(x: np.ndarray, axis: int, box: float, bins: int) -> np.ndarray:
    """Reference of :func:`tflock.observables.axis_profile` for one system."""
    b = np.clip((x[:, axis] * x.dtype.type(bins / box)).astype(np.int64), 0, bins - 1)
    return np.bincount(b, minlength=bins)


def transition_metrics_np(x: np.ndarray, mean_direction: np.ndarray, boundary: str, box: float,
                          radius: float) -> dict[str, float]:
    """What :class:`tflock.observables.TransitionObservables` gives for one system at positions x (n, d) whose
    mean heading is `mean_direction` (d,): none in open space."""
    if boundary == "open":
        return {}
    n, dim = x.shape
    out: dict[str, float] = {}
    levels = gnf_levels(n, dim, box)
    if levels:
        std, exponent = number_fluctuations(box_counts_np(x, box, levels[-1]))
        if len(levels) >= 2:
            out["gnf_exponent"] = exponent
        out.update({f"gnf_std_{m}": std[m] for m in levels})
    axis = int(np.argmax(np.abs(mean_direction)))
    peaks, contrast, _ = band_statistics(axis_profile_np(x, axis, box, profile_bins(box, radius)),
                                         boundary == "periodic")
    out["band_peaks"], out["band_contrast"] = peaks, contrast
    return out
