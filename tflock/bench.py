"""Scaling benchmarks: `tflock bench`.

Each case (model, N, start state, threads, arch, precision, logging on or off) runs in a fresh subprocess, so
engine settings can differ between cases and peak memory is the case's own. A case builds the model's default
config at N agents with the default density kept (the box side scales as N^(1/dim)), steps it to the wanted
state, then times single steps. The first step (JIT compile) is reported apart. Per case: ms per step (median,
min, max over repeats), agent-steps per second, what a run costs per step as ``tflock sim`` runs (the step, the
metrics at the model's default cadence, the non-finite guard; with logging a frame every step too) against the
plain step (:func:`_plain_and_run_steps`), a breakdown (neighbour-grid build, interactions = the rest of the
step, one metrics pass, one logged frame), the mean neighbour count (the workload: a step's cost follows it),
peak resident memory and the model's device bytes per agent.

Peers run in the same subprocess, on the same state, right after tflock's timing, and are reported as times and
as ratios to tflock (absolute times drift on shared machines): the plain NumPy reference (O(N^2), where it
takes under ~10 s a step; Vicsek and potential) and, for Vicsek when scipy is installed, a cKDTree +
sparse-matrix step written the way the common minimal scripts do it, and when numba is installed, a parallel
Numba cell-list step written the usual way (`tflock.peers.numba_vicsek`; its first call, JIT compile or cache
load, is reported apart as first_call_s).
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

STATES = ("uniform", "developed")
PEER_BUDGET_S = 10.0  # a peer runs only where one step is expected to take less than this
#: expected time of a numba cell-list peer step: per agent and per agent-neighbour pair (2 loaded cores)
NUMBA_S_PER_AGENT, NUMBA_S_PER_PAIR = 1e-6, 4e-8
#: expected time of the cKDTree + sparse-matrix peer per agent-neighbour pair (0.2-0.35 us measured here at 1e6)
CKDTREE_S_PER_PAIR = 4e-7
LOG_TURNS = 8  # turns of plain steps and runs per case (see _plain_and_run_steps)
METRICS_NEVER = 10**9  # log.metrics_every of a case: steps logged for timing take no metrics pass (timed apart)


@dataclass(frozen=True)
class BenchCase:
    """One measurement: the model at `n` agents in a start state, with engine settings."""

    model: str
    n: int
    state: str = "uniform"  # uniform: from the initial state; developed: after `develop_steps` steps
    develop_steps: int = 300
    repeats: int = 10
    threads: int = 0
    arch: str = "cpu"
    precision: str = "f32"
    log: bool = False  # time a logged frame (max_agents drawn) on top of the step
    log_agents: int = 50_000
    peers: bool = True
    overrides: tuple[str, ...] = ()  # "params.key=value" applied to the default config before N is set
    metrics_every: int = 0  # the metrics cadence of the timed runs (0: the model's default, log.metrics_every)


@dataclass
class BenchResult:
    """What a case measured (times in ms unless named otherwise)."""

    case: BenchCase
    engine: str = ""
    box: float = 0.0
    mean_neighbors: float = 0.0
    first_step_s: float = 0.0  # JIT compile included
    setup_s: float = 0.0  # model construction, initial metrics included
    ms_median: float = 0.0
    ms_min: float = 0.0
    ms_max: float = 0.0
    agent_steps_per_s: float = 0.0
    build_ms: float | None = None
    interactions_ms: float | None = None
    metrics_ms: float = 0.0
    logging_ms: float | None = None  # one logged frame: the non-finite guard, the frame (edges too), Rerun
    run_ms_median: float = 0.0  # a run's ms per step as tflock sim runs it: metrics (default cadence), guard
    run_ms_min: float = 0.0  # the fastest and slowest of those runs (ms per step)
    run_ms_max: float = 0.0
    run_overhead: float = 0.0  # median over turns of (a run's ms per step / its turn's plain ms per step) - 1
    logged_ms_median: float | None = None  # with log: the same run with a frame every step
    logged_ms_min: float | None = None  # with log: the fastest and slowest logged run (ms per step)
    logged_ms_max: float | None = None
    logging_overhead: float | None = None  # with log: median over turns of (logged run / run without frames) - 1
    peak_rss_mb: float = 0.0
    device_bytes_per_agent: float = 0.0
    # name -> {"ms": .., "ratio": peer / tflock} (numba_cells adds "first_call_s": its JIT compile or cache load)
    peers: dict[str, dict[str, float]] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        """Flat dict for CSV / tables."""
        out = {**asdict(self.case), **{k: v for k, v in asdict(self).items() if k not in ("case", "peers")}}
        out["overrides"] = " ".join(self.case.overrides)
        for name, peer in self.peers.items():
            for key, value in peer.items():
                out[f"{name}_{key}"] = value
        return out


#: length parameters scaled with N to keep a model's default density
LENGTHS = ("box", "world", "init_length", "init_width")


def case_config(case: BenchCase) -> dict[str, Any]:
    """The model's default config (with the case's overrides) at N = case.n, same density (lengths scaled by
    (n / n0)^(1/dim)). Raises :class:`tflock.config.ConfigError` on a bad override."""
    from tflock.config import load_config

    params = load_config(model=case.model, overrides=list(case.overrides)).params
    scale = (case.n / params.n) ** (1.0 / getattr(params, "dim", 2))
    lengths = {k: float(getattr(params, k)) * scale for k in LENGTHS if hasattr(params, k)}
    # steps: one more than the timed steps reach, so that none is the run's last (which takes a metrics pass)
    return {"model": case.model, "seed": 1, "steps": case.develop_steps + case.repeats + 2,
            "engine": {"arch": case.arch, "threads": case.threads, "precision": case.precision},
            "params": {**_override_tree(case.overrides)["params"], "n": case.n, **lengths},
            "log": {"max_agents": case.log_agents, "every": 1, "metrics_every": METRICS_NEVER}}


def _override_tree(overrides: Iterable[str]) -> dict[str, Any]:
    """{"params": {...}} from "params.key=value" overrides (dotted keys nest)."""
    from tflock.config import parse_override

    tree: dict[str, Any] = {"params": {}}
    for expr in overrides:
        key, value = parse_override(expr)
        *parents, leaf = key.split(".")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def device_bytes(obj: object, seen: set[int] | None = None, depth: int = 0) -> int:
    """Bytes of the Taichi ndarrays an object holds, alone or in lists (double buffers), and those of the objects
    it holds, two levels down (a model's grid and metrics scratch)."""
    import taichi as ti

    itemsize = {ti.f32: 4, ti.f64: 8, ti.i32: 4, ti.i64: 8, ti.u32: 4, ti.u8: 1}
    seen = set() if seen is None else seen
    total = 0
    for value in vars(obj).values():
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if id(item) in seen:
                continue
            seen.add(id(item))
            if isinstance(item, ti.Ndarray):
                total += int(np.prod(item.shape)) * itemsize.get(item.dtype, 8)
            elif depth < 2 and hasattr(item, "__dict__") and not isinstance(item, type):
                total += device_bytes(item, seen, depth + 1)
    return total


def _timed(fn: Callable[[], None], sync: Callable[[], None]) -> float:
    t0 = time.perf_counter()
    fn()
    sync()
    return 1e3 * (time.perf_counter() - t0)


def _ckdtree_vicsek_step(x: np.ndarray, theta: np.ndarray, params: Any, rng: np.random.Generator):
    """One Vicsek step the way minimal scripts write it: cKDTree pairs within R as a sparse matrix, the mean of
    exp(i theta) over neighbours (itself included), uniform noise, move, wrap."""
    import scipy.sparse
    from scipy.spatial import cKDTree

    box = params.box if params.boundary == "periodic" else None
    tree = cKDTree(x, boxsize=box)
    dist = tree.sparse_distance_matrix(tree, max_distance=params.radius, output_type="coo_matrix")
    data = np.exp(1j * theta[dist.col])
    neigh = scipy.sparse.coo_matrix((data, (dist.row, dist.col)), shape=(len(x), len(x)))
    s = np.squeeze(np.asarray(neigh.tocsr().sum(axis=1)))  # the diagonal (distance 0) is itself
    theta = np.angle(s) + params.noise * (rng.random(len(x)) - 0.5)
    x = x + params.speed * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    if box is not None:
        x %= box
    return x, theta


def _time_numba_peer(state: dict[str, np.ndarray], params: Any, ms_tflock: float, mean_neighbors: float,
                     threads: int) -> dict[str, dict[str, float]]:
    """The parallel Numba cell-list step on tflock's state, in tflock's precision and thread count (periodic
    synchronous `vector` rule only; nothing without numba or where a step would take over ~10 s)."""
    if (params.boundary != "periodic" or params.rule != "vector" or params.async_bound != 1 or params.leader.enabled
            or params.max_turn_deg < 360):
        return {}
    try:
        import numba

        from tflock.peers.numba_vicsek import vicsek_step
    except ImportError:
        return {}
    n = len(state["theta"])
    expected_s = n * (NUMBA_S_PER_AGENT + NUMBA_S_PER_PAIR * max(1.0, mean_neighbors))
    if expected_s >= PEER_BUDGET_S:
        return {}
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS) if threads > 0
                          else numba.config.NUMBA_NUM_THREADS)
    args = (state["x"], state["theta"], params.box, params.radius, params.speed, params.noise)
    first_call_s = _median_ms(lambda: vicsek_step(*args), 1) / 1e3  # JIT compile, or load from numba's cache
    ms = _median_ms(lambda: vicsek_step(*args), 5, budget_ms=3e3)
    return {"numba_cells": {"ms": ms, "ratio": ms / ms_tflock, "first_call_s": first_call_s}}


