"""Same config and seed: bit-identical trajectories and metrics whatever the thread count, for every model
(counter-based RNG, cell slices sorted by agent id, block-wise reductions). Thread counts are process-wide, so
each run is a subprocess."""

import json
import os
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
    ("vicsek", {**VICSEK, "boundary": "reflecting", "neighbours": "topological", "noise_type": "vectorial"}),
    ("vicsek", {**VICSEK, "box": 11.7, "dim": 3, "noise_type": "vectorial"}),
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


LANES_SCRIPT = """
import json, sys, numpy as np
from tflock import Simulation
from tflock.neighbors import LANES
arrays = {"lanes": np.array(LANES)}
for k, (model, params) in enumerate(json.loads(sys.argv[1])):
    sim = Simulation(model=model, params=params, engine={"precision": "f32"}, steps=40, seed=5)
    sim.run()
    arrays.update({f"{k}_{name}": v for name, v in sim.state().items() if isinstance(v, np.ndarray)})
np.savez(sys.argv[2], **arrays)
"""

#: workloads of every lane-wise CPU kernel: Vicsek's sums and update (periodic and reflecting), potential's step in
#: 2D and 3D, formation's scan with cells of side R and with large sparse cells
LANE_WORKLOADS = [
    ("vicsek", {**VICSEK, "boundary": "periodic"}),
    ("vicsek", {**VICSEK, "boundary": "reflecting", "rule": "average", "leader": {"enabled": True}}),
    ("potential", {"n": 3000, "box": 60.0}),
    ("potential", {"n": 3000, "box": 19.0, "dim": 3}),
    ("formation", {"n": 3000, "world": 400.0, "init_length": 120.0, "init_width": 60.0}),
    ("formation", {"n": 3000, "world": 6000.0, "init_length": 1000.0, "init_width": 1000.0}),
]


def test_8_and_16_lanes_give_identical_runs(tmp_path):
    """The lanes of the CPU kernels (tflock.engine.host_lanes) change the speed, never the trajectory: a block's
    wider window only adds candidates beyond R."""
    runs = []
    for lanes in ("8", "16"):
        out = tmp_path / f"lanes{lanes}.npz"
        # a hang guard: with a cold kernel cache each run compiles every kernel at its width (minutes, the
        # suite's other worker beside it)
        subprocess.run([sys.executable, "-c", LANES_SCRIPT, json.dumps(LANE_WORKLOADS), str(out)], check=True,
                       timeout=1500, env={**os.environ, "TFLOCK_LANES": lanes})
        runs.append(np.load(out))
    eight, sixteen = runs
    assert int(eight["lanes"]) == 8 and int(sixteen["lanes"]) == 16
    assert len(eight.files) > 3 * len(LANE_WORKLOADS)
    for key in eight.files:
        if key != "lanes":
            assert np.array_equal(eight[key], sixteen[key], equal_nan=True), key
