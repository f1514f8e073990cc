"""Numerical faults: a non-finite position, heading or velocity stops the run with one line naming the model, the
step and the first bad agent (exit code 2); the recording stays valid up to the last good frame (nothing of the bad
step), the metrics table ends at the last good logged step, and a checkpoint of the last good state is written,
which resumes into the same fault at the same step.

Faults are injected (the model's ``advance`` poisons agents at a chosen step, in every model) or real (the
potential model with an absurd time step overflows). Runs go through the CLI in-process, at this test session's
engine settings.
"""

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import PRECISION, assert_one_error_line, invoke_in

from tflock import simulation
from tflock.models import model_class
from tflock.record import read_recording, verify_recording
from tflock.simulation import NumericalFaultError, read_checkpoint

ENGINE = ["--set", f"engine.precision={PRECISION}"]
FAULT_STEP = 7
POISONED = (5, 11)  # the guard names the smallest
#: model -> (--set overrides, poisoned array, its row (None: 1D), the quantity the guard names)
MODELS: dict[str, tuple[list[str], str, int | None, str]] = {
    "vicsek": (["params.n=300", "params.box=12.0"], "theta", None, "heading"),
    "adaptive": (["params.n=300", "params.box=5.0"], "pos", 1, "position"),
    "potential": (["params.n=200", "params.box=12.0"], "vel", 0, "velocity"),
    "formation": (["params.n=12"], "f", 0, "heading"),  # row 0 of the current buffer f: the headings
}


def sim(cwd: Path, *args: str) -> Any:
    """`tflock sim ARGS` in-process in `cwd`, at this session's precision (a resumed run has its checkpoint's)."""
    return invoke_in(cwd, ["sim", *([] if "--resume" in args else ENGINE), *args])


def one_line_error(result: Any) -> str:
    line = assert_one_error_line(result)
    assert line.startswith("error: numerical fault"), line
    return line


def poison_at(monkeypatch: pytest.MonkeyPatch, model: str, step: int, agents: tuple[int, ...]) -> None:
    """Make `model`'s agents non-finite right after `step` (in the original run and in every replay)."""
    _, name, row, _ = MODELS[model]
    cls = model_class(model)
    advance = cls.advance

    def poisoned(self: Any, steps: int) -> None:
        for _ in range(steps):
            advance(self, 1)
            if self.step_index == step:
                array, ids = getattr(self, name), self.ids
                if isinstance(array, list):  # formation's double buffers
                    array, ids = array[self.cur], ids[self.cur]
                values, slots = array.to_numpy(), ids.to_numpy()
                for agent in agents:
                    slot = int(np.flatnonzero(slots == agent)[0])
                    values[(slot,) if row is None else (row, slot)] = math.nan
                array.from_numpy(values)

    monkeypatch.setattr(cls, "advance", poisoned)


def steps_of(csv_path: Path) -> list[int]:
    rows = csv_path.read_text(encoding="utf-8").splitlines()[1:]
    return [int(row.split(",", 1)[0]) for row in rows]


@pytest.mark.parametrize("model", list(MODELS))
def test_injected_fault_stops_with_a_valid_recording_and_a_resumable_checkpoint(
        cpu_engine: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, model: str) -> None:
    overrides, _, _, quantity = MODELS[model]
    poison_at(monkeypatch, model, FAULT_STEP, POISONED)
    sets = [arg for o in overrides for arg in ("--set", o)]
    cadence = ["--set", "log.metrics_every=4", "--set", "log.every=3", "--steps", "20"]
    line = one_line_error(sim(tmp_path, "--model", model, *sets, *cadence, "--out", "run.rrd"))
    assert f"numerical fault in {model} at step {FAULT_STEP}: agent {POISONED[0]} has a non-finite {quantity}" in line
    assert "run.lastgood.npz" in line and f"step {FAULT_STEP - 1}" in line

    # checks at steps 3, 4, 6 passed; the one at 8 found the fault, and the replay from the last good copy put it
    # at step 7: frames 0, 3, 6 and metric rows 0, 4 were written, nothing later
    assert verify_recording(tmp_path / "run.rrd")
    summary = read_recording(tmp_path / "run.rrd")
    assert summary.model == model and summary.steps == [0, 3, 6]
    assert steps_of(tmp_path / "run.metrics.csv") == [0, 4]
    saved = read_checkpoint(tmp_path / "run.lastgood.npz")
    assert int(saved["step"]) == FAULT_STEP - 1
    assert saved["metrics__step"].tolist() == [0, 4]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.lastgood.npz", "run.metrics.csv", "run.rrd"]

    # the last good state resumes, and (steps are deterministic) meets the same fault at the same step
    line = one_line_error(sim(tmp_path, "--resume", "run.lastgood.npz", "--out", "resumed.rrd"))
    assert f"at step {FAULT_STEP}: agent {POISONED[0]} has a non-finite {quantity}" in line
    assert verify_recording(tmp_path / "resumed.rrd")
    assert read_recording(tmp_path / "resumed.rrd").steps == []
    assert int(read_checkpoint(tmp_path / "resumed.lastgood.npz")["step"]) == FAULT_STEP - 1


