"""The run loop: a model stepped through its config, with metrics and frames at their cadences.

Metrics are computed at step 0 and every ``log.metrics_every`` steps (and at the last step), frames every
``log.every`` steps; both go to the recorder when one is attached. A :class:`Simulation` is also the Python API:

    sim = Simulation("configs/vicsek.toml", params={"n": 5000}, steps=200)
    sim.run()
    sim.state()["x"], sim.metrics()["polarization"]
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from tflock.config import Config, config_to_dict, config_to_toml, load_config, parse_override
from tflock.engine import EngineInfo, init_engine
from tflock.models import model_class
from tflock.rng import Stream, hash_np


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, Mapping):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), item, out)
    else:
        out[prefix] = value


def drawn_subset(n: int, max_agents: int, seed: int) -> np.ndarray:
    """Sorted ids of the agents drawn every frame: all of them, or the `max_agents` with the smallest hash."""
    if n <= max_agents:
        return np.arange(n)
    keys = hash_np(seed, 0, np.arange(n), Stream.SUBSET)
    return np.sort(np.argpartition(keys, max_agents)[:max_agents])


def default_recording_path(model: str) -> Path:
    return Path("recordings") / f"{model}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


class Simulation:
    """One run of a model: build it from a config, step it, read its state and metrics, optionally record it.

    ``config`` is a TOML path, a nested dict, a :class:`Config`, or None for the model's defaults. Keyword
    overrides are nested like the TOML (``params={"noise": 0.3}``, ``steps=100``) or dotted strings in
    ``overrides`` (``["params.noise=0.3"]``, the CLI's ``--set``). ``record`` is False, True (a file under
    ``recordings/``) or an ``.rrd`` path; ``spawn`` / ``connect`` stream to a viewer.
    """

    def __init__(self, config: str | Path | Mapping[str, Any] | Config | None = None, *,
                 model: str | None = None, overrides: list[str] | Mapping[str, Any] | None = None,
                 record: bool | str | Path = False, spawn: bool = False, connect: str | None = None,
                 **fields: Any) -> None:
        if isinstance(config, Config) and (overrides or fields or model):
            config = config_to_dict(config)
        if not isinstance(config, Config):
            merged: dict[str, Any] = {}
            if isinstance(overrides, Mapping):
                merged.update(overrides)
            elif overrides is not None:
                merged.update(parse_override(expr) for expr in overrides)
            _flatten("", fields, merged)
            config = load_config(config, model=model, overrides=merged)
        self.config: Config = config
        self.engine: EngineInfo = init_engine(config.engine.arch, config.engine.threads, config.engine.precision)
        self.model = model_class(config.model)(config.params, config.seed, self.engine)
        self._rows: list[dict[str, float]] = []
        self._selected = drawn_subset(config.params.n, config.log.max_agents, config.seed)
        self.recorder = None
        self.files: list[Path] = []
        if record or spawn or connect:
            self._open_recorder(record, spawn, connect)
        self._observe(force=True)

    @property
    def step_index(self) -> int:
        return self.model.step_index

    def _open_recorder(self, record: bool | str | Path, spawn: bool, connect: str | None) -> None:
        from tflock.record import Recorder

        path = None
        if record:
            path = Path(record) if not isinstance(record, bool) else (
                Path(self.config.log.out) if self.config.log.out else default_recording_path(self.config.model))
        table = path.with_suffix(".metrics.csv") if path is not None else None
        self.recorder = Recorder(model=self.config.model, config_toml=config_to_toml(self.config),
                                 world=self.model.world(), metrics=self.model.metric_descriptions,
                                 path=path, spawn=spawn, connect=connect, metrics_table=table)
        self.files = [p for p in (path, table) if p is not None]

    def _observe(self, force: bool = False) -> None:
        """Metrics and frame of the current step, at their cadences (or now, when forced)."""
        t = self.model.step_index
        log = self.config.log
        if force or t % log.metrics_every == 0:
            values = self.model.metrics()
            self._rows.append({"step": float(t), "time": t * self.model.dt, **values})
            if self.recorder is not None:
                self.recorder.log_metrics(t, values)
        if self.recorder is not None and (force or t % log.every == 0):
            self.recorder.log_frame(t, self.model.frame(self._selected, log.max_edges))

    def step(self, steps: int = 1, progress: Callable[[int], None] | None = None) -> None:
        """Advance `steps` steps, taking metrics and frames at their cadences; `progress(step)` after each."""
        for _ in range(steps):
            self.model.advance(1)
            last = self.model.step_index == self.config.steps
            self._observe(force=last)
            if progress is not None:
                progress(self.model.step_index)

    def run(self, progress: Callable[[int], None] | None = None) -> None:
        """Step up to the configured number of steps."""
        self.step(max(0, self.config.steps - self.model.step_index), progress)

    def sync(self) -> None:
        """Wait for queued kernels (for timing on asynchronous backends)."""
        import taichi as ti

        ti.sync()

    def state(self) -> dict[str, Any]:
        """NumPy snapshot: the model's arrays (e.g. ``x``, ``theta``) and ``step``."""
        return {**self.model.state(), "step": self.model.step_index}

    def metrics(self) -> dict[str, np.ndarray]:
        """The metrics table so far, as columns (``step``, ``time`` and one per metric): ``pd.DataFrame(...)``."""
        names = ["step", "time", *self.model.metric_descriptions]
        return {name: np.array([row[name] for row in self._rows]) for name in names}

    def close(self) -> None:
        """Finish the recording (idempotent)."""
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

