"""The `tflock` command line: a thin layer over :class:`tflock.Simulation` and :mod:`tflock.record`.

Every user error (bad config, missing file, unwritable output, unavailable arch) is one line on stderr and exit
code 2; Ctrl-C or SIGTERM stops a run cleanly and leaves a complete recording up to the last logged frame.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from tflock.config import MODEL_DESCRIPTIONS, ConfigError, default_config_toml, load_config

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Large-N flocking simulation on Taichi, recorded to Rerun.")
config_app = typer.Typer(no_args_is_help=True, help="Inspect model configs.")
app.add_typer(config_app, name="config")
out = Console()
err = Console(stderr=True)


def fail(message: str) -> NoReturn:
    """One-line error, exit code 2."""
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
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
    no_log: Annotated[bool, typer.Option("--no-log", help="Record nothing (metrics still printed).")] = False,
) -> None:
    """Run a simulation: `tflock sim` runs the default Vicsek config and records it under recordings/."""
    t_start = time.perf_counter()
    overrides = list(set_ or [])
    for key, value in (("steps", steps), ("seed", seed), ("engine.arch", arch), ("engine.threads", threads)):
        if value is not None:
            overrides.append(f"{key}={value!r}" if isinstance(value, str) else f"{key}={value}")
    try:
        cfg = load_config(config, model=model, overrides=overrides)
    except ConfigError as e:
        fail(str(e))
    if out_path is not None and out_path.suffix != ".rrd":
        fail(f"--out: must be a .rrd file, got {str(out_path)!r}")
    record: bool | Path = False if no_log else (out_path or (not (spawn or connect)))

    signal.signal(signal.SIGTERM, signal.default_int_handler)  # SLURM, timeout, docker stop: finish the file
    signal.signal(signal.SIGINT, signal.default_int_handler)  # also when started in the background
    from tflock.engine import EngineError
    from tflock.simulation import Simulation

    try:
        simulation = Simulation(cfg, record=record, spawn=spawn, connect=connect)
    except OSError as e:
        fail(e.strerror or str(e))
    except (EngineError, RuntimeError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        err.print("interrupted during start-up", highlight=False)
        raise typer.Exit(130) from None
    t_ready = time.perf_counter()
    interrupted = False
    first_step_s = 0.0
    t_loop = t_ready
    try:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), console=err,
                      disable=not err.is_terminal, transient=False) as progress:
            task = progress.add_task(f"{cfg.model} n={cfg.params.n}", total=cfg.steps, rate="")
            t_last = time.perf_counter()

            def tick(step: int) -> None:
                nonlocal t_last
                now = time.perf_counter()
                if now - t_last > 0.25 or step == cfg.steps:
                    rate = (step - 1) / (now - t_loop) if step > 1 and now > t_loop else 0.0
                    progress.update(task, completed=step, rate=f"{rate:,.0f} steps/s")
                    t_last = now

            if cfg.steps > 0:
                t0 = time.perf_counter()
                simulation.step(1, tick)  # the first step compiles the step kernels
                first_step_s = time.perf_counter() - t0
                t_loop = time.perf_counter()
                simulation.run(tick)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        simulation.close()
    t_end = time.perf_counter()
    _summary(simulation, t_start, t_ready, first_step_s, t_loop, t_end, interrupted)
    if interrupted:
        raise typer.Exit(130)


def _summary(simulation, t_start: float, t_ready: float, first_step_s: float, t_loop: float, t_end: float,
             interrupted: bool) -> None:
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
    table.add_row("engine", f"{simulation.engine.arch}, {simulation.engine.threads} threads, "
                            f"{simulation.engine.precision}")
    metrics = simulation.metrics()
    for name in simulation.model.metric_descriptions:
        if len(metrics[name]):
            table.add_row(name, f"{metrics[name][-1]:.6g}")
    table.add_row("steps/s", f"{rate:,.1f} (after the first step)")
    table.add_row("agent-steps/s", f"{rate * cfg.params.n:,.3g}")
    table.add_row("start-up", f"{t_ready - t_start:.2f} s (Taichi init, first metrics; compile included)")
    table.add_row("first step", f"{first_step_s:.2f} s (compile included)")
    table.add_row("wall time", f"{t_end - t_start:.2f} s")
    for path in simulation.files:
        table.add_row("wrote", str(path))
    out.print(table)
    rrd = [p for p in simulation.files if p.suffix == ".rrd"]
    if rrd:
        out.print(f"view it: [bold]tflock view {rrd[0]}[/] (or `rerun {rrd[0]}`)", highlight=False)


@app.command()
def models() -> None:
    """List the models."""
    for name, description in MODEL_DESCRIPTIONS.items():
        out.print(f"[bold]{name}[/]  {description}", highlight=False)


@config_app.command("show")
def config_show(model: Annotated[str, typer.Argument(help="Model name (see `tflock models`).")] = "vicsek") -> None:
    """Print the complete default config of a model, with a comment per key."""
    if model not in MODEL_DESCRIPTIONS:
        fail(f"model: must be one of {', '.join(MODEL_DESCRIPTIONS)}, got {model!r}")
    sys.stdout.write(default_config_toml(model))


@app.command()
def view(
    path: Annotated[Path, typer.Argument(help="Recording (.rrd).")],
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer on localhost (no display needed).")] = False,
    port: Annotated[int, typer.Option(help="Web viewer port.")] = 9090,
) -> None:
    """Open a recording in the Rerun viewer."""
    from tflock.record import open_viewer

    if not path.is_file():
        fail(f"recording not found: {path}")
    try:
        open_viewer(path, web=web, port=port)
    except (RuntimeError, OSError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        pass


@app.command()
def inspect(path: Annotated[Path, typer.Argument(help="Recording (.rrd).")]) -> None:
    """Print a recording's model, config, frame count and final metrics, read back from the file."""
    from tflock.record import read_recording

    if not path.is_file():
        fail(f"recording not found: {path}")
    try:
        summary = read_recording(path)
    except ValueError as e:
        fail(str(e))
    out.print(f"[bold]{path}[/]", highlight=False)
    out.print(f"model: {summary.model}")
    first = summary.steps[0] if summary.steps else None
    out.print(f"frames: {summary.frames} (steps {first} to {summary.last_step})")
    out.print(f"metric rows: {summary.metric_rows}")
    table = Table(title="final metrics", show_header=False)
    for name, value in summary.final_metrics.items():
        table.add_row(name, f"{value:.6g}")
    out.print(table)
    out.print("config:")
    out.print(summary.config_toml, markup=False, highlight=False)


def main() -> None:
    """Console-script entry point."""
    app()