def _median_ms(step: Callable[[], object], repeats: int, budget_ms: float = math.inf) -> float:
    """Median wall time of `step` in ms over up to `repeats` calls, stopping once `budget_ms` is spent."""
    times: list[float] = []
    while len(times) < repeats and sum(times) < budget_ms:
        t0 = time.perf_counter()
        step()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def _time_peers(model: Any, ms_tflock: float, mean_neighbors: float,
                threads: int = 0) -> dict[str, dict[str, float]]:
    """Peers on the model's current state: for Vicsek the NumPy reference, cKDTree and Numba steps; for the
    potential model its NumPy reference step (the other models' references come with them)."""
    if model.name == "potential":
        return _time_potential_reference(model, ms_tflock)
    if model.name != "vicsek":
        return {}
    from tflock import reference

    state = model.state()
    x, theta = state["x"].astype(np.float64), state["theta"].astype(np.float64)
    params, n = model.params, len(theta)
    peers: dict[str, dict[str, float]] = {}
    if n <= 4000:  # O(N^2) memory and time: ~1 s at 4000
        ms = _median_ms(lambda: reference.vicsek_step(x, theta, model.step_index, params, model.seed), 1)
        peers["numpy_reference"] = {"ms": ms, "ratio": ms / ms_tflock}
    expected_s = CKDTREE_S_PER_PAIR * n * max(1.0, mean_neighbors)
    if importlib.util.find_spec("scipy") is not None and expected_s < PEER_BUDGET_S:
        rng = np.random.default_rng(0)
        ms = _median_ms(lambda: _ckdtree_vicsek_step(x, theta, params, rng), 3 if expected_s < 1 else 1)
        peers["ckdtree_sparse"] = {"ms": ms, "ratio": ms / ms_tflock}
    peers.update(_time_numba_peer(state, params, ms_tflock, mean_neighbors, threads))
    return peers


