"""The run loop: a model stepped through its config, with metrics and frames at their cadences.

Metrics are computed at step 0 and every ``log.metrics_every`` steps (and at the last step), frames every
``log.every`` steps; both go to the recorder when one is attached. Before anything is kept or written for a step
(metrics, a frame, a checkpoint), the guard checks the state: a nan or infinite position, heading or velocity, or
a Lyapunov function risen beyond integration error (:mod:`tflock.stability`), stops the run with
:class:`NumericalFaultError` (see there). A :class:`Simulation` is also the Python API:

    sim = Simulation("configs/vicsek.toml", params={"n": 5000}, steps=200)
    sim.run()
    sim.state()["x"], sim.metrics()["polarization"]
"""

from __future__ import annotations

import os
import time
import uuid
import weakref
import zipfile
from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from tflock.advice import warn_mistakes
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
from tflock.metric_rows import MetricRows
from tflock.models import model_class
from tflock.models.base import Lyapunov
from tflock.outputs import Outputs, claim, first_free
from tflock.preflight import check_memory, check_viewer
from tflock.rng import Stream, hash_np
from tflock.stability import cheap_test, lyapunov_test

#: Simulation.step hands the model at most this many steps at once, and at most this many agent-steps: a stop
#: request (Ctrl-C) is seen between two such runs of steps
CHUNK_STEPS = 256
CHUNK_AGENT_STEPS = 1 << 20
#: the guard keeps a host copy of a good state when the time since the last copy is this many times what the copy
#: took: copying costs about 0.5 % of the run, and a replay after a fault covers only the steps since the copy
GOOD_COPY_RATIO = 200


class NumericalFaultError(RuntimeError):
    """A non-finite position, heading or velocity, or an unstable integration (:mod:`tflock.stability`), stopped
    the run (the message is one line).

    The run is replayed from the last kept good state, checking every step, to find the first bad ``step`` and,
    for a non-finite state, the smallest bad ``agent`` id (for an unstable integration ``agent`` is None and
    ``quantity`` is "integration"); the simulation is left at the last good state (step - 1), whose checkpoint was
    written to ``checkpoint`` (None if it could not be written), and its recording is closed: nothing is logged
    for steps after the last one that passed the guard (the Lyapunov test runs at metrics steps only, so frames
    between two metrics steps passed the other tests alone).
    """

    def __init__(self, message: str, *, model: str, step: int, agent: int | None, quantity: str,
                 checkpoint: Path | None) -> None:
        super().__init__(message)
        self.model, self.step, self.agent, self.quantity, self.checkpoint = model, step, agent, quantity, checkpoint


def non_finite_start(config: Config, step: int, agent: int, quantity: str, who: str = "") -> NumericalFaultError:
    """The fault of a start state that is already non-finite (numbers beyond the range of the run's precision):
    nothing runs or is written. `who` names the agent's replica in a batch of replicas."""
    precision = config.engine.precision
    largest = "3.4e38" if precision == "f32" else "1.8e308"
    return NumericalFaultError(
        f"numerical fault in {config.model} at step {step}: {who}agent {agent} has a non-finite {quantity} in the "
        f"start state (engine.precision = {precision} holds magnitudes up to {largest}); nothing was written",
        model=config.model, step=step, agent=agent, quantity=quantity, checkpoint=None)


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, Mapping):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), item, out)
    else:
        out[prefix] = value


#: what a resumed run may change of its checkpoint's config besides the logging (log.*): the steps (more of them)
#: and the threads
RESUMABLE = ("steps", "engine.threads")


def _refuse_resumed_changes(overrides: Mapping[str, Any]) -> None:
    """A resumed run continues its checkpoint's run bit for bit: any other change (a parameter, the seed, the
    precision) is a ConfigError naming it."""
    flat: dict[str, Any] = {}
    _flatten("", overrides, flat)
    for key in flat:
        if not (key in RESUMABLE or key.startswith("log.")):
            raise ConfigError(f"{key}: a resumed run continues its checkpoint's config; only steps, engine.threads "
                              "and log.* may change")


