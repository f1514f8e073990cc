"""Running an experiment: its sweeps and single runs (resumable), then its report written to disk."""

import hashlib
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from tflock.config import ConfigError, config_to_toml, load_config
from tflock.reproduce import experiment
from tflock.reproduce.experiment import Results, Series
from tflock.sweep.table import atomic_write

#: a progress callback: (stage label, done, total)
Progress = Callable[[str, int, int], None]


@dataclass
class Reproduction:
    """Where a reproduction's files went and how long it took."""

    name: str
    out: Path
    files: list[Path]
    wall_s: float
    computed: int  # sweep points and single runs computed now
    loaded: int  # ... and read back from an earlier, interrupted or finished, run


def default_out(name: str) -> Path:
    """``results/NAME/``."""
    return Path("results") / name


def reproduce(name: str, *, quick: bool = False, out: str | Path | None = None, workers: int = 0,
              scheduler: str | None = None, progress: Progress | None = None) -> Reproduction:
    """Run experiment `name` (at its quick size for CI, or at the paper's size) and write under `out`
    (default ``results/NAME/``): its figures as PNG, ``table.csv``, ``comparison.md``, and the raw data
    (``sweeps/<sweep>/table.parquet`` and ``series/<run>-<hash>.csv``). Sweep points and single runs found
    there from an earlier run of the same configs are read instead of recomputed. ``workers`` / ``scheduler``
    run the sweep points on Dask as ``tflock sweep`` does."""
    from tflock.sweep import run_sweep

    start = time.perf_counter()
    exp = experiment(name)
    options = [("--quick", quick), (f"--out {out}", out is not None), (f"--workers {workers}", workers),
               (f"--scheduler {scheduler}", scheduler)]
    command = " ".join([f"tflock reproduce {name}", *(option for option, given in options if given)])
    out = Path(out) if out is not None else default_out(name)
    report = progress or (lambda stage, done, total: None)
    results = Results()
    computed = loaded = 0
    for sweep_name, spec in exp.sweeps(quick).items():
        table = run_sweep({"name": sweep_name, **spec}, out=out / "sweeps" / sweep_name, workers=workers,
                          scheduler=scheduler, progress=lambda done, total, s=sweep_name: report(s, done, total))
        results.sweeps[sweep_name] = table
        computed += table.attrs["sweep"]["computed"]
        loaded += table.attrs["sweep"]["loaded"]
    runs = exp.series(quick)
    for k, (run_name, config) in enumerate(runs.items()):
        report(run_name, k, len(runs))
        series, was_loaded = _series(run_name, config, out / "series")
        results.series[run_name] = series
        loaded += was_loaded
        computed += not was_loaded
        report(run_name, k + 1, len(runs))
    import matplotlib

    matplotlib.use("Agg")  # files only: the figures are drawn without a display
    outcome = exp.report(results, quick)
    point_s = sum(float(table["wall_s"].sum()) for table in results.sweeps.values() if "wall_s" in table)
    files = _write_report(exp, outcome, out, quick, command, time.perf_counter() - start, computed, loaded, point_s)
    return Reproduction(name, out, files, time.perf_counter() - start, computed, loaded)


def _series(name: str, config: dict, folder: Path) -> tuple[Series, bool]:
    """A single run's metrics table, from ``folder/<name>-<hash>.csv`` if an earlier run left it."""
    from tflock.simulation import Simulation

    resolved = load_config(config)
    key = hashlib.sha256(config_to_toml(resolved).encode()).hexdigest()[:12]
    path = folder / f"{name}-{key}.csv"
    if path.is_file():
        frame = pd.read_csv(path)
        return {column: frame[column].to_numpy() for column in frame.columns}, True
    simulation = Simulation(resolved)
    simulation.run()
    series = simulation.metrics()
    _atomic_csv(pd.DataFrame(series), path)
    return series, False


def _atomic_csv(frame: pd.DataFrame, path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda tmp: frame.to_csv(tmp, index=False))
    except OSError as error:
        raise ConfigError(f"--out: cannot write {path}: {error.strerror or error}") from None


def _write_report(exp, outcome, out: Path, quick: bool, command: str, wall_s: float, computed: int, loaded: int,
                  point_s: float) -> list[Path]:
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    files = []
    for stem, figure in outcome.figures.items():
        path = out / f"{stem}.png"
        figure.savefig(path, dpi=120, bbox_inches="tight")
        plt.close(figure)
        files.append(path)
    table_path = out / "table.csv"
    _atomic_csv(outcome.table, table_path)
    size = "quick (--quick: reduced sizes for CI)" if quick else exp.full_size
    header = (f"# {exp.title}\n\nSource: {exp.source}. Size: {size}. "
              f"Command: `{command}`. "
              f"Wall time of this invocation: {wall_s:.0f} s ({platform.processor() or platform.machine()}), "
              f"{computed} runs or sweep points computed and {loaded} read back from an earlier invocation; the "
              f"sweep points took {point_s:.0f} s to compute, summed over the points as each recorded it.\n\n")
    comparison = out / "comparison.md"
    comparison.write_text(header + outcome.comparison.strip() + "\n")
    return [*files, table_path, comparison]