def _time_potential_reference(model: Any, ms_tflock: float) -> dict[str, dict[str, float]]:
    """The plain NumPy step of the potential model (:func:`tflock.reference.potential.potential_step`, O(N^2),
    in the run's precision) on the model's state, where N <= 4000."""
    from tflock.reference.potential import graph_edges, potential_step

    if model.params.n > 4000:
        return {}
    state = model.state()
    edges = graph_edges(model.params, model.seed)
    ms = _median_ms(lambda: potential_step(state["x"], state["v"], model.params, edges), 5, budget_ms=3e3)
    return {"numpy_reference": {"ms": ms, "ratio": ms / ms_tflock}}


def _written(sim: Any) -> None:
    """Wait for the kernels and for Rerun's background threads to have written what was logged."""
    import taichi as ti

    ti.sync()
    if sim.recorder is not None:
        sim.recorder.flush()


@dataclass
class Turns:
    """What :func:`_plain_and_run_steps` measured (ms per step)."""

    plain: list[float]  # every plain step: the model's step alone (grid build included)
    run: float  # median over turns of a run's ms per step, as tflock sim runs it without a recording
    run_range: tuple[float, float]  # the fastest and slowest run (ms per step)
    run_overhead: float  # median over turns of (a run's ms per step / its turn's plain ms per step) - 1
    logged: float | None = None  # with --log: median over turns of a logged run's ms per step
    logged_range: tuple[float, float] | None = None  # with --log: the fastest and slowest logged run
    logging_overhead: float | None = None  # with --log: median over turns of (logged run / its turn's run) - 1


