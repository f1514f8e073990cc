"""The uncertainty of a reproduced number: 95 % confidence intervals, and the verdict they allow.

Every number a ``comparison.md`` sets beside the paper's comes with its replicas and an interval from this module;
it "agrees" only when the paper's number lies within that interval (:meth:`Estimate.holds`). Means get Student's t
interval, fractions Wilson's score interval, paired differences the t interval of the differences, and statistics
of a whole table (a least-squares fit over several points) a percentile bootstrap over the replicas of each point.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

LEVEL = 0.95
#: two-sided 95 % quantiles of Student's t for 1 .. 30 degrees of freedom
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)
_Z95 = 1.959964
BOOTSTRAP_RESAMPLES = 2000


def t95(df: int) -> float:
    """The 97.5 % quantile of Student's t with `df` degrees of freedom (table to 30; 1.96 + 2.5 / df beyond, within
    0.002 of the exact value)."""
    if df < 1:
        return math.inf
    return _T95[df - 1] if df <= len(_T95) else _Z95 + 2.5 / df


@dataclass(frozen=True)
class Estimate:
    """A number measured over `n` replicas with its 95 % confidence interval [lo, hi] (nan where one replica
    gives no interval: then nothing agrees with it)."""

    value: float
    lo: float
    hi: float
    n: int

    def holds(self, paper: float) -> bool:
        """Whether the paper's number lies within the interval."""
        return bool(self.lo <= paper <= self.hi)

    def excludes(self, value: float) -> bool:
        """Whether there is an interval and `value` lies outside it (a difference that is not zero)."""
        return bool(self.lo > value or self.hi < value)

    def overlaps(self, low: float, high: float) -> bool:
        """Whether the interval meets [low, high] (a range the paper gives, such as its extremes)."""
        return bool(self.lo <= high and self.hi >= low)

    def text(self, digits: int = 2, unit: str = "", runs: str = "runs") -> str:
        """``851 tu (95 % CI 790 to 912; 10 runs)``."""
        if math.isnan(self.value):
            return f"no value ({self.n} {runs})"
        u = f" {unit}" if unit else ""
        if math.isnan(self.lo):
            return f"{self.value:.{digits}f}{u} ({self.n} {runs}: no interval)"
        return f"{self.value:.{digits}f}{u} (95 % CI {self.lo:.{digits}f} to {self.hi:.{digits}f}; {self.n} {runs})"

    def short(self, digits: int = 2) -> str:
        """``851 [790, 912]``: for table cells whose header names the replicas."""
        if math.isnan(self.value):
            return "-"
        if math.isnan(self.lo):
            return f"{self.value:.{digits}f}"
        return f"{self.value:.{digits}f} [{self.lo:.{digits}f}, {self.hi:.{digits}f}]"


NAN = Estimate(math.nan, math.nan, math.nan, 0)


def mean_ci(values: Sequence[float] | np.ndarray) -> Estimate:
    """The mean and its t interval (one value: an interval of zero width is not claimed, it is unbounded)."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return NAN
    mean = float(x.mean())
    if len(x) == 1:
        return Estimate(mean, math.nan, math.nan, 1)
    half = t95(len(x) - 1) * float(x.std(ddof=1)) / math.sqrt(len(x))
    return Estimate(mean, mean - half, mean + half, len(x))


def paired_difference_ci(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> Estimate:
    """Mean of b - a over pairs (the same replica, so the same initial state, in both cases) and its t interval."""
    return mean_ci(np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64))


def difference_ci(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> Estimate:
    """Mean of b less mean of a for independent samples, with Welch's t interval."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if len(x) < 2 or len(y) < 2:
        return Estimate(float(y.mean() - x.mean()) if len(x) and len(y) else math.nan, math.nan, math.nan,
                        len(x) + len(y))
    vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
    se = math.sqrt(vx + vy)
    df = (vx + vy) ** 2 / ((vx**2 / (len(x) - 1) if vx else 0) + (vy**2 / (len(y) - 1) if vy else 0)) if se else 1
    diff = float(y.mean() - x.mean())
    half = t95(max(1, int(df))) * se
    return Estimate(diff, diff - half, diff + half, len(x) + len(y))


def proportion_ci(successes: int, n: int) -> Estimate:
    """A fraction and Wilson's score interval (sound at 0 and 1, where the normal one collapses)."""
    if n == 0:
        return NAN
    p = successes / n
    z2 = _Z95**2
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = _Z95 * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return Estimate(p, max(0.0, centre - half), min(1.0, centre + half), n)


def share_text(fraction: float, n: float, percent: bool = False) -> str:
    """A fraction of `n` replicas with its Wilson interval: ``0.96 [0.87, 0.99]``, or ``96 % [87, 99]``; ``-``
    where there is none (no replicas, or no fraction)."""
    if not (np.isfinite(fraction) and np.isfinite(n) and n >= 1):
        return "-"
    estimate = proportion_ci(int(round(fraction * n)), int(round(n)))
    if percent:
        return f"{100 * estimate.value:.0f} % [{100 * estimate.lo:.0f}, {100 * estimate.hi:.0f}]"
    return estimate.short(2)


def bootstrap_ci(samples: np.ndarray, statistic: Callable[[np.ndarray], float], value: float, seed: int = 0,
                 resamples: int = BOOTSTRAP_RESAMPLES) -> Estimate:
    """Percentile interval of `statistic` over resamples of `samples`' rows with replacement. `samples` holds one
    row per replica and one column per point of a curve (NaN where that replica gave no value there); a replica
    runs with the same seed, so from the same initial state, at every point, and its values at the points are
    correlated: its row is drawn whole, not point by point (which misjudged the spread of the fits of Li & Wang's
    Fig. 5, as the correlation carries into each coefficient differently). `value` is the statistic of `samples`
    itself; n in the estimate is the number of rows."""
    rng = np.random.default_rng(seed)
    rows = np.asarray(samples, dtype=np.float64)
    draws = np.empty(resamples)
    for k in range(resamples):
        draws[k] = statistic(rows[rng.integers(0, len(rows), len(rows))])
    lo, hi = np.nanquantile(draws, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return Estimate(float(value), float(lo), float(hi), len(rows))


def verdict(ok: bool) -> str:
    return "agrees" if ok else "does NOT agree"
