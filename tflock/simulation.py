"""The run loop: a model stepped through its config, with metrics and frames at their cadences.

Metrics are computed at step 0 and every ``log.metrics_every`` steps (and at the last step), frames every
``log.every`` steps; both go to the recorder when one is attached. Before anything is kept or written for a step
(metrics, a frame, a checkpoint), the non-finite guard checks the state: a nan or infinite position, heading or
velocity stops the run with :class:`NumericalFaultError` (see there). A :class:`Simulation` is also the Python API:

    sim = Simulation("configs/vicsek.toml", params={"n": 5000}, steps=200)
    sim.run()
    sim.state()["x"], sim.metrics()["polarization"]
"""

from __future__ import annotations

import os
import time
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
from tflock.preflight import check_memory, check_writable
from tflock.rng import Stream, hash_np

#: the guard keeps a host copy of a good state when the time since the last copy is this many times what the copy
#: took: copying costs about 0.5 % of the run, and a replay after a fault covers only the steps since the copy
GOOD_COPY_RATIO = 200


class NumericalFaultError(RuntimeError):
    """A non-finite position, heading or velocity stopped the run (the message is one line).

    The run is replayed from the last kept good state, checking every step, to find the first bad ``step`` and
    the smallest bad ``agent`` id; the simulation is left at the last good state (step - 1), whose checkpoint was
    written to ``checkpoint`` (None if it could not be written), and its recording is closed: nothing is logged
    for steps after the last one that passed the guard.
    """

    def __init__(self, message: str, *, model: str, step: int, agent: int, quantity: str,
                 checkpoint: Path | None) -> None:
        super().__init__(message)
        self.model, self.step, self.agent, self.quantity, self.checkpoint = model, step, agent, quantity, checkpoint


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
        raise ConfigError(f"--resume: checkpoint not found: {path}" if not path.exists() else
                          f"--resume: {path} is not a checkpoint file")
    try:
        with np.load(path, allow_pickle=False) as data:
            if int(data["format"]) != CHECKPOINT_FORMAT or "config_toml" not in data.files:
                raise KeyError("format")
            keys = data.files if arrays else ["config_toml", "recording_id", "step"]
            out = {k: data[k] for k in keys}
        tomllib.loads(str(out["config_toml"]))
        return out
    except (OSError, EOFError, TypeError, ValueError, KeyError, zipfile.BadZipFile, tomllib.TOMLDecodeError):
        raise ConfigError(f"--resume: {path} is not a tflock checkpoint (format {CHECKPOINT_FORMAT})") from None


def default_recording_path(model: str) -> Path:
    return Path("recordings") / f"{model}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


