"""Ensembles: many independent realisations of one config, batched into the same kernel launches.

Replica r of a config is the run with seed ``config.seed + r``. Models that support batching (their class's
``can_batch(params)`` is true: Vicsek up to 4096 agents, adaptive) run a batch of replicas as one system whose
agents carry a replica index in their ids, their random keys and their neighbour grid, so replica r of a batch
is bit-identical to the lone run with seed + r; other models run their replicas one after the other. Either way
each replica's metrics table is what :meth:`tflock.simulation.Simulation.metrics` gives for that run: rows at
step 0, every ``log.metrics_every`` steps and at the last step.
"""

from collections.abc import Callable
from typing import Any

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

    ``progress(done)``, if given, is called as the steps complete (a lone run: at each observed step, see
    :meth:`tflock.simulation.Simulation.step`) with the replica-steps done so far (out of ``replicas * config.steps``).
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
    with np.errstate(over="ignore", invalid="ignore"):  # values beyond the float range: the guard refuses them
        model = model_class(config.model)(config.params, config.seed + first, engine, replicas=count)
    names = list(model.metric_descriptions)
    rows: list[tuple[int, dict[str, np.ndarray]]] = [(0, _checked_metrics(model, config, first))]
    for _ in range(config.steps):
        model.advance(1)
        t = model.step_index
        if t % config.log.metrics_every == 0 or t == config.steps:
            rows.append((t, _checked_metrics(model, config, first)))
        if progress is not None:
            progress(first * config.steps + count * t)
    steps = np.array([float(t) for t, _ in rows])
    return [{"step": steps, "time": steps * model.dt, **{name: np.array([values[name][r] for _, values in rows])
                                                        for name in names}}
            for r in range(count)]


def _checked_metrics(model: Any, config: Config, first: int) -> dict[str, np.ndarray]:
    """The batch's :meth:`replica_metrics`, after the non-finite guard a lone run applies (:mod:`tflock.guard`):
    a start state beyond the float range, or a non-finite state at a metrics step, stops the point with a
    :class:`~tflock.simulation.NumericalFaultError` naming the replica, its seed and the agent (ids in a batch are
    ``replica * n + agent``). A state that passed is measured without NumPy's overflow warnings (squares of
    distances beyond the float range are inf, as they should be)."""
    from tflock.simulation import NumericalFaultError, non_finite_start

    found = model.first_non_finite()
    if found is not None:
        slot, quantity = found
        offset, agent = divmod(slot, config.params.n)
        seed = config.seed + first + offset
        who, t = f"replica {first + offset} (seed {seed}), ", model.step_index
        if t == 0:
            raise non_finite_start(config, t, agent, quantity, who)
        raise NumericalFaultError(
            f"numerical fault in {config.model} at step {t}: {who}agent {agent} has a non-finite {quantity} (the "
            f"replicas are checked every log.metrics_every = {config.log.metrics_every} steps); the point stopped: "
            f"`tflock sim` with its config and --seed {seed} finds the first bad step and saves the last good state",
            model=config.model, step=t, agent=agent, quantity=quantity, checkpoint=None)
    with np.errstate(over="ignore"):
        return model.replica_metrics()
