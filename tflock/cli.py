"""The `tflock` command line: a thin layer over :class:`tflock.Simulation` and :mod:`tflock.record`.

Every user error (bad config, missing file, unwritable output, unavailable arch, a value click cannot parse) is one
line on stderr and exit code 2, and so is a numerical fault (a non-finite state: the recording ends at the last
good frame and the last good state is saved); Ctrl-C or SIGTERM stops a run cleanly and leaves a complete
recording up to the last logged frame.
"""

from __future__ import annotations

import functools
import gc
import json
import signal
import sys
import time
import warnings
from collections.abc import Callable
from importlib import import_module
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from typer.core import TyperGroup

from tflock.config import MODEL_DESCRIPTIONS, ConfigError, default_config_toml, load_config, tomllib

#: click's exceptions, as the installed typer raises them (recent typers carry their own copy of click)
_click_errors = import_module(typer.BadParameter.__module__)


class _OneLineUsageErrors(TyperGroup):
    """Click's usage errors (an unknown option or command, a value of the wrong type, a missing argument) as one
    line and exit code 2, like every other error, instead of a usage text and an error box."""

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            with warnings.catch_warnings():
                warnings.showwarning = _warning_line
                code = super().main(*args, standalone_mode=False, **kwargs)
        except getattr(_click_errors, "NoArgsIsHelpError", ()) as e:  # the help text is printed already
            sys.exit(e.exit_code)
        except _click_errors.ClickException as e:
            ctx = getattr(e, "ctx", None)
            hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
            _error_line(e.format_message() + hint)
            sys.exit(e.exit_code)
        except typer.Abort:
            _error_line("aborted")
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


def _flag_type(display: Callable[[Any, Any], str | None]) -> Callable[[Any, Any], str | None]:
    """Typer's help column of an option's type, empty for a flag (from typer 0.2x it prints ``<bool>`` beside
    ``--quick`` or ``--help``, which take no value)."""

    @functools.wraps(display)
    def flag_type(option: Any, ctx: Any) -> str | None:
        if getattr(option, "is_flag", False) and not getattr(option, "count", False):
            return None
        return display(option, ctx)

    return flag_type


if hasattr(typer.core, "TyperOption") and hasattr(typer.core.TyperOption, "display_type_rich"):
    typer.core.TyperOption.display_type_rich = _flag_type(typer.core.TyperOption.display_type_rich)

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, cls=_OneLineUsageErrors,
                  help="Large-N flocking simulation on Taichi, recorded to Rerun.")
config_app = typer.Typer(no_args_is_help=True, help="Inspect model configs.")
app.add_typer(config_app, name="config")
out = Console()
err = Console(stderr=True)


def _error_line(message: str) -> None:
    """``error: <message>`` on one line, whatever the message holds (newlines, markup brackets, emoji codes)."""
    err.print(f"[bold red]error:[/] {escape(' '.join(message.split()))}", highlight=False, soft_wrap=True, emoji=False)


def _warning_line(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
                  line: str | None = None) -> None:
    """A Python warning as one ``warning: ...`` line on stderr: tflock's own (:class:`tflock.advice.TflockWarning`)
    as their message, any other with its category and source."""
    from tflock.advice import TflockWarning

    text = str(message) if issubclass(category, TflockWarning) else (
        f"{category.__name__}: {message} ({Path(filename).name}:{lineno})")
    err.print(f"[yellow]warning:[/] {escape(' '.join(text.split()))}", highlight=False, soft_wrap=True, emoji=False)


def fail(message: str) -> NoReturn:
    """One-line error, exit code 2."""
    _error_line(message)
    raise typer.Exit(2)


