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
