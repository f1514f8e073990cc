"""Running a sweep: load finished points, compute the others where asked, store each as it arrives, build the table."""

import contextlib
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from tflock.config import ConfigError, config_to_toml
from tflock.sweep.execute import PointFailedError, SweepError, Task, executor
from tflock.sweep.spec import Sweep, load_sweep
from tflock.sweep.table import assemble, point_frame, point_path, read_point, write_point, write_table

__all__ = ["default_out", "run_sweep"]


def default_out(name: str) -> Path:
    """Where a sweep's files go unless told: ``results/sweeps/<name>/``."""
    return Path("results") / "sweeps" / name


def run_sweep(
    spec: Sweep | str | Path | Mapping[str, Any],
    *,
    out: str | Path | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Run a sweep and return its table (one row per point and replica), also written to ``out``.

    ``spec`` is a sweep file, a dict shaped like one, or a :class:`~tflock.sweep.spec.Sweep` from
    :func:`~tflock.sweep.spec.load_sweep`. ``out`` (default ``results/sweeps/<name>/``) receives
    ``points/<index>-<key>.parquet`` as each point finishes, then ``table.parquet`` and ``table.csv``; points whose
    file is already there (same config, swept values and replica count) are read instead of recomputed, which is
    how an interrupted sweep resumes. Points run in this process (``workers = 0``), on ``workers`` local Dask
    processes, or on the Dask cluster at ``scheduler`` (e.g. ``"tcp://10.0.0.5:8786"``). ``progress(done, total)``
    is called once the finished points are loaded and after each point; an exception it raises (e.g.
    KeyboardInterrupt) stops the sweep, keeping the points done so far.

    The table's ``attrs["sweep"]`` says what happened: name, out, files, points, computed, loaded, replicas,
    wall_s. Raises :class:`~tflock.config.ConfigError` for a bad sweep and :class:`SweepError` when it cannot run;
    both have one-line messages.
    """
    start = time.perf_counter()
    sweep = spec if isinstance(spec, Sweep) else load_sweep(spec)
    if workers < 0:
        raise SweepError(f"--workers: must be >= 0 (0 = in this process), got {workers}")
    if workers and scheduler is not None:
        raise SweepError("--workers and --scheduler: give one of them, not both")
    out = Path(out) if out is not None else default_out(sweep.name)
    points_dir = out / "points"
    made = [folder for folder in (points_dir, *points_dir.parents) if not folder.exists()]
    _writable(points_dir)
    try:
        return _run(sweep, out, points_dir, workers, scheduler, progress, start)
    except BaseException:  # a sweep refused or stopped before its first point leaves no empty folders
        for folder in made:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise


def _run(sweep: Sweep, out: Path, points_dir: Path, workers: int, scheduler: str | None,
         progress: Callable[[int, int], None] | None, start: float) -> pd.DataFrame:
    """:func:`run_sweep` once its points' folder exists."""
    report = progress or (lambda done, total: None)
    frames: dict[int, pd.DataFrame] = {}
    for point in sweep.points:
        path = point_path(points_dir, point)
        if path.is_file():
            frames[point.index] = _read(path)
    loaded = len(frames)
    total = len(sweep.points)
    report(loaded, total)
    todo = [Task(p.index, config_to_toml(p.config), sweep.replicas, sweep.seed)
            for p in sweep.points if p.index not in frames]
    if todo:
        with executor(workers, scheduler) as execute, contextlib.closing(execute(todo)) as finished:
            try:
                for index, rows in finished:
                    point = sweep.points[index]
                    path = point_path(points_dir, point)
                    _write(path, point_frame(point, rows))
                    frames[index] = _read(path)
                    report(len(frames), total)
            except PointFailedError as failure:
                raise SweepError(f"{sweep.points[failure.index].label}: {_message(failure.error)}") from None

    table = assemble((frames[p.index] for p in sweep.points), sweep.keys)
    try:
        files = write_table(table, out)
    except OSError as error:
        raise SweepError(f"--out: cannot write {out}: {error.strerror or error}") from None
    table.attrs["sweep"] = {"name": sweep.name, "out": out, "files": files, "points": total,
                            "computed": total - loaded, "loaded": loaded, "replicas": sweep.replicas,
                            "wall_s": time.perf_counter() - start}
    return table


def _writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise SweepError(f"--out: cannot create {folder}: {error.strerror or error}") from None
    if not os.access(folder, os.W_OK):
        raise SweepError(f"--out: cannot write into {folder}: permission denied")


def _write(path: Path, frame: pd.DataFrame) -> None:
    try:
        write_point(path, frame)
    except OSError as error:
        raise SweepError(f"--out: cannot write {path}: {error.strerror or error}") from None


def _read(path: Path) -> pd.DataFrame:
    try:
        return read_point(path)
    except (OSError, ValueError) as error:
        raise SweepError(f"{path}: unreadable ({_message(error)}); delete it to recompute the point") from None


def _message(error: BaseException) -> str:
    """An error as one line; its type is named unless it is one of ours (whose messages say it all)."""
    from tflock.engine import EngineError
    from tflock.simulation import NumericalFaultError

    text = " ".join(str(error).split())
    if isinstance(error, (ConfigError, EngineError, NumericalFaultError, SweepError)) and text:
        return text
    return f"{type(error).__name__}: {text}" if text else type(error).__name__
