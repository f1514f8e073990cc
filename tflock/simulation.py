"""The run loop: a model stepped through its config, with metrics and frames at their cadences.

Metrics are computed at step 0 and every ``log.metrics_every`` steps (and at the last step), frames every
``log.every`` steps; both go to the recorder when one is attached. A :class:`Simulation` is also the Python API:

    sim = Simulation("configs/vicsek.toml", params={"n": 5000}, steps=200)
    sim.run()
    sim.state()["x"], sim.metrics()["polarization"]
"""

from __future__ import annotations

import os
import uuid
import zipfile
from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from tflock.config import (
    Config,
    ConfigError,
    config_to_dict,
    config_to_toml,
    load_config,
    parse_override,
    tomllib,
)
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


CHECKPOINT_FORMAT = 1


def read_checkpoint(path: str | Path, *, arrays: bool = True) -> dict[str, Any]:
    """A checkpoint written by :meth:`Simulation.save_checkpoint` (no pickles are loaded); with
    ``arrays=False`` only its config and recording id, without reading the state arrays."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--resume: checkpoint not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            if int(data["format"]) != CHECKPOINT_FORMAT or "config_toml" not in data.files:
                raise KeyError("format")
            keys = data.files if arrays else ["config_toml", "recording_id", "step"]
            return {k: data[k] for k in keys}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        raise ConfigError(f"--resume: {path} is not a tflock checkpoint (format {CHECKPOINT_FORMAT})") from None


def default_recording_path(model: str) -> Path:
    return Path("recordings") / f"{model}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


class Simulation:
    """One run of a model: build it from a config, step it, read its state and metrics, optionally record it.

    ``config`` is a TOML path, a nested dict, a :class:`Config`, or None for the model's defaults. Keyword
    overrides are nested like the TOML (``params={"noise": 0.3}``, ``steps=100``) or dotted strings in
    ``overrides`` (``["params.noise=0.3"]``, the CLI's ``--set``). ``record`` is False, True (a file under
    ``recordings/``) or an ``.rrd`` path; ``spawn`` / ``connect`` stream to a viewer. ``checkpoint`` /
    ``checkpoint_every``: write :meth:`save_checkpoint` there every k steps; ``resume``: continue from such a file
    (bit-identical to the uninterrupted run; a recording goes to a new file with the same recording id).
    """

    def __init__(self, config: str | Path | Mapping[str, Any] | Config | None = None, *,
                 model: str | None = None, overrides: list[str] | Mapping[str, Any] | None = None,
                 record: bool | str | Path = False, spawn: bool = False, connect: str | None = None,
                 resume: str | Path | None = None, checkpoint: str | Path | None = None,
                 checkpoint_every: int = 0, **fields: Any) -> None:
        saved = None
        if resume is not None:  # the checkpoint carries the config
            saved = read_checkpoint(resume)
            if config is not None or model is not None:
                raise ConfigError("--resume: the checkpoint carries its config; do not also give a config or model")
            config = tomllib.loads(str(saved["config_toml"]))
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
        self.recording_id = uuid.uuid4().hex
        self.checkpoint_path = None if checkpoint is None else Path(checkpoint)
        self.checkpoint_every = checkpoint_every
        if saved is not None:
            self._restore(saved)
        if record or spawn or connect:
            self._open_recorder(record, spawn, connect)
        if saved is None:
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
                                 path=path, spawn=spawn, connect=connect, metrics_table=table,
                                 recording_id=self.recording_id)
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
            if self.checkpoint_every and self.checkpoint_path and self.model.step_index % self.checkpoint_every == 0:
                self.save_checkpoint(self.checkpoint_path)
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

    def save_checkpoint(self, path: str | Path) -> Path:
        """Write the full state (the model's arrays, step, config, metrics so far, recording id) to an .npz,
        atomically (a temporary file renamed over `path`). :class:`Simulation` ``(resume=path)`` continues it."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        table = self.metrics()
        arrays = {f"model__{k}": v for k, v in self.model.checkpoint().items()}
        arrays.update({f"metrics__{k}": v for k, v in table.items()})
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(f, **arrays, step=np.int64(self.model.step_index),
                     config_toml=np.str_(config_to_toml(self.config)), recording_id=np.str_(self.recording_id),
                     format=np.int64(CHECKPOINT_FORMAT))
        os.replace(tmp, path)
        if path not in self.files:
            self.files.append(path)
        return path

    def _restore(self, checkpoint: Mapping[str, Any]) -> None:
        arrays = {k.removeprefix("model__"): v for k, v in checkpoint.items() if k.startswith("model__")}
        try:
            self.model.restore(arrays, int(checkpoint["step"]))
        except ValueError as e:
            raise ConfigError(f"--resume: {e}") from None
        columns = {k.removeprefix("metrics__"): v for k, v in checkpoint.items() if k.startswith("metrics__")}
        self._rows = [{name: float(column[i]) for name, column in columns.items()}
                      for i in range(len(columns["step"]))]
        self.recording_id = str(checkpoint["recording_id"])

    def close(self) -> None:
        """Finish the recording (idempotent)."""
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

