"""The oracle tests again at f32, in a subprocess (precision is fixed per process by ti.init).

At f32 only one-step comparisons from a shared state run (tolerance 2e-4); free-running trajectories are
compared at f64 only, since an f32 kernel and any oracle drift apart chaotically after some tens of steps.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.skipif(os.environ.get("TFLOCK_TEST_PRECISION") == "f32", reason="already the f32 run")
def test_oracle_tests_pass_at_f32():
    tests = Path(__file__).parent
    env = {**os.environ, "TFLOCK_TEST_PRECISION": "f32"}
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             str(tests / "test_oracle.py"), str(tests / "test_rng.py"),
                             str(tests / "test_formation.py"), str(tests / "test_potential.py"),
                             str(tests / "test_adaptive.py"), str(tests / "test_ensemble.py"),
                             str(tests / "test_topological_lanes.py")],
                            env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert " passed" in result.stdout