@app.command()
def sim(
    model: Annotated[str | None, typer.Option("--model", "-m", help="Model to run with its default config.")] = None,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="TOML config file.")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", "-s", help="Override a key: params.noise=0.3.")] = None,
    steps: Annotated[int | None, typer.Option(help="Number of steps.")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed.")] = None,
    arch: Annotated[str | None, typer.Option(help="cpu | cuda | vulkan | auto.")] = None,
    threads: Annotated[int | None, typer.Option(help="CPU threads (0 = all cores).")] = None,
    out_path: Annotated[Path | None, typer.Option("--out", "-o", help="Recording file (.rrd).")] = None,
    spawn: Annotated[bool, typer.Option("--spawn", help="Stream to a new native viewer.")] = False,
    connect: Annotated[str | None, typer.Option(help="Stream to a viewer: rerun+http://host:9876/proxy.")] = None,
    no_log: Annotated[bool, typer.Option(
        "--no-log", help="Record nothing: no .rrd, no .metrics.csv (final metrics printed).")] = False,
    checkpoint_every: Annotated[int, typer.Option(help="Write a checkpoint every K steps (0 = never).")] = 0,
    checkpoint: Annotated[Path | None, typer.Option(help="Checkpoint file (default: beside the recording).")] = None,
    resume: Annotated[Path | None, typer.Option(help="Continue a run from its checkpoint (.npz).")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an earlier run's files at the output "
                                            "paths (refused without it).")] = False,
) -> None:
    """Run a simulation: `tflock sim` runs the default Vicsek config and records it under recordings/."""
    t_start = time.perf_counter()
    if out_path is not None and out_path.suffix != ".rrd":
        fail(f"--out: must be a .rrd file, got {str(out_path)!r}")
    if checkpoint is not None and checkpoint.suffix != ".npz":
        fail(f"--checkpoint: must be a .npz file, got {str(checkpoint)!r}")
    if out_path is not None and no_log:
        fail("--out and --no-log: a run without a recording writes no .rrd; give one of them")
    overrides = list(set_ or [])
    for key, value in (("steps", steps), ("seed", seed), ("engine.arch", arch), ("engine.threads", threads)):
        if value is not None:
            overrides.append(f"{key}={value!r}" if isinstance(value, str) else f"{key}={value}")
    if out_path is not None:  # log.out, so that the config saved in the recording and checkpoints says where it went
        overrides.append(f"log.out={json.dumps(str(out_path))}")
    if checkpoint_every < 0:
        fail(f"--checkpoint-every: must be >= 0, got {checkpoint_every}")
    if resume is not None:
        given = [name for name, value in (("--config", config), ("--model", model), ("--seed", seed))
                 if value is not None]
        if given:
            fail(f"--resume with {given[0]}: the checkpoint carries the config; only --steps, --threads and --set "
                 f"log.* may change")
        changed = [o.split("=", 1)[0] for o in overrides if not o.startswith(("log.", "steps=", "engine.threads="))]
        if changed:
            fail(f"--resume: {changed[0]} may not change: a resumed run continues its checkpoint's config; only "
                 f"--steps, --threads and --set log.* may change")
    try:
        if resume is not None:
            from tflock.simulation import read_checkpoint

            header = read_checkpoint(resume, arrays=False)
            cfg = load_config(tomllib.loads(header["config_toml"]), overrides=overrides)
            at = header["step"]
            if cfg.steps <= at:
                fail(f"--steps: the checkpoint is at step {at} and the run would end at step {cfg.steps}: nothing "
                     f"to run; give --steps > {at} (the total, counted from step 0)")
        else:
            cfg = load_config(config, model=model, overrides=overrides)
    except ConfigError as e:
        fail(str(e))
    record = not no_log and (out_path is not None or not (spawn or connect))  # to log.out, else a default name

    stop = _StopRequest()
    signal.signal(signal.SIGTERM, stop.handler)  # SLURM, timeout, docker stop: finish the file
    signal.signal(signal.SIGINT, stop.handler)  # also when started in the background
    from tflock.engine import EngineError
    from tflock.simulation import NumericalFaultError, Simulation

    try:
        simulation = Simulation(cfg if resume is None else None, overrides=None if resume is None else overrides,
                                resume=resume, record=record, spawn=spawn, connect=connect, checkpoint=checkpoint,
                                checkpoint_every=checkpoint_every, overwrite=overwrite)
    except OSError as e:
        fail(e.strerror or str(e))
    except (ConfigError, EngineError, RuntimeError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        err.print("interrupted during start-up", highlight=False)
        raise typer.Exit(130) from None
    if stop.requested:
        simulation.close()
        err.print("interrupted during start-up", highlight=False)
        raise typer.Exit(130)
    t_ready = time.perf_counter()
    # one run per process: what start-up made (modules, Taichi's and Rerun's objects) lives as long as the run, so
    # the garbage collector's full passes, which the run's allocations trigger now and then, need not scan it again
    gc.freeze()
    interrupted = False
    first_step_s = 0.0
    t_loop = t_ready
    try:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), console=err,
                      disable=not err.is_terminal, transient=False) as progress:
            task = progress.add_task(f"{cfg.model} n={cfg.params.n}", total=cfg.steps, rate="",
                                     completed=simulation.step_index)
            t_last = time.perf_counter()

            def tick(step: int) -> None:
                nonlocal t_last
                now = time.perf_counter()
                if now - t_last > 0.25 or step == cfg.steps:
                    rate = (step - 1) / (now - t_loop) if step > 1 and now > t_loop else 0.0
                    progress.update(task, completed=step, rate=f"{rate:,.0f} steps/s")
                    t_last = now
                if stop.requested:  # between steps: the state, metrics and recording are consistent
                    raise _StopSignalError

            if cfg.steps > simulation.step_index:
                t0 = time.perf_counter()
                simulation.step(1, tick)  # the first step compiles the step kernels
                first_step_s = time.perf_counter() - t0
                t_loop = time.perf_counter()
                simulation.run(tick)
    except (_StopSignalError, KeyboardInterrupt) as stop_error:
        interrupted = True
        if isinstance(stop_error, _StopSignalError):  # between two steps: the state is whole
            _save_at_stop(simulation)
    except NumericalFaultError as e:  # the recording is closed and the last good state saved
        fail(str(e))
    except OSError as e:  # a checkpoint or the metrics table that cannot be written (a full disk, ...)
        fail(_cannot_write(e))
    finally:
        simulation.close()
        gc.unfreeze()  # frozen objects are never finalized: Taichi would not write its kernel cache at exit
    t_end = time.perf_counter()
    streamed = connect or ("a new viewer" if spawn else None)
    _summary(simulation, t_start, t_ready, first_step_s, t_loop, t_end, interrupted, streamed)
    if interrupted:
        raise typer.Exit(130)


