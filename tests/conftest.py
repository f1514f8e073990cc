"""Shared test setup: one Taichi initialisation per test process.

In-process tests run at the precision named by TFLOCK_TEST_PRECISION (f64 by default, so oracle comparisons can
run long horizons); `test_precision.py` reruns the oracle tests in a subprocess at f32. Anything that needs other
engine settings (thread counts, the CLI) runs in a subprocess.
"""

import os

import pytest

PRECISION = os.environ.get("TFLOCK_TEST_PRECISION", "f64")


@pytest.fixture(scope="session")
def engine():
    from tflock.engine import init_engine

    return init_engine("cpu", 0, PRECISION)


@pytest.fixture
def make_sim(engine):
    """Simulation factory at the session's precision, recording off unless asked."""
    from tflock import Simulation

    def make(**kwargs):
        kwargs.setdefault("engine", {})["precision"] = PRECISION
        return Simulation(**kwargs)

    return make


@pytest.fixture(scope="session")
def reproduce_quick():
    """``run(name, out)``: ``tflock reproduce NAME --quick --out OUT`` in a subprocess (reproductions run at the
    default f32 engine; this process's Taichi is f64), failing the test with its stderr unless it exits 0."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")])}

    def run(name: str, out: Path) -> Path:
        done = subprocess.run([sys.executable, "-m", "tflock", "reproduce", name, "--quick", "--out", str(out)],
                              capture_output=True, text=True, env=env, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        return out

    return run
