"""The reports' statistics (tflock.reproduce.stats) against what they must mean."""

import numpy as np

from tflock.reproduce.stats import bootstrap_ci


def test_bootstrap_draws_a_replica_whole_across_the_points_of_a_curve() -> None:
    """A replica runs from one initial state at every point of a curve, so its values there are correlated: the
    bootstrap draws its row whole. For a slope through two points that share most of their variation, the interval
    is then narrow (the shared part cancels in the difference) where drawing the points apart would not let it
    cancel; for the mean over the points it is wide, the shared part not averaging out. Either way the interval
    holds the statistic of the sample itself, and a missing value (NaN) is left out of its point."""
    rng = np.random.default_rng(3)
    shared = rng.normal(0.0, 1.0, 200)
    rows = np.stack([shared + rng.normal(0.0, 0.1, 200), 1.0 + shared + rng.normal(0.0, 0.1, 200)], axis=1)

    def slope(sample: np.ndarray) -> float:
        means = np.nanmean(sample, axis=0)
        return float(means[1] - means[0])

    joint = bootstrap_ci(rows, slope, slope(rows), resamples=500)
    assert joint.lo <= slope(rows) <= joint.hi and joint.n == 200
    assert joint.hi - joint.lo < 0.1  # independent draws of the two points: about 4 * 1.4 / sqrt(200) = 0.4 wide
    level = bootstrap_ci(rows, lambda s: float(np.nanmean(s)), float(rows.mean()), resamples=500)
    assert level.hi - level.lo > 0.25  # points drawn apart: about 0.2 wide
    gaps = rows.copy()
    gaps[::2, 1] = np.nan
    assert np.isfinite(bootstrap_ci(gaps, slope, slope(gaps), resamples=100).lo)
