"""One Taichi initialisation per process: arch, CPU threads and floating-point precision.

Taichi cannot be re-initialised safely once fields or ndarrays exist (taichi-dev/taichi#4468), so every
simulation in a process shares the settings of the first :func:`init_engine` call. A later call with other
settings raises :class:`EngineError`; run such work in a new process (``python -m tflock ...``).
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import tempfile
import warnings
from dataclasses import dataclass

import numpy as np

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # before the import: no banner on stdout

import taichi as ti  # noqa: E402

from tflock.advice import TflockWarning  # noqa: E402
from tflock.taichi_frontend import fast_class_check, memoize_position_messages  # noqa: E402
from tflock.taichi_host import copy_on_host  # noqa: E402
from tflock.taichi_launch import fast_launches  # noqa: E402

fast_class_check()
memoize_position_messages()
copy_on_host()
fast_launches()

ARCHES = ("cpu", "cuda", "vulkan", "auto")
#: Taichi's on-disk kernel cache (~/.cache/taichi) may hold this much before it drops the least recently used
#: quarter: its own limit, 100 MiB, fills with tflock's kernels (two precisions, two lane widths, every model's
#: variants), after which runs compile again (seconds to minutes) what a larger cache keeps
KERNEL_CACHE_BYTES = 1 << 30
PRECISIONS = ("f32", "f64")
LANE_COUNTS = ("8", "16")
#: Taichi's front-end passes over the control-flow graph (store-to-load forwarding, dead-store elimination) take
#: most of the time of compiling tflock's lane-wise kernels; on the CPU, LLVM's own passes do that work again, so
#: without them the kernels compile several times faster and run as fast (docs/performance.md, "Start-up"). Off on
#: the CPU unless TI_CFG_OPTIMIZATION is set; GPU arches keep Taichi's default (not measured there).
CPU_CFG_OPTIMIZATION = False
#: where Taichi is pointed when its kernel cache folder cannot be written (see :func:`kernel_cache_folder`): it stays
#: empty, the cache being off
NO_CACHE_FOLDER = os.path.join(tempfile.gettempdir(), "tflock-no-kernel-cache")


class EngineError(RuntimeError):
    """The requested engine settings cannot be honoured in this process."""


@dataclass(frozen=True)
class EngineInfo:
    """Settings Taichi runs with in this process."""

    arch: str          # the arch actually in use: cpu, cuda or vulkan
    requested_arch: str
    threads: int       # CPU threads (0 for GPU arches)
    precision: str     # f32 or f64
    lanes: int = 8     # agents the lane-wise CPU kernels take at once (:func:`host_lanes`)

    def describe(self) -> str:
        """One line for summaries and benchmark tables, e.g. ``cpu, 2 threads, f32, 16 lanes``."""
        if self.arch != "cpu":
            return f"{self.arch}, {self.precision}"
        threads = f"{self.threads} thread" + ("s" if self.threads != 1 else "")
        return f"{self.arch}, {threads}, {self.precision}, {self.lanes} lanes"

    @property
    def real(self) -> type:
        """NumPy dtype of floating-point state arrays."""
        return np.float32 if self.precision == "f32" else np.float64


_current: EngineInfo | None = None


def cpu_identity(path: str = "/proc/cpuinfo") -> dict[str, str]:
    """The first CPU's ``vendor_id``, ``cpu family``, ``model``, ``model name`` and ``flags`` from /proc/cpuinfo
    (empty where there is none: not Linux, or not x86)."""
    fields = {}
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for line in f:
                if not line.strip():
                    break  # the first processor's block only
                key, _, value = line.partition(":")
                fields[key.strip()] = value.strip()
    except OSError:
        return {}
    return {k: fields[k] for k in ("vendor_id", "cpu family", "model", "model name", "flags") if k in fields}


def lanes_for(cpu: dict[str, str]) -> int:
    """16 lanes on AMD's family 1Ah (Zen 5) with AVX-512, whose 512-bit operations run at full width; 8 (one AVX2
    register of float32) elsewhere. `cpu` as :func:`cpu_identity` gives it.

    A block of 16 agents visits fewer candidates per agent than two blocks of 8, for the same instructions a
    candidate where 512-bit operations run at full width; the 3D `potential` step gains most (docs/performance.md).
    CPUs that split 512-bit operations in two (AMD's Zen 4) or have fewer 512-bit ports (Intel's client cores) would
    pay twice a candidate for that; they keep 8 (TFLOCK_LANES=16 tries it)."""
    family = cpu.get("cpu family", "")
    wide = (cpu.get("vendor_id") == "AuthenticAMD" and family.isdigit() and int(family) >= 0x1A
            and "avx512f" in cpu.get("flags", "").split())
    return 16 if wide else 8


@functools.cache
def host_lanes() -> int:
    """Agents (float32 lanes) the lane-wise CPU kernels take at once, :data:`tflock.neighbors.LANES`, once per
    process: TFLOCK_LANES when it says 8 or 16, else :func:`lanes_for` this CPU. The trajectory is the same bit for
    bit either way (a block's wider window only adds candidates beyond R, which add nothing); only the speed
    differs."""
    chosen = _lanes_chosen()
    return int(chosen) if chosen in LANE_COUNTS else lanes_for(cpu_identity())


def _lanes_chosen() -> str:
    """TFLOCK_LANES as set, stripped ("" when unset or empty: chosen for this CPU)."""
    return os.environ.get("TFLOCK_LANES", "").strip()


def _arch_name(arch: object) -> str:
    name = str(arch).rsplit(".", 1)[-1]
    return "cpu" if name in ("x64", "arm64") else name


def kernel_cache_folder() -> tuple[str, bool]:
    """Taichi's kernel cache folder (``TI_OFFLINE_CACHE_FILE_PATH``, else its default under ``~/.cache/taichi``),
    made where missing, and whether it can be written. Taichi 1.7 makes that folder when its program is finalized,
    at exit, even with the cache off, and crashes there (SIGSEGV) when it cannot: :func:`init_engine` then turns the
    cache off and points Taichi at :data:`NO_CACHE_FOLDER`."""
    path = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or ti._lib.core.CompileConfig().offline_cache_file_path
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return path, False
    return path, os.access(path, os.W_OK)


def init_engine(arch: str = "cpu", threads: int = 0, precision: str = "f32") -> EngineInfo:
    """Initialise Taichi once; later calls must ask for the same settings (or are no-ops when they do).

    ``threads = 0`` uses every core. ``arch = "auto"`` takes CUDA, then Vulkan (f32 only), then the CPU. Asking
    for a GPU arch that this machine lacks is an error, not a silent fallback.
    """
    global _current
    lanes = _lanes_chosen()
    if lanes and lanes not in LANE_COUNTS:
        raise EngineError(f"TFLOCK_LANES: must be 8 or 16 (or unset: chosen for this CPU), got {lanes!r}")
    if arch not in ARCHES:
        raise EngineError(f"engine.arch: must be one of {', '.join(ARCHES)}, got {arch!r}")
    if precision not in PRECISIONS:
        raise EngineError(f"engine.precision: must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if arch == "vulkan" and precision == "f64":
        raise EngineError("engine.precision: f64 is not available on vulkan (Taichi's Vulkan shaders have no 64-bit "
                          "sin, cos, atan2 or pow); use f32 there, or cpu / cuda for f64")
    n_threads = threads if threads > 0 else (os.cpu_count() or 1)
    if _current is not None:
        same = _current.requested_arch == arch and _current.precision == precision
        if same and (_current.arch != "cpu" or _current.threads == n_threads):
            return _current
        raise EngineError(
            f"engine: Taichi already runs here with arch={_current.arch}, threads={_current.threads}, "
            f"precision={_current.precision}; other settings need a new process"
        )
    fp = ti.f32 if precision == "f32" else ti.f64
    # a GPU arch that is missing logs fallback warnings; our own one-line error replaces them
    quiet = ti.WARN if arch == "cpu" else ti.ERROR
    common = dict(default_fp=fp, default_ip=ti.i32, cpu_max_num_threads=n_threads, log_level=quiet,
                  offline_cache_max_size_of_files=KERNEL_CACHE_BYTES)
    if arch == "cpu" and not os.environ.get("TI_CFG_OPTIMIZATION"):
        common["cfg_optimization"] = CPU_CFG_OPTIMIZATION
    folder, writable = kernel_cache_folder()
    if not writable:
        common.update(offline_cache=False, offline_cache_file_path=NO_CACHE_FOLDER)
        warnings.warn(f"Taichi's kernel cache folder {folder} cannot be written: kernels are compiled again in "
                      f"every run (set TI_OFFLINE_CACHE_FILE_PATH to a folder that can be written)", TflockWarning,
                      stacklevel=2)
    arches = {"cpu": ti.cpu, "auto": [ti.cuda, ti.vulkan, ti.cpu] if precision == "f32" else [ti.cuda, ti.cpu]}
    named = os.environ.pop("TI_OFFLINE_CACHE_FILE_PATH", None) if not writable else None  # else Taichi warns
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # ti.init prints "[Taichi] Starting on arch=..."
            ti.init(arch=arches.get(arch) or getattr(ti, arch), **common)
    finally:
        if named is not None:
            os.environ["TI_OFFLINE_CACHE_FILE_PATH"] = named
    if arch not in arches:
        used = _arch_name(ti.lang.impl.current_cfg().arch)
        if used != arch:
            ti.reset()
            raise EngineError(f"engine.arch: {arch} is not available on this machine; allowed here: cpu, auto")
    used = _arch_name(ti.lang.impl.current_cfg().arch)
    ti.set_logging_level(ti.WARN)
    _current = EngineInfo(arch=used, requested_arch=arch, threads=n_threads if used == "cpu" else 0,
                          precision=precision, lanes=host_lanes())
    return _current


def current_engine() -> EngineInfo | None:
    """The settings of this process's Taichi, or None before :func:`init_engine`."""
    return _current
