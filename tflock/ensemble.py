"""Ensembles: many independent realisations of one config, batched into the same kernel launches.

Replica r of a config is the run with seed ``config.seed + r``. Models that support batching (their class's
``can_batch(params)`` is true: Vicsek up to 4096 agents, adaptive) run a batch of replicas as one system whose
agents carry a replica index in their ids, their random keys and their neighbour grid, so replica r of a batch
is bit-identical to the lone run with seed + r; other models run their replicas one after the other. Either way
each replica's metrics table is what :meth:`tflock.simulation.Simulation.metrics` gives for that run: rows at
step 0, every ``log.metrics_every`` steps and at the last step.
"""

from collections.abc import Callable

import numpy as np

from tflock.config import Config
from tflock.engine import init_engine
from tflock.models import model_class

#: agents in one batch at most: bounds memory, while a batch stays big enough to keep every core busy
BATCH_AGENTS = 1 << 21

MetricsTable = dict[str, np.ndarray]


def replica_config(config: Config, replica: int) -> Config:
    """The config of replica `replica`: the same with seed ``config.seed + replica``."""
    return config.model_copy(update={"seed": config.seed + replica})


def batch_size(config: Config, replicas: int) -> int:
    """Replicas per batch: all of them, unless that would exceed :data:`BATCH_AGENTS` agents."""
    return max(1, min(replicas, BATCH_AGENTS // config.params.n))


def run_replicas(config: Config, replicas: int,
                 progress: Callable[[int], None] | None = None) -> list[MetricsTable]:
    """Metrics tables of replicas 0 .. replicas - 1 of `config`, batched where the model supports it.

    ``progress(done)``, if given, is called after every step with the replica-steps done so far (out of
    ``replicas * config.steps``).
    """
    cls = model_class(config.model)
    if not cls.can_batch(config.params):
        return [_lone(replica_config(config, r), r * config.steps, progress) for r in range(replicas)]
    tables: list[MetricsTable] = []
    size = batch_size(config, replicas)
    for first in range(0, replicas, size):
        tables.extend(_batch(config, first, min(size, replicas - first), progress))
    return tables


def _lone(config: Config, done: int, progress: Callable[[int], None] | None) -> MetricsTable:
    from tflock.simulation import Simulation

    simulation = Simulation(config)
    simulation.run(None if progress is None else lambda t: progress(done + t))
    return simulation.metrics()


def _batch(config: Config, first: int, count: int, progress: Callable[[int], None] | None) -> list[MetricsTable]:
    """Replicas first .. first + count - 1 in one batched model, observed at the cadence of a lone run."""
    engine = init_engine(config.engine.arch, config.engine.threads, config.engine.precision)
    model = model_class(config.model)(config.params, config.seed + first, engine, replicas=count)
    names = list(model.metric_descriptions)
    rows: list[tuple[int, dict[str, np.ndarray]]] = [(0, model.replica_metrics())]
    for _ in range(config.steps):
        model.advance(1)
        t = model.step_index
        if t % config.log.metrics_every == 0 or t == config.steps:
            rows.append((t, model.replica_metrics()))
        if progress is not None:
            progress(first * config.steps + count * t)
    steps = np.array([float(t) for t, _ in rows])
    return [{"step": steps, "time": steps * model.dt, **{name: np.array([values[name][r] for _, values in rows])
                                                        for name in names}}
            for r in range(count)]