def start_run(model: Any, start: tuple[Any, int], metrics_every: int, frames: bool) -> None:
    """Put `model` in the state `start` (a checkpoint and its step) as a run leaves it at that step, before a
    timed run: its metrics taken where the cadence takes them (the Vicsek and `potential` metrics passes sum the next
    step's neighbours, which that step then skips) and, with `frames`, its neighbours built for the frame."""
    import taichi as ti

    model.restore(*start)
    if model.step_index % metrics_every == 0:
        model.metrics()
    if frames:
        model.build_neighbours()
    ti.sync()


def _plain_and_run_steps(sim: Any, repeats: int, metrics_every: int, log: bool) -> Turns:
    """Plain steps against runs of as many steps as ``tflock sim`` runs them: ``Simulation.step`` with metrics
    every `metrics_every` steps (the case's cadence, by default the model's) and the non-finite guard, and with
    `log` a frame every step (the frame, its edges, Rerun's encoding and writing).

    ``LOG_TURNS`` turns, each `repeats` plain steps, a run without frames and, with `log`, a logged run, all from
    the case's state (every turn times the same steps: the workload stays the state's). A run is timed whole, until
    Rerun's background threads have written its last frame (timing single logged steps between plain ones hides
    the background work of a frame, which then overlaps the next plain step). A run starts from the state as a run
    leaves it at the step before (:func:`start_run`, untimed). Overheads are medians over turns of a
    run against its own turn's plain steps (or a logged run against its turn's run), which cancels the drift of a
    shared machine between turns."""
    import taichi as ti

    model, log_config = sim.model, sim.config.log
    start = (model.checkpoint(), model.step_index)
    plain: list[float] = []
    runs, run_ratios, logged, log_ratios = [], [], [], []

    def timed_run(frames: bool) -> float:
        start_run(model, start, metrics_every, frames)
        log_config.every = 1 if frames else METRICS_NEVER
        log_config.metrics_every = metrics_every
        try:
            return _timed(lambda: sim.step(repeats), lambda: _written(sim)) / repeats
        finally:
            log_config.metrics_every = METRICS_NEVER

    for _ in range(LOG_TURNS):
        model.restore(*start)
        turn = [_timed(lambda: model.advance(1), ti.sync) for _ in range(repeats)]
        plain += turn
        runs.append(timed_run(frames=False))
        run_ratios.append(runs[-1] / statistics.fmean(turn))
        if log:
            logged.append(timed_run(frames=True))
            log_ratios.append(logged[-1] / runs[-1])
    turns = Turns(plain, statistics.median(runs), (min(runs), max(runs)), statistics.median(run_ratios) - 1.0)
    if log:
        turns.logged, turns.logged_range = statistics.median(logged), (min(logged), max(logged))
        turns.logging_overhead = statistics.median(log_ratios) - 1.0
    return turns


