"""``tflock reproduce NAME``: the published results of the seed papers, one command each.

Each experiment lives in its own module and registers in :data:`EXPERIMENTS`; :func:`reproduce` runs its sweeps
(:func:`tflock.sweep.run_sweep`: resumable, in-process or on Dask) and single runs, then writes its figures (PNG),
its table (CSV) and ``comparison.md`` under ``results/NAME/``.
"""

import importlib

from tflock.config import ConfigError
from tflock.reproduce.experiment import Experiment, Report, Results

#: name -> "module:Class", imported on use
EXPERIMENTS: dict[str, str] = {
    "vicsek-noise": "tflock.reproduce.vicsek_noise:VicsekNoise",
    "jadbabaie": "tflock.reproduce.jadbabaie:Jadbabaie",
    "tanner": "tflock.reproduce.tanner:Tanner",
    "formation": "tflock.reproduce.formation:Formation",
    "liwang": "tflock.reproduce.liwang:LiWang",
    "samiloglu": "tflock.reproduce.samiloglu:Samiloglu",
}


def experiment(name: str) -> Experiment:
    """The experiment called `name`; a :class:`~tflock.config.ConfigError` naming the known ones otherwise."""
    if name not in EXPERIMENTS:
        raise ConfigError(f"reproduce: unknown experiment {name!r}; known: {', '.join(sorted(EXPERIMENTS))}")
    module, cls = EXPERIMENTS[name].split(":")
    return getattr(importlib.import_module(module), cls)()


__all__ = ["EXPERIMENTS", "Experiment", "Report", "Results", "experiment"]
