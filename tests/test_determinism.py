"""Same config and seed: bit-identical trajectories whatever the thread count (counter-based RNG, cell slices
sorted by agent id, block-wise reductions). Thread counts are process-wide, so each run is a subprocess."""

import subprocess
import sys

import numpy as np
import pytest

SCRIPT = """
import sys, numpy as np
from tflock import Simulation
sim = Simulation(params={"n": 4000, "box": 40.0, "radius": 1.0, "speed": 0.5, "noise": 0.5,
                         "boundary": sys.argv[2], "rule": "vector"},
                 engine={"threads": int(sys.argv[1]), "precision": "f32"}, steps=60, seed=11)
sim.run()
s = sim.state()
m = sim.metrics()
np.savez(sys.argv[3], x=s["x"], theta=s["theta"], **{k: v for k, v in m.items()})
"""


@pytest.mark.parametrize("boundary", ["periodic", "open"])
def test_one_and_two_threads_give_identical_runs(tmp_path, boundary):
    runs = []
    for threads in (1, 2):
        out = tmp_path / f"run{threads}.npz"
        subprocess.run([sys.executable, "-c", SCRIPT, str(threads), boundary, str(out)], check=True, timeout=300)
        runs.append(np.load(out))
    one, two = runs
    assert one["theta"].dtype == np.float32
    for key in one.files:
        assert np.array_equal(one[key], two[key]), key