def _save_at_stop(simulation) -> None:
    """A run stopped between two steps: its state saved to its checkpoint file (with checkpoints on), said first,
    as the save may take seconds; a second Ctrl-C skips it (the previous checkpoint stays)."""
    from tflock.simulation import NumericalFaultError

    def announce(path: Path, step: int) -> None:
        err.print(f"saving step {step} to {path} (Ctrl-C again to skip)", highlight=False, soft_wrap=True)

    try:
        simulation.checkpoint_now(announce)
    except KeyboardInterrupt:
        err.print("checkpoint skipped: the previous one stays", highlight=False, soft_wrap=True)
    except NumericalFaultError as e:
        fail(str(e))
    except OSError as e:
        fail(_cannot_write(e))


def _cannot_write(error: OSError) -> str:
    """A run's output that could not be written, as one line."""
    return f"cannot write {error.filename or 'an output'}: {error.strerror or error}"


class _StopSignalError(Exception):
    """Raised between two steps after SIGINT / SIGTERM."""


class _StopRequest:
    """The first SIGINT / SIGTERM asks the run to stop after the current step (so a kernel, a frame or a file write
    is never cut in half); a second one interrupts at once."""

    def __init__(self) -> None:
        self.requested = False

    def handler(self, signum: int, frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


def _summary(simulation, t_start: float, t_ready: float, first_step_s: float, t_loop: float, t_end: float,
             interrupted: bool, streamed: str | None) -> None:
    """The table a run ends with; `streamed`: the viewer the run was streamed to (--connect's URL, or --spawn's)."""
    cfg = simulation.config
    done = simulation.step_index
    loop_steps = max(0, done - 1)
    loop_s = t_end - t_loop
    rate = loop_steps / loop_s if loop_steps and loop_s > 0 else 0.0
    table = Table(title=f"{cfg.model}: {done} of {cfg.steps} steps" + (" (interrupted)" if interrupted else ""),
                  show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("agents", f"{cfg.params.n:,}")
    table.add_row("engine", simulation.engine.describe())
    last = simulation.last_metrics() or {}
    for name in simulation.model.metric_descriptions:
        if name in last:
            table.add_row(name, f"{last[name]:.6g}")
    if loop_steps:
        table.add_row("steps/s", f"{rate:,.1f} (after the first step)")
        table.add_row("agent-steps/s", f"{rate * cfg.params.n:,.3g}")
    else:
        table.add_row("steps/s", "- (no step after the first)")
    table.add_row("start-up", f"{t_ready - t_start:.2f} s (Taichi init, first metrics; compile included)")
    table.add_row("first step", f"{first_step_s:.2f} s (compile included)")
    table.add_row("wall time", f"{t_end - t_start:.2f} s")
    rrd = [p for p in simulation.files if p.suffix == ".rrd"]
    if streamed:
        table.add_row("streamed to", streamed + ("" if rrd else " (no file: --out records the run too)"))
    for path in simulation.files:
        step = simulation.checkpoint_steps.get(path)
        table.add_row("wrote", str(path) + (f" (step {step})" if step is not None else ""))
    out.print(table)
    if rrd:
        out.print(f"view it: [bold]tflock view {rrd[0]}[/] (or `rerun {rrd[0]}`)", highlight=False, soft_wrap=True)


@app.command()
def models() -> None:
    """List the models."""
    width = max(map(len, MODEL_DESCRIPTIONS))
    for name, description in MODEL_DESCRIPTIONS.items():
        out.print(f"[bold]{name:<{width}}[/]  {description}", highlight=False, soft_wrap=True)


@config_app.command("show")
def config_show(model: Annotated[str, typer.Argument(help="Model name (see `tflock models`).")] = "vicsek") -> None:
    """Print the complete default config of a model, with a comment per key."""
    if model not in MODEL_DESCRIPTIONS:
        fail(f"model: must be one of {', '.join(MODEL_DESCRIPTIONS)}, got {model!r}")
    sys.stdout.write(default_config_toml(model))


@app.command()
def view(
    path: Annotated[Path | None, typer.Argument(help="Recording (.rrd); none with --live.", metavar="PATH",
                                                show_default=False)] = None,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer on localhost (no display needed).")] = False,
    live: Annotated[bool, typer.Option(
        "--live", help="No recording: a viewer that shows runs as they go (tflock sim --connect, the URL printed).")
    ] = False,
    port: Annotated[int | None, typer.Option(help="Web viewer port (default: a free one).")] = None,
    grpc_port: Annotated[int | None, typer.Option(
        help="Data port of --web, the port runs stream to with --live (default: a free one).")] = None,
    screenshot: Annotated[Path | None, typer.Option(
        help="Save a PNG of the web viewer showing the recording (headless Chromium; needs playwright).")] = None,
) -> None:
    """Open a recording in the Rerun viewer, or save a screenshot of it; --live: a viewer for runs as they go."""
    from tflock.record import open_viewer

    if live:
        if path is not None:
            fail(f"--live and {path}: --live opens a viewer for runs streamed to it, not a recording; give one of them")
        if screenshot is not None:
            fail("--screenshot needs a recording (.rrd), not --live")
    elif path is None:
        fail("Missing argument 'PATH': the recording (.rrd) to open, or --live for a viewer that runs stream to; "
             "see tflock view --help")
    else:
        _refuse_missing_recording(path)
    try:
        if screenshot is not None and path is not None:
            from tflock.screenshot import take_screenshots

            take_screenshots(path, [screenshot])
            out.print(str(screenshot), soft_wrap=True, highlight=False, markup=False)
            return
        open_viewer(path, web=web, port=port, grpc_port=grpc_port)
    except (RuntimeError, OSError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        pass


def plural(count: int, noun: str) -> str:
    """'1 frame', '2 frames'."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _refuse_missing_recording(path: Path) -> None:
    """A recording argument that names no file: missing, or a folder."""
    if path.is_dir():
        fail(f"{path} is a folder, not a recording (.rrd)")
    if not path.is_file():
        fail(f"recording not found: {path}")


@app.command()
def inspect(path: Annotated[Path, typer.Argument(help="Recording (.rrd).")]) -> None:
    """Print a recording's model, config, frame count and final metrics, read back from the file."""
    from tflock.record import read_recording

    _refuse_missing_recording(path)
    try:
        summary = read_recording(path)
    except ValueError as e:
        from tflock.repair import RRD_MAGIC

        with open(path, "rb") as file:
            cut = file.read(len(RRD_MAGIC)) == RRD_MAGIC  # a Rerun file whose end is cut: a killed run's
        fail(str(e) + (f"; if its run was killed, `tflock repair {path}` recovers what it holds" if cut else ""))
    out.print(f"[bold]{path}[/]", highlight=False, soft_wrap=True)
    out.print(f"model: {summary.model}")
    steps = f" (steps {summary.steps[0]} to {summary.last_step})" if summary.steps else ""
    out.print(f"frames: {summary.frames}{steps}")
    out.print(f"metric rows: {summary.metric_rows}")
    table = Table(title="final metrics", show_header=False)
    for name, value in summary.final_metrics.items():
        table.add_row(name, f"{value:.6g}")
    out.print(table)
    out.print("config:")
    out.print(summary.config_toml, markup=False, highlight=False)


@app.command()
def repair(
    path: Annotated[Path, typer.Argument(help="Recording (.rrd) of a killed run: no footer.")],
    out_path: Annotated[Path | None, typer.Option("--out", "-o", help="Write the repaired file here instead of "
                                                  "replacing PATH.")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an earlier file at --out.")] = False,
) -> None:
    """Make a killed run's recording complete (footer included) through Rerun's own reader and writer."""
    from tflock.repair import RepairError, repair_recording

    if out_path is not None and out_path.suffix != ".rrd":
        fail(f"--out: must be a .rrd file, got {str(out_path)!r}")
    try:
        result = repair_recording(path, out_path, overwrite=overwrite)
    except RepairError as e:
        fail(str(e))
    except OSError as e:
        fail(e.strerror or str(e))
    summary = result.summary
    held = "" if summary is None or summary.last_step is None else (
        f": {plural(summary.frames, 'frame')} (steps {summary.steps[0]} to {summary.last_step}), "
        f"{plural(summary.metric_rows, 'metric row')}")
    if not result.rewritten:
        out.print(f"{result.path} is complete already (rerun rrd verify passes){held}", highlight=False,
                  soft_wrap=True)
        return
    out.print(f"repaired {result.path} (rerun rrd verify passes){held}", highlight=False, soft_wrap=True)
    if summary is None:  # whole Rerun messages, but none of a tflock run's description
        out.print(f"it holds no tflock run's description (no /meta model or /config document: the run was cut "
                  f"before it wrote them), so `tflock inspect` cannot read it; `rerun {result.path}` shows what it "
                  "holds", highlight=False, soft_wrap=True)
        return
    table = path.with_suffix(".metrics.csv")
    last = _last_table_step(table)
    if last is not None:
        out.print(f"its metrics table {table} has rows up to step {last} (the recording's last metrics may be a "
                  "fraction of a second older)", highlight=False, soft_wrap=True)


def _last_table_step(table: Path) -> int | None:
    """The step of the last complete row of a metrics table, or None."""
    try:
        with open(table, "rb") as file:
            file.seek(max(0, file.seek(0, 2) - 65536))
            rows = file.read().decode("utf-8", "replace").split("\n")
    except OSError:
        return None
    for row in reversed(rows[:-1]):  # the text after the last newline is a row cut short, or nothing
        first = row.split(",", 1)[0]
        if first.isdigit():
            return int(first)
    return None


def _int_list(text: str, what: str, example: str) -> list[int]:
    try:
        values = [int(float(v)) for v in text.split(",") if v.strip()]
    except (ValueError, OverflowError):  # not a number; nan or inf
        fail(f"--{what}: expected comma-separated numbers such as {example}, got {text!r}")
    if not values or min(values) <= 0:
        fail(f"--{what}: every value must be > 0, got {text!r}")
    return values


def _refuse_bench_cases(todo: list, prefix: Path) -> None:
    """Before any case runs: every size must fit in memory and the results must be writable."""
    from tflock.bench import case_config
    from tflock.preflight import check_memory, check_writable

    for case in todo:
        try:
            config = case_config(case)
        except ConfigError as e:
            fail(f"--set: {case.model}: {e}")
        try:
            check_memory(load_config(config))
        except ConfigError as e:
            fail(f"--sizes: {case.model} at n = {case.n:,}: {e}")
    try:
        check_writable(prefix.with_suffix(".json"), "benchmark results")
    except OSError as e:
        fail(f"--out: {e.strerror or e}")


@app.command()
def bench(
    models_: Annotated[str, typer.Option("--models", help="Comma-separated models (default: all).")] = "",
    sizes: Annotated[str, typer.Option(help="Comma-separated N values.")] = "1e3,1e4,1e5,1e6",
    states: Annotated[str, typer.Option(help="uniform, developed or both.")] = "uniform,developed",
    develop_steps: Annotated[int, typer.Option(help="Steps before timing the developed state.")] = 300,
    repeats: Annotated[int, typer.Option(help="Timed steps per case.")] = 10,
    threads: Annotated[str, typer.Option(help="Comma-separated CPU thread counts (0 = all cores).")] = "0",
    arch: Annotated[str, typer.Option(help="cpu | cuda | vulkan | auto.")] = "cpu",
    precision: Annotated[str, typer.Option(help="f32 | f64.")] = "f32",
    log: Annotated[bool, typer.Option(
        "--log/--no-log", help="Also time logging: one frame, and the same steps again with a frame each.")] = False,
    peers: Annotated[bool, typer.Option("--peers/--no-peers", help=(
        "Time the peers: the NumPy reference, and the cKDTree and Numba steps where scipy / numba are installed "
        "(pip install -e '.\\[bench]' in the repository)."))] = True,
    prefix: Annotated[Path | None, typer.Option("--out", help=(
        "Results prefix (.json/.csv/.png added) \\[default: results/bench/bench-DATE-TIME]."))] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", "-s", help=(
        "Override a model parameter of the default config, e.g. params.box=240 (lengths then scale with N to "
        "keep its density)."))] = None,
    metrics_every: Annotated[int, typer.Option(help=(
        "Metrics cadence of the timed runs (run ms/step), >= 1; 0 = the model's default."))] = 0,
) -> None:
    """Scaling benchmark: ms/step, agent-steps/s, breakdown, memory and peers, written under results/bench/."""
    from tflock.bench import (
        STATES,
        BenchCase,
        CaseEngineError,
        cases,
        default_out,
        engine_labels,
        run_in_subprocess,
        write_results,
    )

    names = [m for m in models_.split(",") if m] or list(MODEL_DESCRIPTIONS)
    for name in names:
        if name not in MODEL_DESCRIPTIONS:
            fail(f"--models: must be among {', '.join(MODEL_DESCRIPTIONS)}, got {name!r}")
    wanted_states = [s for s in states.split(",") if s]
    if not wanted_states or any(s not in STATES for s in wanted_states):
        fail(f"--states: must be among {', '.join(STATES)}, got {states!r}")
    if arch not in ("cpu", "cuda", "vulkan", "auto") or precision not in ("f32", "f64"):
        fail(f"--arch / --precision: allowed cpu|cuda|vulkan|auto and f32|f64, got {arch!r} / {precision!r}")
    if repeats < 1:
        fail(f"--repeats: must be >= 1, got {repeats}")
    if develop_steps < 0:
        fail(f"--develop-steps: must be >= 0, got {develop_steps}")
    if metrics_every < 0:
        fail(f"--metrics-every: must be >= 1 (or 0: the model's default), got {metrics_every}")
    overrides = tuple(set_ or ())
    for expr in overrides:
        if not expr.startswith("params.") or expr.startswith("params.n="):
            fail(f"--set: only model parameters other than params.n (set by --sizes) may change, got {expr!r}")
    todo: list[BenchCase] = []
    for t in _int_list(threads, "threads", "1,2") if threads != "0" else [0]:
        todo += cases(names, _int_list(sizes, "sizes", "1e3,1e4"), wanted_states, develop_steps=develop_steps,
                      repeats=repeats, threads=t, arch=arch, precision=precision, log=log, peers=peers,
                      overrides=overrides, metrics_every=metrics_every)
    prefix = prefix or default_out()
    _refuse_bench_cases(todo, prefix)
    results, skipped = [], []
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, disable=not err.is_terminal) as progress:
        task = progress.add_task("bench", total=len(todo))
        for case in todo:
            progress.update(task, description=f"{case.model} n={case.n:,} {case.state}")
            try:
                results.append(run_in_subprocess(case))
            except CaseEngineError as e:  # (the same for every case: nothing would run)
                progress.stop()
                fail(str(e))
            except RuntimeError as e:
                err.print(f"[yellow]skipped:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
                skipped.append((case, str(e)))
            progress.advance(task)
    table = Table(title="tflock bench (ms per step: median (min-max); run: as tflock sim runs it, with metrics and "
                  "guard, against the plain step; logged run: a frame every step too, against the run; "
                  "workload = mean neighbours per agent)")
    engines = engine_labels(results)  # e.g. --threads 1,2: a column tells the rows apart
    for column in ("model", "N", "state", *(("engine",) if engines else ()), "neighbours", "ms/step", "run ms/step",
                   "logged run", "agent-steps/s", "build", "interact", "metrics", "log", "first step", "B/agent",
                   "peers (x tflock time)"):
        table.add_column(column, justify="right")
    for r in results:
        c = r.case
        opt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        peer_text = ", ".join(f"{k} {v['ratio']:.1f}x" for k, v in r.peers.items()) or "-"
        logged = "-" if r.logged_ms_median is None else (
            f"{r.logged_ms_median:.2f} ({r.logged_ms_min:.2f}-{r.logged_ms_max:.2f}, {r.logging_overhead:+.0%})")
        table.add_row(c.model, f"{c.n:,}", c.state, *((engines[r.engine],) if engines else ()),
                      f"{r.mean_neighbors:.1f}",
                      f"{r.ms_median:.2f} ({r.ms_min:.2f}-{r.ms_max:.2f})",
                      f"{r.run_ms_median:.2f} ({r.run_ms_min:.2f}-{r.run_ms_max:.2f}, {1 + r.run_overhead:.2f}x)",
                      logged, f"{r.agent_steps_per_s:.3g}",
                      opt(r.build_ms), opt(r.interactions_ms), f"{r.metrics_ms:.1f}", opt(r.logging_ms),
                      f"{r.first_step_s:.2f} s", f"{r.device_bytes_per_agent:.0f}", peer_text)
    (out if out.is_terminal else Console(width=200)).print(table)
    if not results:
        fail("no benchmark case completed")
    for path in write_results(results, prefix, "tflock " + " ".join(sys.argv[1:]), skipped):
        out.print(f"wrote {path}", highlight=False, soft_wrap=True)


@app.command()
def sweep(
    file: Annotated[Path, typer.Argument(help="Sweep file (TOML): model or base, fixed keys, grid, points.")],
    out_dir: Annotated[Path | None, typer.Option("--out", "-o", help="Folder (default results/sweeps/NAME).")] = None,
    workers: Annotated[int | None, typer.Option(help="Run the points on N local processes (Dask).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler to run on: tcp://HOST:PORT.")] = None,
    replicas: Annotated[int | None, typer.Option(help="Replicas per point (replaces the file's).")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", "-s", help="Fix a key for every point.")] = None,
) -> None:
    """Run a parameter sweep: every point of the grid x replicas, one table (Parquet and CSV); resumable."""
    from tflock.sweep import SweepError, default_out, load_sweep, run_sweep
    from tflock.sweep.table import point_path

    t_start = time.perf_counter()
    if workers is not None and workers < 1:
        fail(f"--workers: must be >= 1, got {workers}")
    if workers is not None and scheduler is not None:
        fail("--workers and --scheduler: give one of them, not both")
    try:
        plan = load_sweep(file, replicas=replicas, overrides=set_)
    except ConfigError as e:
        fail(str(e))
    folder = out_dir or default_out(plan.name)
    where = f"Dask at {scheduler}" if scheduler else f"{workers} local processes" if workers else "in-process"
    try:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err, disable=not err.is_terminal) as progress:
            task = progress.add_task(f"sweep {plan.name} ({where})", total=len(plan.points))

            def tick(finished: int, total: int) -> None:
                progress.update(task, completed=finished)

            table = run_sweep(plan, out=folder, workers=workers or 0, scheduler=scheduler, progress=tick)
    except (ConfigError, SweepError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        # counted on disk: a point written just before the signal may not have reached the progress bar yet
        done = sum(point_path(folder / "points", point).is_file() for point in plan.points)
        err.print(f"interrupted: {done} of {len(plan.points)} points saved in {folder / 'points'}; "
                  "run the same command again to resume", highlight=False, soft_wrap=True)
        raise typer.Exit(130) from None
    info = table.attrs["sweep"]
    summary = Table(title=f"sweep {plan.name}: {plan.model}", show_header=False)
    summary.add_column(style="bold")
    summary.add_column()
    summary.add_row("points", f"{info['points']} ({info['computed']} computed, {info['loaded']} from earlier runs)")
    summary.add_row("replicas", f"{info['replicas']} per point (seeds {plan.seed} .. {plan.seed + plan.replicas - 1})")
    summary.add_row("rows", f"{len(table)} x {len(table.columns)} columns")
    summary.add_row("ran", where if info["computed"] else "nothing to compute (every point read back)")
    summary.add_row("wall time", f"{time.perf_counter() - t_start:.1f} s")
    for path in [*info["files"], folder / "points"]:
        summary.add_row("wrote", str(path))
    out.print(summary)


@app.command()
def reproduce(
    name: Annotated[str | None, typer.Argument(help="Experiment (omit, or --list, to list them).")] = None,
    quick: Annotated[bool, typer.Option("--quick", help="Reduced sizes (seconds; what CI runs).")] = False,
    out_dir: Annotated[Path | None, typer.Option("--out", "-o",
                                                 help="Output folder \\[default: results/NAME].")] = None,
    workers: Annotated[int | None, typer.Option(help="Run sweep points on N local processes (Dask).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler to run on: tcp://HOST:PORT.")] = None,
    list_: Annotated[bool, typer.Option("--list", help="List the experiments.")] = False,
) -> None:
    """Reproduce a paper's published results: figures (PNG), table (CSV) and comparison.md; resumable."""
    from tflock.reproduce import EXPERIMENTS, experiment
    from tflock.reproduce.run import reproduce as run_reproduction
    from tflock.sweep import SweepError

    if list_ or name is None:
        listing = Table(title="tflock reproduce NAME", show_header=True)
        listing.add_column("name", style="bold")
        listing.add_column("experiment")
        listing.add_column("source", overflow="fold")  # a paper's file name whole, wrapped, not cut to "papers/00…"
        for key in sorted(EXPERIMENTS):
            exp = experiment(key)
            listing.add_row(key, exp.title, exp.source)
        out.print(listing)
        return
    if workers is not None and workers < 1:
        fail(f"--workers: must be >= 1, got {workers}")
    if workers is not None and scheduler is not None:
        fail("--workers and --scheduler: give one of them, not both")
    try:
        experiment(name)
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err, disable=not err.is_terminal) as progress:
            tasks: dict[str, int] = {}

            def tick(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = progress.add_task(f"{name}: {stage}", total=total)
                progress.update(tasks[stage], completed=done, total=total)

            result = run_reproduction(name, quick=quick, out=out_dir, workers=workers or 0, scheduler=scheduler,
                                      progress=tick)
    except (ConfigError, SweepError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        err.print("interrupted: finished sweep points and runs are kept; run the same command again to resume",
                  highlight=False, soft_wrap=True)
        raise typer.Exit(130) from None
    summary = Table(title=f"reproduce {name}{' --quick' if quick else ''}", show_header=False)
    summary.add_column(style="bold")
    summary.add_column()
    summary.add_row("runs", f"{result.computed} computed, {result.loaded} from earlier runs")
    summary.add_row("wall time", f"{result.wall_s:.1f} s")
    for path in result.files:
        summary.add_row("wrote", str(path))
    out.print(summary)


def main() -> None:
    """Console-script entry point."""
    app()