class Simulation:
    """One run of a model: build it from a config, step it, read its state and metrics, optionally record it.

    ``config`` is a TOML path, a nested dict, a :class:`Config`, or None for the model's defaults. Keyword
    overrides are nested like the TOML (``params={"noise": 0.3}``, ``steps=100``) or dotted strings in
    ``overrides`` (``["params.noise=0.3"]``, the CLI's ``--set``). ``record`` is False, True (a file under
    ``recordings/``) or an ``.rrd`` path; ``spawn`` / ``connect`` stream to a viewer. ``checkpoint`` /
    ``checkpoint_every``: write :meth:`save_checkpoint` there every k steps (``checkpoint`` also receives the last
    good state after a :class:`NumericalFaultError`); ``resume``: continue from such a file (bit-identical to the
    uninterrupted run; a recording goes to a new file with the same recording id). A config that needs more memory
    than the machine has is a :class:`ConfigError`, and an output path that cannot be written an OSError, both
    raised before anything is allocated or written.
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
        record_path = None if not record else Path(record) if not isinstance(record, bool) else (
            Path(config.log.out) if config.log.out else default_recording_path(config.model))
        check_memory(config)
        outputs = [(checkpoint, "checkpoint")]
        if record_path is not None:
            outputs += [(record_path, "recording"), (record_path.with_suffix(".metrics.csv"), "metrics table")]
        for path, what in outputs:
            if path is not None:
                check_writable(Path(path), what)
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
        self._refuse_non_finite_start()
        if record_path is not None or spawn or connect:
            self._open_recorder(record_path, spawn, connect)
        if saved is None:
            self._observe(force=True)
        self._checked = self.model.step_index  # the last step whose state passed the guard (or the start)
        self._keep_good()

    @property
    def step_index(self) -> int:
        return self.model.step_index

    def _open_recorder(self, path: Path | None, spawn: bool, connect: str | None) -> None:
        from tflock.record import Recorder

        table = path.with_suffix(".metrics.csv") if path is not None else None
        self.recorder = Recorder(model=self.config.model, config_toml=config_to_toml(self.config),
                                 world=self.model.world(), metrics=self.model.metric_descriptions,
                                 profiles=self.model.profile_descriptions,
                                 path=path, spawn=spawn, connect=connect, metrics_table=table,
                                 recording_id=self.recording_id)
        self.files = [p for p in (path, table) if p is not None]

    def _metrics_due(self, t: int) -> bool:
        return t % self.config.log.metrics_every == 0

    def _frame_due(self, t: int) -> bool:
        return self.recorder is not None and t % self.config.log.every == 0

    def _observe(self, force: bool = False) -> None:
        """Metrics and frame of the current step, at their cadences (or now, when forced)."""
        t = self.model.step_index
        if force or self._metrics_due(t):
            values = self.model.metrics()
            self._rows.append({"step": float(t), "time": t * self.model.dt, **values})
            if self.recorder is not None:
                self.recorder.log_metrics(t, values)
        if self.recorder is not None and (force or self._frame_due(t)):
            self.recorder.log_frame(t, self.model.frame(self._selected, self.config.log.max_edges))

    def step(self, steps: int = 1, progress: Callable[[int], None] | None = None) -> None:
        """Advance `steps` steps, taking metrics and frames at their cadences; `progress(step)` after each.
        Raises :class:`NumericalFaultError` when the state becomes non-finite."""
        for _ in range(steps):
            if self._frame_due(self.model.step_index + 1):
                self.model.draw_next(self._selected)
            self.model.advance(1)
            t = self.model.step_index
            last = t == self.config.steps
            checkpoint = bool(self.checkpoint_every and self.checkpoint_path and t % self.checkpoint_every == 0)
            if last or checkpoint or self._metrics_due(t) or self._frame_due(t):
                self._guard()
            self._observe(force=last)
            if checkpoint:
                self.save_checkpoint(self.checkpoint_path)
            if progress is not None:
                progress(t)

    # ------------------------------------------------------------------ the non-finite guard
    def _refuse_non_finite_start(self) -> None:
        """A start state that is already non-finite (numbers beyond the float range) stops before anything is
        written."""
        found = self.model.first_non_finite()
        if found is None:
            return
        agent, quantity = found
        t, precision = self.model.step_index, self.config.engine.precision
        largest = "3.4e38" if precision == "f32" else "1.8e308"
        raise NumericalFaultError(
            f"numerical fault in {self.config.model} at step {t}: agent {agent} has a non-finite {quantity} in the "
            f"start state (engine.precision = {precision} holds magnitudes up to {largest}); nothing was written",
            model=self.config.model, step=t, agent=agent, quantity=quantity, checkpoint=None)

    def _keep_good(self) -> None:
        """Keep a host copy of the current (good) state to replay from after a fault."""
        t0 = time.perf_counter()
        self._good = (self.model.checkpoint(), self.model.step_index)
        self._good_at = time.perf_counter()
        self._good_cost = self._good_at - t0

    def _guard(self) -> None:
        """Check the state before anything of this step is kept: stop at a non-finite value, else now and then
        keep a copy of this good state."""
        found = self.model.first_non_finite()
        if found is not None:
            self._fault(found)
        self._checked = self.model.step_index
        if time.perf_counter() - self._good_at >= GOOD_COPY_RATIO * self._good_cost:
            self._keep_good()

    def _fault(self, seen: tuple[int, str]) -> None:
        """Replay from the kept good state, checking every step after the last one that passed the guard, to the
        first bad step; save the state before it, close the recording and raise NumericalFaultError. `seen` is
        what the guard found at the current step."""
        detected = self.model.step_index
        arrays, start = self._good
        self.model.restore(arrays, start)
        self.model.advance(self._checked - start)
        found = None
        while found is None and self.model.step_index < detected:
            good = self.model.checkpoint()
            self.model.advance(1)
            found = self.model.first_non_finite()
        agent, quantity = found or seen  # steps are deterministic: the replay finds it again, at or before
        bad = self.model.step_index
        self.model.restore(good, bad - 1)
        path = self.checkpoint_path or (
            self.recorder.path if self.recorder is not None and self.recorder.path is not None
            else default_recording_path(self.config.model)).with_suffix(".lastgood.npz")
        try:
            saved: Path | None = self.save_checkpoint(path)
            where = f"the last good state (step {bad - 1}) is saved in {path}"
        except OSError as e:
            saved, where = None, f"the last good state (step {bad - 1}) could not be saved to {path}: {e.strerror or e}"
        self.close()
        message = (f"numerical fault in {self.config.model} at step {bad}: agent {agent} has a non-finite {quantity}; "
                   f"the run stopped (nothing after step {self._checked} is recorded) and {where}")
        raise NumericalFaultError(message, model=self.config.model, step=bad, agent=agent, quantity=quantity,
                                  checkpoint=saved)

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