def drawn_subset(n: int, max_agents: int, seed: int) -> np.ndarray:
    """Sorted ids of the agents drawn every frame: all of them, or the `max_agents` with the smallest hash."""
    if n <= max_agents:
        return np.arange(n)
    keys = hash_np(seed, 0, np.arange(n), Stream.SUBSET)
    return np.sort(np.argpartition(keys, max_agents)[:max_agents])


def field_pixels(n: int, drawn: int, setting: int) -> int:
    """Pixels a side of the field of all agents in each frame (log.field): none when every agent is drawn, else
    the setting, or for -1 :func:`tflock.field.field_size` of n."""
    if drawn >= n or setting == 0:
        return 0
    if setting < 0:
        from tflock.field import field_size

        return field_size(n)
    return setting


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
        # the scalars as Python values: the config as TOML text, the id, the step
        out.update(config_toml=str(out["config_toml"]), recording_id=str(out["recording_id"]), step=int(out["step"]))
        tomllib.loads(out["config_toml"])
        return out
    except (OSError, EOFError, TypeError, ValueError, KeyError, zipfile.BadZipFile, tomllib.TOMLDecodeError):
        raise ConfigError(f"--resume: {path} is not a tflock checkpoint of format {CHECKPOINT_FORMAT} that can be read "
                          f"(another kind of file, or one cut short or damaged)") from None


def _checkpoint_file(path: str | Path) -> Path:
    """`path` as a checkpoint's path: an .npz, else ConfigError."""
    if not isinstance(path, str | Path) or Path(path).suffix != ".npz":
        raise ConfigError(f"checkpoint: must be a .npz file, got {str(path)!r}")
    return Path(path)


def _check_output_arguments(record: bool | str | Path | None, checkpoint: str | Path | None,
                            checkpoint_every: int) -> None:
    """Refuse, as the CLI refuses its options, a recording that is neither a bool, None nor an .rrd path, a
    checkpoint path that is not an .npz and a checkpoint interval that is not an integer >= 0 (a negative one never
    stopped a run)."""
    if not (record is None or isinstance(record, bool) or isinstance(record, str | Path) and
            Path(record).suffix == ".rrd"):
        raise ConfigError(f"record: must be True, False or a .rrd file, got {str(record)!r}")
    if checkpoint is not None:
        _checkpoint_file(checkpoint)
    if isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int | np.integer) or checkpoint_every < 0:
        raise ConfigError(f"checkpoint_every: must be an integer >= 0 (0 = never), got {checkpoint_every!r}")


def default_recording_path(model: str) -> Path:
    return Path("recordings") / f"{model}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


