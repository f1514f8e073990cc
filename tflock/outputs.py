"""Output ownership: a run owns the files it writes, from its start to its end.

A run writes its recording (``x.rrd``) and its metrics table (``x.metrics.csv``) in place, as it goes, so that
they can be read while it runs (``tflock inspect``, ``tail -f``) and a killed run leaves what it had written at
the final names. Two rules keep two runs from writing into each other's files:

* **Lock.** For each output it writes (the recording, whose lock covers its metrics table, and the checkpoint) a
  run holds an exclusive ``flock`` on a lock file beside it, ``<name>.lock``, holding its pid and host. A second
  run on the same path fails at start (:class:`OutputBusyError`) and writes nothing. The kernel drops the lock when
  the process ends however it ends, so a lock file left by a killed run holds no lock and the next run reuses it;
  a run that ends normally, on Ctrl-C / SIGTERM or on a fault removes its lock files.
* **No silent overwrite.** An existing output from an earlier run is refused (:class:`OutputExistsError`) unless
  the run is asked to overwrite (``--overwrite``, ``overwrite=True``); the checkpoint a run resumes from may be
  its own checkpoint. A default recording name (``recordings/<model>-<time>.rrd``) that is taken gets a
  ``-2``, ``-3``, ... suffix instead.

Where ``fcntl`` does not exist (Windows) there is no lock; the overwrite rule still holds.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from tflock.preflight import check_writable

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

LOCK_SUFFIX = ".lock"
T = TypeVar("T")


class OutputBusyError(OSError):
    """An output path is locked by another run (or by a Simulation of this process that is still open)."""


class OutputExistsError(FileExistsError):
    """An output path holds an earlier run's file, and the run was not asked to overwrite it."""


def lock_path(path: Path) -> Path:
    """The lock file of an output: ``x.rrd`` -> ``x.rrd.lock``."""
    return path.with_name(path.name + LOCK_SUFFIX)


def _owner(fd: int) -> str:
    """Who holds a lock, from what it wrote in its lock file: ``pid N`` (``pid N on HOST`` from another host)."""
    try:
        words = os.pread(fd, 200, 0).decode("utf-8", "replace").split()
    except OSError:
        words = []
    if not words or not words[0].isdigit():
        return "pid unknown"
    pid, host = int(words[0]), words[1] if len(words) > 1 else ""
    if host and host != socket.gethostname():
        return f"pid {pid} on {host}"
    if pid == os.getpid():
        return f"pid {pid}: a Simulation of this process that is still open; close() it first"
    return f"pid {pid}"


def _acquire(path: Path) -> int | None:
    """Take the exclusive lock of output `path` (None where there is no fcntl); raise OutputBusyError if it is held."""
    if fcntl is None:
        return None
    where = lock_path(path)
    while True:
        fd = os.open(where, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = _owner(fd)
            os.close(fd)
            raise OutputBusyError(16, f"{path} is being written by another tflock run ({owner})") from None
        try:  # its holder may have removed the file between our open and our lock: then lock the new one
            current = os.stat(where)
        except FileNotFoundError:
            current = None
        if current is not None and os.path.samestat(os.fstat(fd), current):
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
    return fd


@dataclass
class OutputLock:
    """The lock a run holds on output `path` (and the files named after it: a recording's metrics table)."""

    path: Path
    fd: int | None = None

    def release(self) -> None:
        """Remove the lock file, then drop the lock (idempotent)."""
        if self.fd is None:
            return
        try:
            os.unlink(lock_path(self.path))
        except FileNotFoundError:
            pass
        os.close(self.fd)
        self.fd = None


@dataclass
class Outputs:
    """The outputs of one run, locked for its lifetime; :meth:`release` at its end (idempotent). `replaced`: an
    earlier run's files that ``--overwrite`` replaces, deleted by :meth:`remove_replaced` once the run starts."""

    locks: list[OutputLock] = field(default_factory=list)
    replaced: list[Path] = field(default_factory=list)

    def remove_replaced(self) -> None:
        """Delete the earlier run's files this run replaces: when it starts, not half-way through it, and not
        before, so that a run refused at its start (an engine that is missing, a start state that is not finite)
        leaves them as they were."""
        for file in self.replaced:
            file.unlink(missing_ok=True)
        self.replaced.clear()

    def release(self) -> None:
        for lock in self.locks:
            lock.release()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock(path: Path) -> OutputLock:
    """Lock an existing output (to rewrite it: ``tflock repair``); raises OutputBusyError while a run holds it."""
    return OutputLock(path, _acquire(path))


def claim(path: Path, what: str, covers: Iterable[tuple[Path, str]] = (), *, overwrite: bool = False,
          allowed: Path | None = None, into: Outputs) -> OutputLock:
    """Check that output `path` (the `what`: "recording", "checkpoint") and the files it `covers` (path, what) can
    be written, lock it for this run and refuse an earlier run's file there: unless `overwrite`, which lists them in
    ``into.replaced`` (:meth:`Outputs.remove_replaced`; `allowed` may exist and stays: the checkpoint a run resumes
    from). Appends the lock to `into`. Raises OSError ("cannot write the ..."), OutputBusyError or
    OutputExistsError, leaving nothing behind."""
    files = [(path, what), *covers]
    for file, kind in files:
        check_writable(file, kind)
    held = lock(path)
    existing = [f for f, _ in files if f.exists() and not (allowed is not None and _same_file(f, allowed))]
    if existing and not overwrite:
        held.release()
        raise OutputExistsError(17, f"{existing[0]} exists (an earlier run's output); --overwrite "
                                    "(overwrite=True in Python) replaces it, or give another path")
    into.replaced += existing
    into.locks.append(held)
    return held


#: the most numbered names tried for a default output name before giving up
MAX_NUMBERED = 1000


def first_free(base: Path, attempt: Callable[[Path], T]) -> T:
    """``attempt(name)`` for ``base`` (``x.rrd``), then ``x-2.rrd``, ``x-3.rrd``, ... until one is neither locked nor
    taken (`attempt` raises OutputBusyError / OutputExistsError for a name in use, having released what it took)."""
    for k in range(1, MAX_NUMBERED + 1):
        name = base if k == 1 else base.with_name(f"{base.stem}-{k}{base.suffix}")
        try:
            return attempt(name)
        except (OutputBusyError, OutputExistsError):
            continue
    raise OutputBusyError(16, f"{base} and {MAX_NUMBERED - 1} numbered names after it are all in use")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False
