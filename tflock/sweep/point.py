"""One point of a sweep: its replicas run and summarised as result rows.

:func:`run_point` is the single entry point that turns a config and a replica count into rows; the sweep runner,
its Dask tasks and ``tflock reproduce`` call nothing else to run a point, so how the replicas are computed (one
after another, or batched in one kernel launch per step: :mod:`tflock.ensemble`) can change behind it.
"""

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from tflock.config import Config, config_to_dict, config_to_toml, load_config, tomllib

__all__ = ["run_point", "summarise"]

SUMMARIES = ("mean", "std")
"""Statistics of every metric over the second half of the run (the logged steps >= steps / 2)."""


def run_point(config: Config | Mapping[str, Any] | str, replicas: int, seed: int) -> list[dict[str, Any]]:
    """Run ``replicas`` realisations of ``config`` (a :class:`~tflock.config.Config`, a nested dict or TOML text),
    replica r with seed ``seed + r``, without recording; one row per replica (see :func:`summarise`).

    Taichi starts here on first use, with the config's ``[engine]`` settings (once per process).
    """
    from tflock.ensemble import replica_config, run_replicas

    if isinstance(config, str):
        config = tomllib.loads(config)
    base = config_to_dict(config) if isinstance(config, Config) else config
    first = load_config(base, overrides={"seed": seed})
    start = time.perf_counter()
    tables = run_replicas(first, replicas)
    wall_s = (time.perf_counter() - start) / replicas  # batched replicas share their wall time
    return [{"replica": r, **summarise(replica_config(first, r), table), "wall_s": wall_s}
            for r, table in enumerate(tables)]


def summarise(config: Config, table: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """A replica's row from its config and metrics table (columns ``step``, ``time`` and one per metric, as
    :meth:`tflock.simulation.Simulation.metrics` gives): ``seed``, ``steps``, ``final_<m>`` (the last logged step),
    ``mean_<m>`` and ``std_<m>`` over the logged steps >= steps / 2, and ``config`` (its full TOML)."""
    metrics = [name for name in table if name not in ("step", "time")]
    late = np.asarray(table["step"]) >= config.steps / 2
    row: dict[str, Any] = {"seed": config.seed, "steps": config.steps}
    row.update({f"final_{m}": float(table[m][-1]) for m in metrics})
    for statistic in SUMMARIES:
        function = getattr(np, statistic)
        row.update({f"{statistic}_{m}": float(function(np.asarray(table[m])[late])) for m in metrics})
    row["config"] = config_to_toml(config)
    return row
