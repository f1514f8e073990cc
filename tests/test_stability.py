"""The integrator-stability guard (tflock/stability.py): the potential model's Lyapunov function W or Q never rises
above its value at step 0 in a legitimate run (papers/001 eqs. 8 and 12), so a run where it rises by more than the
energy the system started with, or where two agents move apart by more than the desired distance in one step, stops
like a non-finite one: one line, exit 2, the recording up to the last good step and a checkpoint of it."""

from pathlib import Path
from typing import Any

import pytest
from conftest import PRECISION, assert_one_error_line, invoke_in

from tflock import stability
from tflock.record import read_recording, verify_recording
from tflock.simulation import NumericalFaultError, read_checkpoint

ENGINE = ["--set", f"engine.precision={PRECISION}"]


def test_an_absurd_time_step_stops_at_step_1_with_the_start_saved(cpu_engine: Any, tmp_path: Path) -> None:
    args = ["sim", "--model", "potential", "--set", "params.n=200", "--set", "params.box=12.0", "--set",
            "params.dt=1e6", *ENGINE, "--out", "p.rrd"]
    line = assert_one_error_line(invoke_in(tmp_path, args))
    assert line.startswith("error: numerical fault in potential at step 1: the integration is unstable: two agents "
                           "move "), line
    assert "more than the desired distance 1 over which the potential changes; lower params.dt (= 1e+06)" in line
    assert "nothing after step 0 is recorded" in line and "the last good state (step 0) is saved in p.lastgood.npz" \
        in line
    assert verify_recording(tmp_path / "p.rrd") and read_recording(tmp_path / "p.rrd").steps == [0]
    assert int(read_checkpoint(tmp_path / "p.lastgood.npz")["step"]) == 0
    again = assert_one_error_line(invoke_in(tmp_path, ["sim", "--resume", "p.lastgood.npz", "--no-log"]))
    assert "at step 1: the integration is unstable" in again  # deterministic: the same fault, resumed


def test_runs_without_outputs_save_their_last_good_states_under_names_of_their_own(
        make_sim: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two runs with no recording nor checkpoint path that fault in the same second (same default name) each keep
    their last good state: the second takes the next free name, and no lock or temporary file stays."""
    import tflock.simulation

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tflock.simulation, "default_recording_path", lambda model: Path("recordings") / "p.rrd")
    faults = []
    for seed in (1, 2):
        with pytest.raises(NumericalFaultError) as fault:
            make_sim(model="potential", params={"n": 20, "box": 5.0, "dt": 1e6}, steps=3, seed=seed).run()
        faults.append(fault.value.checkpoint)
    assert faults == [Path("recordings/p.lastgood.npz"), Path("recordings/p.lastgood-2.npz")]
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == ["p.lastgood-2.npz", "p.lastgood.npz"]
    seeds = [str(read_checkpoint(tmp_path / path, arrays=False)["config_toml"]).split("seed = ")[1].split()[0]
             for path in faults]
    assert seeds == ["1", "2"]


@pytest.mark.parametrize(("params", "name"), [
    ({"n": 10, "box": 5.0}, "Q"),  # configs/papers/tanner-switching.toml
    ({"n": 10, "box": 5.0, "topology": "fixed", "graph": "random"}, "W"),  # configs/papers/tanner-fixed.toml
    ({"n": 60, "box": 8.0, "topology": "fixed", "graph": "tree"}, "W"),
])
def test_legitimate_runs_never_rise_above_the_start(make_sim: Any, params: dict[str, Any], name: str) -> None:
    """Theorems 1 and 2 (eqs. 8, 12): W and Q do not increase; in these runs every value stays at or below the
    start, so the guard (which allows a rise of the whole start energy) is far from firing."""
    run = make_sim(model="potential", params=params, steps=600, seed=3)
    run.run()
    table = run.metrics()
    values = table[name]
    start = table["kinetic_energy"][0] + abs(table["potential_energy"][0])
    assert values.max() <= values[0] + 1e-9 * start, (values.max(), values[0])
    assert values[-1] < values[0]  # the alignment term dissipated energy
    moved, desired = run.model.step_spread()
    assert moved < 0.1 * desired


def test_each_test_fires_on_its_own(make_sim: Any) -> None:
    """Velocities 30 times larger hold 900 times the kinetic energy (the Lyapunov test) but move two agents at most
    0.6 d apart in a step (speeds < 1, dt = 0.01); 100 times larger also fail the displacement test."""
    run = make_sim(model="potential", params={"n": 50, "box": 5.0}, steps=0)
    start = run.model.lyapunov()
    state = run.model.state()
    assert stability.cheap_test(run.model) is None and stability.lyapunov_test(start, run.model) is None
    for factor, cheap in ((30.0, False), (100.0, True)):
        run.model.set_state({"x": state["x"], "v": state["v"] * factor}, 0)  # speeds < 1: spreads < 2
        assert stability.lyapunov_test(start, run.model).startswith(
            "the integration is unstable: the Lyapunov function Q rose from")
        assert (stability.cheap_test(run.model) is not None) == cheap


def test_the_replay_finds_the_first_unstable_step(make_sim: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """The guard checks at metrics steps (every 7 here); the replay from the last good copy names the first step
    that fails (a displacement that grows with the step: it fails from step 52 on)."""
    from tflock.models.potential import Potential

    monkeypatch.setattr(Potential, "step_spread", lambda self: (self.step_index / 51.5, 1.0))
    run = make_sim(model="potential", params={"n": 40, "box": 6.0}, steps=100, log={"metrics_every": 7})
    with pytest.raises(NumericalFaultError) as fault:
        run.run()
    assert (fault.value.step, fault.value.agent, fault.value.quantity) == (52, None, "integration")
    assert run.step_index == 51 and run.metrics()["step"].tolist() == list(range(0, 50, 7))


def test_the_kernel_numbers_of_gpu_arches_equal_numpys(make_sim: Any) -> None:
    """GPU arches take the guard's velocity numbers from a kernel's block partials; they equal NumPy's."""
    import numpy as np

    run = make_sim(model="potential", params={"n": 5000, "box": 100.0}, steps=3)  # two blocks of 4096
    run.run()
    big, small, squares = run.model.kernel_velocity_stats()
    v = run.model.vel.to_numpy()
    assert np.array_equal(big, v.max(axis=1)) and np.array_equal(small, v.min(axis=1))
    assert squares == pytest.approx(float(np.square(v, dtype=np.float64).sum()), rel=1e-6)
