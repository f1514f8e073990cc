"""Checks a run passes before it allocates or writes anything: the memory it needs, writable output paths and a
viewer that answers where it streams to.

The memory estimate counts, per agent, the arrays each model allocates (state, neighbour grid, graph metrics)
and the larger of its host copies (the NumPy start-up draws, then the non-finite guard's copy of a good state)
at the run's float size, and compares the total with the machine's physical memory. It is rough (the grid's bucket count
varies with the box) but close: at f32 the default configs count 124 (vicsek), 132 (adaptive), 156 (potential)
and 176 (formation) device bytes per agent, and ``tests/test_bad_input.py`` checks the counts against the
arrays the models really allocate (:func:`tflock.bench.device_bytes`).
"""

import os
import socket
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from tflock.config import Config, ConfigError

#: agent ids are 32-bit integers in every kernel
MAX_AGENTS = 2**31 - 1
#: the port of a Rerun viewer's gRPC server when the URL names none (the viewer's default), and how long to wait for it
VIEWER_PORT = 9876
VIEWER_SCHEMES = ("rerun", "rerun+http", "rerun+https")
VIEWER_TIMEOUT_S = 3.0
#: host bytes per agent of the start-up draws (a few float64 / int64 NumPy arrays, freed once uploaded)
STARTUP_BYTES = 64


def _grid(dim: int, graph: bool, hashed: bool) -> tuple[float, float]:
    """(floats, ints) per agent of a cell grid (sorted positions, cell coordinates, ~2 buckets per agent; a hashed
    open-space grid has 2-4 buckets per agent, each with a count, a start and a shared-bucket flag) and, with
    ``graph``, the union-find arrays of the cluster metrics."""
    return dim, 2 * dim + 8 + (8 if hashed else 0) + (3 if graph else 0)


def _vicsek(p: Any) -> tuple[float, float]:
    """pos 2, theta, payload 3, turn (+ neighbour sums 3 and cos/sin 2 for the synchronous step in a box, which
    the CPU runs lane-wise); ids, updated; the ring of past states."""
    ring = p.async_bound + 1 if p.async_bound > 1 else 0
    lane_wise = 5 if not ring and p.boundary != "open" else 0
    return 7 + lane_wise + 3 * ring, 2 + (1 if ring else 0)


def _potential(p: Any) -> tuple[float, float]:  # pos, vel, scratch (+ pos_next), energy, nearest; ids, where,
    fixed = p.topology == "fixed"  # valency (+ CSR offsets and ~2 neighbour entries on a fixed graph; the runs of
    lane_wise = 0 if fixed else 3  # cells of the switching step, one per bucket)
    return (4 if fixed else 3) * p.dim + 2, (6 if fixed else 3) + lane_wise


#: (floats, ints) per agent of each model's own arrays, counted from its allocations (a new model adds its count)
MODEL_ARRAYS: dict[str, Callable[[Any], tuple[float, float]]] = {
    "vicsek": _vicsek,
    "adaptive": lambda p: (3 * p.dim + 1, 1),  # pos, dirs, payload (dim each), phi; ids
    "potential": _potential,
    # two buffers of pos 2, f 4, i 2 and ids; payload 2, rule, where; its torus is mostly empty, so the grid has
    # its cap of 4 cells per agent: 2 more than _grid counts (a count and a start each), and 4 run ends
    "formation": lambda p: (14, 16),
}


def _bytes(config: Config, floats: float, ints: float) -> float:
    return floats * (4 if config.engine.precision == "f32" else 8) + ints * 4


def device_bytes_per_agent(config: Config) -> float:
    """Bytes per agent of the Taichi arrays a run of ``config`` allocates: the model's, its grid's and metrics'."""
    p = config.params
    hashed = config.model == "potential" or getattr(p, "boundary", None) == "open"  # potential is always open
    grid = _grid(getattr(p, "dim", 2), graph=config.model != "formation", hashed=hashed)  # formation: no clusters
    return _bytes(config, *MODEL_ARRAYS[config.model](config.params)) + _bytes(config, *grid)


def estimate_bytes(config: Config) -> int:
    """Rough peak memory of a run of ``config``: the Taichi arrays, and the larger of the start-up draws (freed once
    uploaded) and the guard's host copy of the model's own arrays (made after them)."""
    model = _bytes(config, *MODEL_ARRAYS[config.model](config.params))
    per_agent = device_bytes_per_agent(config) + max(model, STARTUP_BYTES)
    return int(config.params.n * per_agent)


def physical_memory() -> int | None:
    """Bytes of physical memory of this machine, or None where the OS does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:,.1f} GiB"


def check_memory(config: Config) -> None:
    """Refuse (ConfigError naming params.n) a run whose agents need more memory than the machine has."""
    n = config.params.n
    if n > MAX_AGENTS:
        raise ConfigError(f"params.n: must be <= {MAX_AGENTS} (agent ids are 32-bit), got {n}")
    need, have = estimate_bytes(config), physical_memory()
    if have is not None and need > have:
        fit = have * n // need
        raise ConfigError(f"params.n: {n:,} agents need about {_gib(need)} ({need // n} bytes per agent), more "
                          f"than this machine's {_gib(have)} of memory; at most about {fit:,.3g} agents fit")


def check_writable(path: Path, what: str) -> None:
    """Refuse an output path that cannot be written (OSError "cannot write the <what> to <path>: <reason>"),
    leaving no file behind: the directory is created as the writer would, and a probe file made and removed."""
    path = Path(path).expanduser()
    try:
        if path.is_dir():
            raise IsADirectoryError(21, "it is a directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent, prefix=".tflock-probe-"):
            pass
        if path.exists() and not os.access(path, os.W_OK):
            raise PermissionError(13, "permission denied")
    except OSError as e:
        reason = e.strerror or str(e)
        if isinstance(e, FileExistsError | NotADirectoryError):  # a file where the path needs a folder
            blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
            reason = reason if blocking is None else f"{blocking} is a file, not a folder"
        raise OSError(e.errno, f"cannot write the {what} to {path}: {reason}") from None


def check_viewer(url: str) -> None:
    """Refuse a viewer URL (``--connect``) where nothing accepts a connection (ConnectionError "--connect: ..."):
    Rerun's gRPC sink would drop everything the run logs, and say so only at its end, in a log line of its own. A
    URL Rerun does not accept is its own error, raised when the sink is made."""
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port or VIEWER_PORT
    except ValueError:  # a port that is no number: Rerun's own error names the endpoint
        return
    if parts.scheme not in VIEWER_SCHEMES or not host:
        return
    try:
        socket.create_connection((host, port), timeout=VIEWER_TIMEOUT_S).close()
    except OSError as e:
        reason = e.strerror or str(e) or type(e).__name__
        raise ConnectionError(f"--connect: no Rerun viewer answers at {host}:{port} ({reason.lower()}); start one "
                              "(tflock view --live [--web] prints the URL to connect to), or record to a file and open "
                              "it later") from None
