"""The engine's choice of lanes for the CPU kernels, from the CPU's identity or TFLOCK_LANES (the trajectories do
not depend on it: test_determinism runs both)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ARCH, PRECISION

from tflock.engine import EngineError, EngineInfo, cpu_identity, host_lanes, init_engine, lanes_for

ZEN5_FLAGS = "fpu sse2 avx avx2 fma avx512f avx512dq avx512bw avx512vl"


def test_cpu_identity_reads_the_first_processor(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
                    "model name\t: AMD EPYC\nflags\t\t: fpu avx2 avx512f\n\n"
                    "processor\t: 1\nvendor_id\t: GenuineIntel\ncpu family\t: 6\n")
    assert cpu_identity(str(info)) == {"vendor_id": "AuthenticAMD", "cpu family": "26", "model": "2",
                                       "model name": "AMD EPYC", "flags": "fpu avx2 avx512f"}
    assert cpu_identity(str(tmp_path / "missing")) == {}


@pytest.mark.parametrize("cpu,lanes", [
    ({"vendor_id": "AuthenticAMD", "cpu family": "26", "flags": ZEN5_FLAGS}, 16),  # Zen 5: full-width AVX-512
    ({"vendor_id": "AuthenticAMD", "cpu family": "26", "flags": "fpu avx2 fma"}, 8),  # no AVX-512 exposed
    ({"vendor_id": "AuthenticAMD", "cpu family": "25", "flags": ZEN5_FLAGS}, 8),  # Zen 4: 512-bit split in two
    ({"vendor_id": "AuthenticAMD", "cpu family": "23", "flags": "fpu avx2 fma"}, 8),  # Zen 2
    ({"vendor_id": "GenuineIntel", "cpu family": "6", "flags": ZEN5_FLAGS}, 8),  # not measured: the safe width
    ({}, 8),  # no /proc/cpuinfo (macOS, Windows) or not x86
])
def test_lanes_for_the_cpu(cpu: dict[str, str], lanes: int) -> None:
    assert lanes_for(cpu) == lanes


@pytest.mark.parametrize("value,lanes", [("8", 8), (" 16 ", 16), ("12", None), ("", None)])
def test_tflock_lanes_chooses(monkeypatch: pytest.MonkeyPatch, value: str, lanes: int | None) -> None:
    monkeypatch.setenv("TFLOCK_LANES", value)
    host_lanes.cache_clear()
    try:
        assert host_lanes() == (lanes or lanes_for(cpu_identity()))
    finally:
        host_lanes.cache_clear()


def test_describe_names_the_lanes_on_the_cpu_only() -> None:
    assert EngineInfo("cpu", "auto", 2, "f32", 16).describe() == "cpu, 2 threads, f32, 16 lanes"
    assert EngineInfo("cpu", "auto", 1, "f32", 16).describe() == "cpu, 1 thread, f32, 16 lanes"
    assert EngineInfo("cuda", "cuda", 0, "f64", 8).describe() == "cuda, f64"


def test_init_engine_refuses_a_bad_lanes_value_only(monkeypatch: pytest.MonkeyPatch, engine: EngineInfo) -> None:
    """An empty TFLOCK_LANES means unset, as host_lanes reads it; anything but 8 or 16 is an engine error."""
    monkeypatch.setenv("TFLOCK_LANES", " ")
    assert init_engine(ARCH, 0, PRECISION) is engine
    monkeypatch.setenv("TFLOCK_LANES", "12")
    with pytest.raises(EngineError, match="TFLOCK_LANES: must be 8 or 16"):
        init_engine(ARCH, 0, PRECISION)


@pytest.mark.parametrize("setting,expected", [(None, False), ("1", True), ("0", False)])
def test_cpu_compiles_without_taichis_cfg_passes_unless_told(setting: str | None, expected: bool) -> None:
    """On the CPU tflock turns Taichi's control-flow-graph passes off (LLVM repeats them; compiles take several times
    less); TI_CFG_OPTIMIZATION, where set, decides."""
    env = {k: v for k, v in os.environ.items() if k != "TI_CFG_OPTIMIZATION"}
    if setting is not None:
        env["TI_CFG_OPTIMIZATION"] = setting
    script = ("from tflock.engine import init_engine; init_engine('cpu', 1, 'f32'); import taichi as ti; "
              "print(ti.lang.impl.current_cfg().cfg_optimization)")
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == str(expected)