def run_case(case: BenchCase) -> BenchResult:
    """Measure one case in this process (the engine is initialised with the case's settings)."""
    import taichi as ti

    from tflock.config import load_config
    from tflock.simulation import Simulation

    metrics_every = case.metrics_every or load_config(model=case.model).log.metrics_every
    result = BenchResult(case=case)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        record = Path(tmp) / "bench.rrd" if case.log else False
        sim = Simulation(case_config(case), record=record)
        model = sim.model
        result.engine = sim.engine.describe()
        result.box = float(next(getattr(model.params, k) for k in LENGTHS if hasattr(model.params, k)))
        result.setup_s = time.perf_counter() - t0
        result.first_step_s = _timed(lambda: model.advance(1), ti.sync) / 1e3
        if case.state == "developed":
            model.advance(case.develop_steps)
            ti.sync()  # a GPU runs launches asynchronously: the first timed step must not wait for these
        turns = _plain_and_run_steps(sim, case.repeats, metrics_every, case.log)
        steps = turns.plain
        result.run_ms_median, result.run_overhead = turns.run, turns.run_overhead
        result.run_ms_min, result.run_ms_max = turns.run_range
        result.logged_ms_median, result.logging_overhead = turns.logged, turns.logging_overhead
        if turns.logged_range is not None:
            result.logged_ms_min, result.logged_ms_max = turns.logged_range
        result.ms_median = statistics.median(steps)
        result.ms_min, result.ms_max = min(steps), max(steps)
        result.agent_steps_per_s = case.n / (result.ms_median / 1e3)
        if hasattr(model, "build_neighbours"):
            builds = [_timed(model.build_neighbours, ti.sync) for _ in range(max(3, case.repeats // 2))]
            result.build_ms = statistics.median(builds)
            result.interactions_ms = max(0.0, result.ms_median - result.build_ms)
        metrics: dict[str, float] = {}

        def measure() -> None:
            metrics.update(model.metrics())

        result.metrics_ms = _timed(measure, ti.sync)
        result.mean_neighbors = _mean_neighbours(model, metrics, result.box)
        if case.log:
            result.logging_ms = _timed(lambda: (sim._guard(), sim._observe()), lambda: _written(sim))
        result.device_bytes_per_agent = device_bytes(model) / case.n
        if case.peers:
            result.peers = _time_peers(model, result.ms_median, result.mean_neighbors, sim.engine.threads)
        sim.close()
    result.peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return result


def _mean_neighbours(model: Any, metrics: dict[str, float], box: float) -> float:
    """The workload: the model's own mean neighbour count where its metrics have one, else the mean number of
    agents within its interaction radius, counted on its grid of side `box` (formation: the vision radius)."""
    for key in ("mean_neighbors", "valency_mean"):
        if key in metrics:
            return float(metrics[key])
    from tflock.metrics import NeighbourGraph

    model.build_neighbours()
    return NeighbourGraph(model.grid).compute(model.params.radius, box)["mean_neighbors"]


class CaseEngineError(RuntimeError):
    """A case's engine did not start (its arch, precision or TFLOCK_LANES): every case would fail alike."""


#: the exit code of a case's process whose engine did not start (the engine's message: its last line on stderr)
ENGINE_EXIT = 3


def run_in_subprocess(case: BenchCase, timeout_s: float = 3600) -> BenchResult:
    """Run a case in a fresh Python process (its own engine settings and memory). Raises CaseEngineError (the
    engine's one-line message) where its engine did not start, RuntimeError where the case failed otherwise."""
    proc = subprocess.run([sys.executable, "-m", "tflock.bench", json.dumps(asdict(case))], capture_output=True,
                          text=True, timeout=timeout_s)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        if proc.returncode == ENGINE_EXIT:
            raise CaseEngineError(tail)
        raise RuntimeError(f"bench case {case.model} n={case.n} {case.state} failed: {tail}")
    data = json.loads(proc.stdout.strip().splitlines()[-1])
    data["case"] = case
    return BenchResult(**data)


def machine() -> dict[str, Any]:
    """Where the numbers come from: the CPU (its family and model tell hosts with the same model name apart, and
    whether it has AVX-512 decides the lanes of the CPU kernels), cores, memory, versions, GPUs."""
    import taichi as ti

    from tflock.engine import cpu_identity

    cpu = cpu_identity()
    info = {"cpu": cpu.get("model name") or platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "memory_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
            "python": platform.python_version(), "numpy": np.__version__,
            "taichi": ".".join(map(str, ti.__version__)), "platform": platform.platform()}
    if cpu:
        flags = cpu.get("flags", "").split()
        info["cpu_id"] = " ".join(f"{k} {cpu.get(k, '?')}" for k in ("vendor_id", "cpu family", "model"))
        info["vector"] = "avx512f" if "avx512f" in flags else ("avx2" if "avx2" in flags else "other")
    gpus = _nvidia_gpus()
    if gpus:
        info["gpu"] = gpus
    return info


def _nvidia_gpus() -> list[str]:
    """'name, driver, memory' of each NVIDIA GPU that nvidia-smi lists; empty without one."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.strip() for line in out.stdout.splitlines() if line.strip()] if out.returncode == 0 else []


def cases(models: Iterable[str], sizes: Iterable[int], states: Iterable[str], **common: Any) -> list[BenchCase]:
    """The cross product, smallest N first."""
    return [BenchCase(model=m, n=n, state=s, **common) for n in sorted(sizes) for m in models for s in states]


def default_out(now: float | None = None) -> Path:
    """``results/bench/bench-<date-time>`` in the working directory, beside ``tflock reproduce``'s ``results/NAME``:
    a user's runs never mix with the reference results committed under ``benchmarks/`` (written with ``--out``)."""
    return Path("results") / "bench" / f"bench-{time.strftime('%Y%m%d-%H%M%S', time.localtime(now))}"


def write_results(results: list[BenchResult], out: Path, command: str,
                  skipped: Sequence[tuple[BenchCase, str]] = ()) -> list[Path]:
    """JSON (with the machine, the command and each case that failed, with its error), CSV, and a log-log PNG
    when matplotlib is installed."""
    import csv

    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"command": command, "machine": machine(), "date": time.strftime("%Y-%m-%d"),
               "results": [{**asdict(r), "case": asdict(r.case)} for r in results],
               "skipped": [{"case": asdict(case), "error": error} for case, error in skipped]}
    json_path = out.with_suffix(".json")
    json_path.write_text(json.dumps(payload, indent=1) + "\n")
    rows = [r.row() for r in results]
    columns = list(dict.fromkeys(k for row in rows for k in row))
    csv_path = out.with_suffix(".csv")
    with open(csv_path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    written = [json_path, csv_path]
    png = plot(results, out.with_suffix(".png"))
    if png is not None:
        written.append(png)
    return written


def engine_labels(results: list[BenchResult]) -> dict[str, str]:
    """Each result's engine line (``cpu, 2 threads, f32, 8 lanes``) shortened to the parts in which the results'
    engines differ (``2 threads``), to tell apart the rows and lines of a run over several (``--threads 1,2``);
    empty where all ran on one engine."""
    engines = sorted({r.engine for r in results})
    if len(engines) < 2:
        return {}
    parts = [engine.split(", ") for engine in engines]
    differ = [k for k in range(max(map(len, parts))) if len({p[k] if k < len(p) else "" for p in parts}) > 1]
    return {engine: ", ".join(p[k] for k in differ if k < len(p)) for engine, p in zip(engines, parts, strict=True)}


def plot(results: list[BenchResult], path: Path) -> Path | None:
    """agent-steps/s and ms/step against N, log-log, one line per (model, state; engine where several ran: see
    :func:`engine_labels`), with a run's ms/step (and a logged run's) beside the step's and the peers'; None without
    matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 6))
    labels = engine_labels(results)
    groups: dict[tuple[str, str, bool, str], list[BenchResult]] = {}
    for r in results:  # one line per engine too where several ran (e.g. --threads 1,2)
        groups.setdefault((r.case.model, r.case.state, r.case.log, r.engine), []).append(r)
    styles = {"numpy_reference": ":", "ckdtree_sparse": "--", "numba_cells": "-."}
    for index, ((model, state, log, engine), rs) in enumerate(groups.items()):
        color = f"C{index % 10}"
        rs.sort(key=lambda r: r.case.n)
        n = [r.case.n for r in rs]
        nb = ", ".join(f"{r.mean_neighbors:.0f}" for r in rs)
        series = f"{model} {state}" + (f" [{labels[engine]}]" if labels else "")
        label = f"{series}{' +log' if log else ''}: step (neighbours {nb})"
        left.loglog(n, [r.agent_steps_per_s for r in rs], "o-", color=color, label=label)
        right.loglog(n, [r.ms_median for r in rs], "o-", color=color, label=label)
        right.loglog(n, [r.run_ms_median for r in rs], "s", linestyle=(0, (6, 2)), color=color,
                     label=f"{series}: run (metrics, guard)")
        logged = [r for r in rs if r.logged_ms_median is not None]
        if logged:
            right.loglog([r.case.n for r in logged], [r.logged_ms_median for r in logged], "^", linestyle=(0, (2, 2)),
                         color=color, label=f"{series}: logged run")
        for name in sorted({p for r in rs for p in r.peers}):
            with_peer = [r for r in rs if name in r.peers]
            right.loglog([r.case.n for r in with_peer], [r.peers[name]["ms"] for r in with_peer], "x",
                         linestyle=styles.get(name, "-."), color=color, label=f"{series}: {name}")
    left.set(xlabel="N agents", ylabel="agent-steps / s", title="throughput")
    right.set(xlabel="N agents", ylabel="ms / step (median)", title="step time, and a run's")
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
    for ax in (left, right):  # below the axes: the right one's entries would cover its lines
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    engine = results[0].engine if results and not labels else "engines in the legend"
    overrides = sorted({o for r in results for o in r.case.overrides})
    config = f"default config with {', '.join(overrides)}" if overrides else "default config"
    fig.suptitle(f"tflock bench ({engine}; workload: {config}, density kept; neighbours per agent in the legend)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _worker(argv: list[str]) -> None:
    from tflock.engine import EngineError

    fields = json.loads(argv[0])
    case = BenchCase(**{**fields, "overrides": tuple(fields.get("overrides", ()))})
    try:
        result = run_case(case)
    except EngineError as error:  # the same for every case: the caller stops the bench with this line
        print(error, file=sys.stderr)
        sys.exit(ENGINE_EXIT)
    print(json.dumps({**asdict(result), "case": asdict(case)}))


if __name__ == "__main__":
    _worker(sys.argv[1:])
