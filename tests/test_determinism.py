"""Same config and seed: bit-identical trajectories and metrics whatever the thread count, for every model
(counter-based RNG, cell slices sorted by agent id, block-wise reductions). Thread counts are process-wide, so
each run is a subprocess."""

import json
import subprocess
import sys

import numpy as np
import pytest

SCRIPT = """
import json, sys, numpy as np
from tflock import Simulation
model, params = json.loads(sys.argv[2])
sim = Simulation(model=model, params=params, engine={"threads": int(sys.argv[1]), "precision": "f32"}, steps=60,
                 seed=11)
sim.run()
s = sim.state()
m = sim.metrics()
arrays = {f"state_{k}": v for k, v in s.items() if isinstance(v, np.ndarray)}
np.savez(sys.argv[3], **arrays, **{f"metric_{k}": v for k, v in m.items()})
"""


VICSEK = {"n": 4000, "box": 40.0, "radius": 1.0, "speed": 0.5, "noise": 0.5, "rule": "vector"}


@pytest.mark.parametrize("model,params", [
    ("vicsek", {**VICSEK, "boundary": "periodic"}),
    ("vicsek", {**VICSEK, "boundary": "open", "async_bound": 4}),
    ("potential", {"n": 3000, "box": 90.0}),
    ("adaptive", {"n": 3000, "box": 16.0, "noise": 0.3, "dim": 3}),
    ("formation", {"n": 3000, "world": 400.0, "init_length": 150.0, "init_width": 150.0, "fail_prob": 0.2,
                   "noise_deg": 1.0}),
])
def test_one_and_two_threads_give_identical_runs(tmp_path, model, params):
    runs = []
    for threads in (1, 2):
        out = tmp_path / f"run{threads}.npz"
        subprocess.run([sys.executable, "-c", SCRIPT, str(threads), json.dumps([model, params]), str(out)],
                       check=True, timeout=300)
        runs.append(np.load(out))
    one, two = runs
    assert one["state_x"].dtype == np.float32 and len(one.files) > 5
    for key in one.files:
        assert np.array_equal(one[key], two[key], equal_nan=True), key