class Simulation:
    """One run of a model: build it from a config, step it, read its state and metrics, optionally record it.

    ``config`` is a TOML path, a nested dict, a :class:`Config`, or None for the defaults of ``model`` (a name
    from ``tflock models``; vicsek when neither is given). Keyword
    overrides are nested like the TOML (``params={"noise": 0.3}``, ``steps=100``) or dotted strings in
    ``overrides`` (``["params.noise=0.3"]``, the CLI's ``--set``). ``record`` is False, True (a file under
    ``recordings/``) or an ``.rrd`` path; ``spawn`` / ``connect`` stream to a viewer. ``checkpoint`` /
    ``checkpoint_every``: write :meth:`save_checkpoint` there every k steps (``checkpoint`` also receives the last
    good state after a :class:`NumericalFaultError`); ``resume``: continue from such a file (bit-identical to the
    uninterrupted run; a recording goes to a new file with the same recording id); ``checkpoint_every`` without
    ``checkpoint`` writes ``<recording>.checkpoint.npz``. The run owns its outputs until :meth:`close`
    (:mod:`tflock.outputs`): an output path another run holds, or that holds an earlier run's file (unless
    ``overwrite``), is refused. A config that needs more memory than the machine has is a :class:`ConfigError`,
    and an output path that cannot be written or is in use an OSError, all raised before anything is allocated
    or written.
    """

    def __init__(self, config: str | Path | Mapping[str, Any] | Config | None = None, *,
                 model: str | None = None, overrides: list[str] | Mapping[str, Any] | None = None,
                 record: bool | str | Path | None = False, spawn: bool = False, connect: str | None = None,
                 resume: str | Path | None = None, checkpoint: str | Path | None = None,
                 checkpoint_every: int = 0, overwrite: bool = False, **fields: Any) -> None:
        _check_output_arguments(record, checkpoint, checkpoint_every)
        record = bool(record) if record is None or isinstance(record, bool) else record
        self._resumed_from = None if resume is None else Path(resume)  # save_checkpoint may write it again
        saved = None
        if resume is not None:  # the checkpoint carries the config
            saved = read_checkpoint(resume)
            if config is not None or model is not None:
                raise ConfigError("--resume: the checkpoint carries its config; do not also give a config or model")
            config = tomllib.loads(saved["config_toml"])
        if isinstance(config, Config) and (overrides or fields or model):
            config = config_to_dict(config)
        merged: dict[str, Any] = {}  # the keys given with the config, overrides and fields
        if not isinstance(config, Config):
            if isinstance(overrides, Mapping):
                merged.update(overrides)
            elif overrides is not None:
                merged.update(parse_override(expr) for expr in overrides)
            _flatten("", fields, merged)
            if resume is not None:
                _refuse_resumed_changes(merged)
            config = load_config(config, model=model, overrides=merged)
        self.config: Config = config
        record_path = None if not record else Path(record) if not isinstance(record, bool) else (
            Path(config.log.out) if config.log.out else None)
        # a resumed run recording to its checkpoint's path (none given anew) writes the next segment beside it
        next_segment = resume is not None and record is True and record_path is not None and "log.out" not in merged
        check_memory(config)
        if connect:
            check_viewer(connect)
        self._outputs = Outputs()
        weakref.finalize(self, self._outputs.release)  # a Simulation never closed lets go of its outputs at exit
        self.recorder = None
        try:
            record_path, checkpoint = self._claim_outputs(
                record_path, bool(record) and record_path is None, None if checkpoint is None else Path(checkpoint),
                checkpoint_every, None if resume is None else Path(resume), overwrite, next_segment)
            self._start(saved, record_path, spawn, connect, checkpoint, checkpoint_every)
        except BaseException:
            self.close()
            raise
        warn_mistakes(config, checkpoint_every=checkpoint_every if checkpoint else 0, start_step=self.step_index,
                      recording=record_path, drawn=len(self._selected), field=self._field_size)

    def _claim_outputs(self, record_path: Path | None, default_name: bool, checkpoint: Path | None,
                       checkpoint_every: int, resume: Path | None, overwrite: bool,
                       next_segment: bool = False) -> tuple[Path | None, Path | None]:
        """Check, lock and return the run's recording and checkpoint paths (:mod:`tflock.outputs`): a recording
        named by tflock (`default_name`) takes the first free ``recordings/<model>-<time>[-k].rrd``, a resumed run's
        `next_segment` the first free ``<name>-k.rrd`` after its checkpoint's recording ``<name>.rrd`` (which it
        never replaces); a checkpoint every k steps without a path goes beside the recording (``.checkpoint.npz``)."""
        if checkpoint is not None:
            claim(checkpoint, "checkpoint", overwrite=overwrite, allowed=resume, into=self._outputs)

        def attempt(recording: Path | None, base: Path | None, replace: bool = overwrite
                    ) -> tuple[Path | None, Path | None]:
            taken = Outputs()
            try:
                beside = None
                if checkpoint is None and checkpoint_every and base is not None:
                    beside = base.with_suffix(".checkpoint.npz")
                    claim(beside, "checkpoint", overwrite=replace, allowed=resume, into=taken)
                if recording is not None:
                    claim(recording, "recording", [(recording.with_suffix(".metrics.csv"), "metrics table")],
                          overwrite=replace, into=taken)
            except BaseException:
                taken.release()
                raise
            self._outputs.locks += taken.locks
            self._outputs.replaced += taken.replaced
            return recording, checkpoint or beside

        if default_name or (record_path is None and checkpoint is None and checkpoint_every):
            return first_free(default_recording_path(self.config.model),
                              lambda base: attempt(base if default_name else None, base))
        if next_segment:
            return first_free(record_path, lambda base: attempt(base, base, replace=False))
        return attempt(record_path, record_path)

    def _start(self, saved: Mapping[str, Any] | None, record_path: Path | None, spawn: bool, connect: str | None,
               checkpoint: Path | None, checkpoint_every: int) -> None:
        """Build the model and the recorder, at the start or from a checkpoint (`saved`)."""
        config = self.config
        self.engine: EngineInfo = init_engine(config.engine.arch, config.engine.threads, config.engine.precision)
        with np.errstate(over="ignore", invalid="ignore"):  # values beyond the float range: the guard refuses them
            self.model = model_class(config.model)(config.params, config.seed, self.engine)
        self._table = MetricRows(["step", "time", *self.model.metric_descriptions])
        self._selected = drawn_subset(config.params.n, config.log.max_agents, config.seed)
        self._field_size = field_pixels(config.params.n, len(self._selected), config.log.field)
        self.files: list[Path] = []
        self.checkpoint_steps: dict[Path, int] = {}  # the step of each checkpoint this run wrote, last write
        self.recording_id = uuid.uuid4().hex
        self.checkpoint_path = checkpoint
        self.checkpoint_every = checkpoint_every
        if saved is not None:
            with np.errstate(over="ignore", invalid="ignore"):
                self._restore(saved)
        self._refuse_non_finite_start()
        self._outputs.remove_replaced()  # (--overwrite) the run starts here
        if record_path is not None or spawn or connect:
            self._open_recorder(record_path, spawn, connect)
        if saved is None:
            self._observe(force=True)
        self._checked = self.model.step_index  # the last step whose state passed the guard (or the start)
        self._lyapunov_start = self._start_lyapunov(saved)
        self._keep_good()

    @property
    def step_index(self) -> int:
        """The step the state is at (0: the start)."""
        return self.model.step_index

    def _open_recorder(self, path: Path | None, spawn: bool, connect: str | None) -> None:
        from tflock.record import Recorder

        table = path.with_suffix(".metrics.csv") if path is not None else None
        n, log = self.config.params.n, self.config.log
        drawn = f"{len(self._selected)} of {n} agents drawn (the same seeded subset every frame)"
        with np.errstate(over="ignore"):  # a box beyond the float32 range of the drawing: its outline is at inf
            self.recorder = Recorder(model=self.config.model, config_toml=config_to_toml(self.config),
                                     world=self.model.world(), metrics=self.model.metric_descriptions,
                                     profiles=self.model.profile_descriptions, angles=self.model.angle_metrics,
                                     edges=self.model.edges_description, first_plots=self.model.first_plots,
                                     path=path, spawn=spawn, connect=connect, metrics_table=table,
                                     recording_id=self.recording_id, legend=self.model.color_legend,
                                     field=self._field_size > 0, trail=log.trail, drawn=drawn)
        self.files = [p for p in (path, table) if p is not None]

    def _metrics_due(self, t: int) -> bool:
        return t % self.config.log.metrics_every == 0

    def _frame_due(self, t: int) -> bool:
        return self.recorder is not None and t % self.config.log.every == 0

    def _observe(self, force: bool = False) -> None:
        """Metrics and frame of the current step, at their cadences (or now, when forced)."""
        with np.errstate(over="ignore"):  # a state that passed the guard: a square or a float32 drawing past the
            self._observe_now(force)      # float range is inf, as it should be, without a NumPy warning

    def _observe_now(self, force: bool) -> None:
        t = self.model.step_index
        if force or self._metrics_due(t):
            values = self.model.metrics()
            self._table.append({"step": float(t), "time": t * self.model.dt, **values})
            if self.recorder is not None:
                self.recorder.log_metrics(t, values)
        if self.recorder is not None and (force or self._frame_due(t)):
            self.recorder.log_frame(t, self.model.frame(self._selected, self.config.log.max_edges, self._field_size))

    def step(self, steps: int = 1, progress: Callable[[int], None] | None = None) -> None:
        """Advance `steps` steps, taking metrics and frames at their cadences; `progress(step)` after each run of
        steps between two observed steps (at most :data:`CHUNK_STEPS` steps). Raises :class:`NumericalFaultError`
        when the state becomes non-finite.

        The steps between two observed steps (a metrics row, a frame, a checkpoint, the last step) go to the model
        as one ``advance(k)``, which a model may run in fewer launches than k single steps (the trajectory is the
        same bit for bit); the guard checks the state at the observed steps, as it always has."""
        end = self.model.step_index + steps
        while self.model.step_index < end:
            t = self._next_stop(self.model.step_index, end)
            if self._frame_due(t):  # announced before the step that makes the drawn state: it may write the rows
                if not self.model.draws_ahead:
                    self.model.advance(t - 1 - self.model.step_index)
                self.model.draw_next(self._selected, t)
            self.model.advance(t - self.model.step_index)
            last = t == self.config.steps
            checkpoint = bool(self.checkpoint_every and self.checkpoint_path and t % self.checkpoint_every == 0)
            full = last or checkpoint or self._metrics_due(t)  # where the stability guard's Lyapunov test runs
            if full or self._frame_due(t):
                self._guard(full)
            self._observe(force=last)
            if checkpoint:
                self.save_checkpoint(self.checkpoint_path)
            if progress is not None:
                progress(t)

    def _next_stop(self, t0: int, end: int) -> int:
        """The first step after `t0`, at most `end`, at which something is observed (metrics, a frame, a checkpoint,
        the run's last step), or after :data:`CHUNK_STEPS` steps (:data:`CHUNK_AGENT_STEPS` agent-steps), so that a
        stop request is seen soon."""
        log = self.config.log
        n = self.config.params.n
        stops = [end, t0 + max(1, min(CHUNK_STEPS, CHUNK_AGENT_STEPS // max(1, n))),
                 (t0 // log.metrics_every + 1) * log.metrics_every]
        if t0 < self.config.steps:
            stops.append(self.config.steps)
        if self.recorder is not None:
            stops.append((t0 // log.every + 1) * log.every)
        if self.checkpoint_every and self.checkpoint_path:
            stops.append((t0 // self.checkpoint_every + 1) * self.checkpoint_every)
        return min(stops)

    # ------------------------------------------------------------------ the non-finite guard
    def _refuse_non_finite_start(self) -> None:
        """A start state that is already non-finite (numbers beyond the float range) stops before anything is
        written."""
        found = self.model.first_non_finite()
        if found is not None:
            raise non_finite_start(self.config, self.model.step_index, *found)

    def _start_lyapunov(self, saved: Mapping[str, Any] | None) -> Lyapunov | None:
        """The Lyapunov function at step 0, the stability guard's reference: now, or as a checkpoint kept it."""
        if saved is not None and "lyapunov_start" in saved:
            name, kinetic, potential = (str(v) for v in saved["lyapunov_start"])
            return Lyapunov(name, float(kinetic), float(potential))
        return self.model.lyapunov()

    def _keep_good(self) -> None:
        """Keep a host copy of the current (good) state to replay from after a fault."""
        t0 = time.perf_counter()
        self._good = (self.model.checkpoint(), self.model.step_index)
        self._good_at = time.perf_counter()
        self._good_cost = self._good_at - t0

    def _guard(self, full: bool = True) -> None:
        """Check the state before anything of this step is kept: stop at a non-finite value or an unstable
        integration (its Lyapunov test where `full`), else now and then keep a copy of this good state."""
        problem = self._problem(full)
        if problem is not None:
            self._fault(problem)
        self._checked = self.model.step_index
        if time.perf_counter() - self._good_at >= GOOD_COPY_RATIO * self._good_cost:
            self._keep_good()

    def _problem(self, full: bool = True) -> tuple[int | None, str, str] | None:
        """What is wrong with the current state, ``(agent, quantity, what)``, or None: a non-finite position,
        heading or velocity (the smallest bad agent), else an integration that left its stable range
        (:mod:`tflock.stability`: the displacement test, and where `full` the Lyapunov test; agent None)."""
        found = self.model.first_non_finite()
        if found is not None:
            agent, quantity = found
            return agent, quantity, f"agent {agent} has a non-finite {quantity}"
        unstable = cheap_test(self.model) or (lyapunov_test(self._lyapunov_start, self.model) if full else None)
        if unstable is None:
            return None
        dt = getattr(self.config.params, "dt", None)
        return None, "integration", unstable + ("" if dt is None else f"; lower params.dt (= {dt:g})")

    def _fault(self, seen: tuple[int | None, str, str]) -> None:
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
            found = self._problem(full=True)
        agent, quantity, what = found or seen  # steps are deterministic: the replay finds it again, at or before
        bad = self.model.step_index
        self.model.restore(good, bad - 1)
        path = self.checkpoint_path or (
            self.recorder.path if self.recorder is not None and self.recorder.path is not None
            else default_recording_path(self.config.model)).with_suffix(".lastgood.npz")
        try:
            if self.checkpoint_path is None and (self.recorder is None or self.recorder.path is None):
                path = first_free(path, self._claim_lastgood)  # a name no other run writes or wrote
            saved: Path | None = self.save_checkpoint(path, overwrite=True)  # this run's or its recording's name
            where = f"the last good state (step {bad - 1}) is saved in {path}"
        except OSError as e:
            saved, where = None, f"the last good state (step {bad - 1}) could not be saved to {path}: {e.strerror or e}"
        self.close()
        message = (f"numerical fault in {self.config.model} at step {bad}: {what}; "
                   f"the run stopped (nothing after step {self._checked} is recorded) and {where}")
        raise NumericalFaultError(message, model=self.config.model, step=bad, agent=agent, quantity=quantity,
                                  checkpoint=saved)

    def _claim_lastgood(self, path: Path) -> Path:
        """Lock `path` for this run's last good state, refusing an earlier file there (:func:`tflock.outputs.claim`)."""
        claim(path, "checkpoint", into=self._outputs)
        return path

    def run(self, progress: Callable[[int], None] | None = None) -> None:
        """Step up to the configured number of steps (nothing once there: :meth:`step` goes on past them);
        ``progress(step)`` as in :meth:`step`."""
        self.step(max(0, self.config.steps - self.model.step_index), progress)

    def sync(self) -> None:
        """Wait for queued kernels (for timing on asynchronous backends)."""
        import taichi as ti

        ti.sync()

    def state(self) -> dict[str, Any]:
        """NumPy snapshot: the model's arrays (e.g. ``x``, ``theta``) and ``step``."""
        return {**self.model.state(), "step": self.model.step_index}

    def metrics(self) -> dict[str, np.ndarray]:
        """The metrics table so far, as columns (``step``, ``time`` and one per metric): ``pd.DataFrame(...)``.

        The run keeps its table in bounded memory (one block of rows; the rest in a temporary file, see
        :mod:`tflock.metric_rows`): this reads it back, so its arrays take memory only once asked for. ``step`` is
        an integer column, the others float64."""
        columns = self._table.columns()
        columns["step"] = columns["step"].astype(np.int64)  # (kept as float64 with the rest of a row)
        return columns

    def last_metrics(self) -> dict[str, float] | None:
        """The last row of the metrics table (``step`` an int, ``time`` and one float per metric), or None before
        any."""
        row = self._table.last()
        if row is not None:
            row["step"] = int(row["step"])
        return row

    def checkpoint_now(self, announce: Callable[[Path, int], None] | None = None) -> Path | None:
        """Where the run writes checkpoints (``checkpoint_every``): the current state, guarded, saved to its
        checkpoint file unless this run already wrote this step there; `announce(path, step)` is called before
        the save. The CLI calls it when a run is stopped between two steps (Ctrl-C, SIGTERM), so a resume
        continues from where it stopped, not from the last periodic checkpoint. None without checkpoints. A fault
        found by the guard raises :class:`NumericalFaultError` as a step would."""
        path = self.checkpoint_path
        if not (self.checkpoint_every and path):
            return None
        if self.checkpoint_steps.get(path) != self.model.step_index:
            self._guard(True)
            if announce is not None:
                announce(path, self.model.step_index)
            self.save_checkpoint(path)
        return path

    def save_checkpoint(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the full state (the model's arrays, step, config, metrics so far, recording id) to an .npz,
        atomically (a temporary file renamed over `path`). :class:`Simulation` ``(resume=path)`` continues it.
        A path that is not an .npz is a ConfigError; an .npz there that this run neither wrote, locked nor resumed
        from (an earlier run's checkpoint) is refused with :class:`tflock.outputs.OutputExistsError` unless
        `overwrite`, and a path another open run holds with OutputBusyError (:func:`tflock.outputs.claim`, which also
        locks it for this run)."""
        path = _checkpoint_file(path)
        held = {p.resolve() for p in (*self.files, *(lock.path for lock in self._outputs.locks))}
        if path.resolve() not in held:
            taken = Outputs()
            claim(path, "checkpoint", overwrite=overwrite, allowed=self._resumed_from, into=taken)
            self._outputs.locks += taken.locks  # (a file it replaces is replaced by the write below)
        path.parent.mkdir(parents=True, exist_ok=True)
        table = self._table.columns(copy=False)  # views of the table file: written in chunks, not held in memory
        arrays = {f"model__{k}": v for k, v in self.model.checkpoint().items()}
        arrays.update({f"metrics__{k}": v for k, v in table.items()})
        if self._lyapunov_start is not None:
            arrays["lyapunov_start"] = np.array([str(v) for v in self._lyapunov_start])
        tmp = path.with_name(path.name + ".tmp")
        try:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays, step=np.int64(self.model.step_index),
                         config_toml=np.str_(config_to_toml(self.config)), recording_id=np.str_(self.recording_id),
                         format=np.int64(CHECKPOINT_FORMAT))
            os.replace(tmp, path)
        except BaseException:  # a full disk, a second Ctrl-C: the previous checkpoint stays, and no stray .tmp
            tmp.unlink(missing_ok=True)
            raise
        if path.resolve() not in {p.resolve() for p in self.files}:
            self.files.append(path)
        self.checkpoint_steps[path] = self.model.step_index
        return path

    def _restore(self, checkpoint: Mapping[str, Any]) -> None:
        arrays = {k.removeprefix("model__"): v for k, v in checkpoint.items() if k.startswith("model__")}
        try:
            self.model.restore(arrays, int(checkpoint["step"]))
        except ValueError as e:
            raise ConfigError(f"--resume: {e}") from None
        columns = {k.removeprefix("metrics__"): v for k, v in checkpoint.items() if k.startswith("metrics__")}
        self._table.extend(columns)
        self.recording_id = str(checkpoint["recording_id"])

    def close(self) -> None:
        """Finish the recording and let go of the run's outputs (idempotent)."""
        try:
            if self.recorder is not None:
                self.recorder.close()
        finally:
            self._outputs.release()

    def __enter__(self) -> Simulation:
        """``with Simulation(...) as sim:`` closes the run (its recording, its outputs' locks) at the block's end."""
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

