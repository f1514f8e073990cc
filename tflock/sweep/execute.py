"""Where a sweep's points run: in this process, one after another, or as tasks on a Dask distributed cluster.

Both yield ``(point index, rows)`` as points finish. A Dask task carries only the point's config TOML, its replica
count and seed (plain, picklable data); each worker process starts Taichi itself on its first point, with the
config's ``[engine]`` settings, and runs one point at a time (Taichi is not thread-safe), however many threads the
worker has.
"""

import asyncio
import contextlib
import logging
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from tflock.sweep.point import run_point

__all__ = ["PointFailedError", "SweepError", "Task", "executor"]

CONNECT_TIMEOUT_S = 10
"""How long ``--scheduler`` waits for the Dask scheduler to answer."""

QUIET = logging.ERROR
"""Level of Dask's loggers here and in local workers: its start-up and shutdown chatter stays off the terminal."""

Rows = list[dict[str, Any]]
Execute = Callable[[Sequence["Task"]], Iterator[tuple[int, Rows]]]


@dataclass(frozen=True)
class Task:
    """A point to compute: picklable, so it travels to Dask workers as is."""

    index: int
    config_toml: str
    replicas: int
    seed: int


class PointFailedError(Exception):
    """Computing point ``index`` raised ``error`` (here or on a worker)."""

    def __init__(self, index: int, error: BaseException) -> None:
        super().__init__(index, error)
        self.index = index
        self.error = error


class SweepError(RuntimeError):
    """A sweep cannot run or finish (unreachable cluster, unwritable output, a failed point); one-line message."""


@contextlib.contextmanager
def executor(workers: int = 0, scheduler: str | None = None) -> Iterator[Execute]:
    """A function that computes tasks and yields ``(index, rows)`` as each finishes: in-process when ``workers``
    is 0 and no ``scheduler`` is given, else on ``workers`` local Dask processes or on the Dask cluster at address
    ``scheduler``. A cluster started here is closed on exit, also after an exception or Ctrl-C."""
    if not workers and scheduler is None:
        yield _in_process
        return
    with _client(workers, scheduler) as client:
        yield lambda tasks: _on_dask(client, tasks)


def _in_process(tasks: Sequence[Task]) -> Iterator[tuple[int, Rows]]:
    for task in tasks:
        try:
            rows = run_point(task.config_toml, task.replicas, task.seed)
        except Exception as error:
            raise PointFailedError(task.index, error) from error
        yield task.index, rows


@contextlib.contextmanager
def _client(workers: int, scheduler: str | None) -> Iterator[Any]:
    dask_log = logging.getLogger("distributed")
    level = dask_log.level
    dask_log.setLevel(QUIET)
    try:
        with _connect(scheduler) if scheduler is not None else _local_cluster(workers) as client:
            yield client
    finally:
        dask_log.setLevel(level)


def _connect(scheduler: str) -> Any:
    from distributed import Client

    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, ValueError, TypeError) as error:
        message = " ".join(str(error).split()) or type(error).__name__
        raise SweepError(f"--scheduler: cannot connect to {scheduler!r}: {message}") from None


@contextlib.contextmanager
def _local_cluster(workers: int) -> Iterator[Any]:
    from distributed import Client, LocalCluster

    # a terminal sends Ctrl-C to the whole process group: local workers ignore it (dask_setup) and we close them;
    # ":0": the scheduler's HTTP server takes a free port (the default 8787 warns when another cluster holds it)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=QUIET, preload=[__name__]) as cluster, Client(cluster) as client:
        yield client


HEARTBEAT_RACE = "Failed to communicate with scheduler during heartbeat"
"""What a local worker logs, as an error with a traceback, when its heartbeat meets the scheduler already closed at
the end of a sweep (a race in the cluster's shutdown: a clean-clone CI run failed on it once)."""


def _not_heartbeat_race(record: logging.LogRecord) -> bool:
    return not record.getMessage().startswith(HEARTBEAT_RACE)


def dask_setup(worker: Any) -> None:
    """Run by Dask in each local worker process at start (``preload``): ignore SIGINT, which the terminal sends to
    every process of the group on Ctrl-C (the sweep stops and closes its workers itself), and drop the heartbeat
    error of the shutdown race (a scheduler lost mid-sweep still shows, as the points' failure)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger("distributed.worker").addFilter(_not_heartbeat_race)


def _on_dask(client: Any, tasks: Sequence[Task]) -> Iterator[tuple[int, Rows]]:
    from distributed import as_completed

    futures = {client.submit(_run_task, task, pure=False): task.index for task in tasks}
    try:
        for future in as_completed(futures):
            index = futures[future]
            try:
                rows = future.result()
            except (Exception, asyncio.CancelledError) as error:
                raise PointFailedError(index, error) from error
            yield index, rows
    finally:
        client.cancel(list(futures))


_ONE_AT_A_TIME = threading.Lock()


def _run_task(task: Task) -> Rows:
    """A point on a Dask worker; points on the same worker process run one at a time."""
    with _ONE_AT_A_TIME:
        return run_point(task.config_toml, task.replicas, task.seed)
