"""One point of a sweep: its replicas run and summarised as result rows.

:func:`run_point` is the single entry point that turns a config and a replica count into rows; the sweep runner,
its Dask tasks and ``tflock reproduce`` call nothing else to run a point, so how the replicas are computed (one
after another, or batched in one kernel launch per step: :mod:`tflock.ensemble`) can change behind it.
"""

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from tflock.config import Config, config_to_dict, config_to_toml, load_config, tomllib

__all__ = ["run_point", "summarise"]

SUMMARIES = ("mean", "std")
"""Statistics of every metric over the second half of the run (the logged steps >= steps / 2)."""
EXTREMES = ("min", "max")
"""Statistics of every metric over the whole run (every logged step, the initial state's included)."""
POOLED = "_pooled"
"""Suffix of the columns computed over the second halves of all replicas of a point (the same in each of its rows)."""


def run_point(config: Config | Mapping[str, Any] | str, replicas: int, seed: int) -> list[dict[str, Any]]:
    """Run ``replicas`` realisations of ``config`` (a :class:`~tflock.config.Config`, a nested dict or TOML text),
    replica r with seed ``seed + r``, without recording; one row per replica (see :func:`summarise`).

    Taichi starts here on first use, with the config's ``[engine]`` settings (once per process).
    """
    from tflock.ensemble import replica_config, run_replicas
    from tflock.observables import order_statistics

    if isinstance(config, str):
        config = tomllib.loads(config)
    base = config_to_dict(config) if isinstance(config, Config) else config
    first = load_config(base, overrides={"seed": seed})
    start = time.perf_counter()
    tables = run_replicas(first, replicas)
    wall_s = (time.perf_counter() - start) / replicas  # batched replicas share their wall time
    halves = [_second_half(first, table) for table in tables]
    pooled = order_statistics({m: np.concatenate([h[m] for h in halves]) for m in halves[0]}, first.params.n,
                              suffix=POOLED)
    return [{"replica": r, **summarise(replica_config(first, r), table), **pooled, "wall_s": wall_s}
            for r, table in enumerate(tables)]


def _second_half(config: Config, table: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each metric's values at the logged steps >= steps / 2."""
    late = np.asarray(table["step"]) >= config.steps / 2
    return {m: np.asarray(values)[late] for m, values in table.items() if m not in ("step", "time")}


def summarise(config: Config, table: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """A replica's row from its config and metrics table (columns ``step``, ``time`` and one per metric, as
    :meth:`tflock.simulation.Simulation.metrics` gives): ``seed``, ``steps``, ``final_<m>`` (the last logged step),
    ``mean_<m>`` and ``std_<m>`` over the logged steps >= steps / 2, ``min_<m>`` and ``max_<m>`` over every logged
    step where m is not NaN (the smallest distance of a whole run, say), for each order parameter m (e.g.
    ``polarization``) its Binder cumulant ``binder_<m>`` and susceptibility ``susceptibility_<m>`` over those steps
    (:mod:`tflock.observables`), and ``config`` (its full TOML). :func:`run_point` adds ``binder_<m>_pooled`` and
    ``susceptibility_<m>_pooled``, over the second halves of all replicas of the point."""
    from tflock.observables import order_statistics

    late = _second_half(config, table)
    row: dict[str, Any] = {"seed": config.seed, "steps": config.steps}
    row.update({f"final_{m}": float(table[m][-1]) for m in late})
    for statistic in SUMMARIES:
        function = getattr(np, statistic)
        row.update({f"{statistic}_{m}": float(function(values)) for m, values in late.items()})
    for m in late:
        taken = np.asarray(table[m], dtype=np.float64)
        taken = taken[~np.isnan(taken)]  # (a metric not yet defined at a step, e.g. tau, is NaN there)
        row.update({f"{statistic}_{m}": float(getattr(taken, statistic)()) if taken.size else math.nan
                    for statistic in EXTREMES})
    row.update(order_statistics(late, config.params.n))
    row["config"] = config_to_toml(config)
    return row