def test_replay_from_the_start_finds_the_same_step(cpu_engine: Any, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """With no good copy kept after the start, the replay covers every step from 0, to the same answer; the
    --checkpoint file receives the last good state."""
    monkeypatch.setattr(simulation, "GOOD_COPY_RATIO", 1e12)
    poison_at(monkeypatch, "vicsek", 13, (42,))
    line = one_line_error(sim(tmp_path, "--set", "params.n=300", "--set", "params.box=12.0", "--steps", "30",
                              "--set", "log.metrics_every=10", "--no-log", "--checkpoint", "ck.npz"))
    assert "at step 13: agent 42 has a non-finite heading" in line and "ck.npz" in line
    saved = read_checkpoint(tmp_path / "ck.npz")
    assert int(saved["step"]) == 12 and saved["metrics__step"].tolist() == [0, 10]


def test_python_api_raises_with_the_details(make_sim: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Formation speeds are recomputed every step (a bad one does not last): metrics every step see it at once."""
    monkeypatch.setitem(MODELS, "formation", (["params.n=12"], "f", 1, "velocity"))  # row 1: the speeds
    poison_at(monkeypatch, "formation", 4, (3, 7))
    run = make_sim(model="formation", params={"n": 12}, steps=10, checkpoint=tmp_path / "last.npz")
    with pytest.raises(NumericalFaultError) as fault:
        run.run()
    error = fault.value
    assert (error.model, error.step, error.agent, error.quantity) == ("formation", 4, 3, "velocity")
    assert error.checkpoint == tmp_path / "last.npz" and run.step_index == 3
    assert run.metrics()["step"].tolist() == [0, 1, 2, 3]


def test_a_non_finite_start_state_is_refused_before_anything_is_written(
        cpu_engine: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tflock.models.vicsek as vicsek

    initial = vicsek.initial_state

    def overflowing(params: Any, seed: int) -> dict[str, np.ndarray]:
        state = initial(params, seed)
        state["x"][17, 0] = math.inf  # what a box beyond the float range gives
        return state

    monkeypatch.setattr(vicsek, "initial_state", overflowing)
    line = one_line_error(sim(tmp_path, "--set", "params.n=300", "--set", "params.box=12.0", "--out", "x.rrd"))
    assert "at step 0: agent 17 has a non-finite position in the start state" in line
    assert list(tmp_path.iterdir()) == []


#: an absurd time step on a complete graph: explicit Euler's velocity alignment is unstable for dt > 2 / n, and the
#: velocity mismatch grows ~n dt-fold a step until it overflows (step 68 at f64, 16 at f32)
BLOW_UP_DT = {"f64": 10.0, "f32": 1.0}


def test_real_blow_up_is_found_at_its_exact_step(make_sim: Any, cpu_engine: Any, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """With the stability guard off (it stops this run at step 1: tests/test_stability.py), the non-finite guard
    finds where the overflow happens."""
    monkeypatch.setattr(simulation, "cheap_test", lambda model: None)
    monkeypatch.setattr(simulation, "lyapunov_test", lambda start, model: None)
    params = {"n": 20, "box": 5.0, "dt": BLOW_UP_DT[PRECISION], "min_separation": 0.0, "topology": "fixed",
              "graph": "complete"}
    reference = make_sim(model="potential", params=params, steps=400)
    for _ in range(400):  # the first step with a non-finite x or v, from the plain state arrays
        reference.model.advance(1)
        state = reference.model.state()
        bad = ~(np.isfinite(state["x"]).all(axis=1) & np.isfinite(state["v"]).all(axis=1))
        if bad.any():
            break
    assert bad.any(), "no blow-up: pick a larger dt"
    step, agent = reference.step_index, int(np.flatnonzero(bad)[0])
    quantity = "position" if not np.isfinite(state["x"][agent]).all() else "velocity"

    sets = [arg for k, v in params.items() for arg in ("--set", f"params.{k}={v!r}")]
    line = one_line_error(sim(tmp_path, "--model", "potential", *sets, "--steps", "400", "--set",
                              "log.metrics_every=4", "--set", "log.every=4", "--out", "p.rrd"))
    assert f"numerical fault in potential at step {step}: agent {agent} has a non-finite {quantity}" in line
    assert verify_recording(tmp_path / "p.rrd")
    last_logged = (step - 1) // 4 * 4  # the check after it (a multiple of 4) found the fault; a replay placed it
    assert read_recording(tmp_path / "p.rrd").last_step == last_logged
    assert steps_of(tmp_path / "p.metrics.csv")[-1] == last_logged
    assert int(read_checkpoint(tmp_path / "p.lastgood.npz")["step"]) == step - 1
