"""A run owns its outputs (tflock/outputs.py): a second run on the same path is refused at start with one line and
writes nothing, an earlier run's files are refused unless --overwrite, a default name that is taken gets a number,
and no lock or temporary file is left after a run ends (normally, on SIGTERM, on a refusal or on a fault). What a
SIGKILLed run leaves is in tests/test_repair.py."""

import os
import signal
import subprocess
from pathlib import Path
from typing import Any

import pytest
from conftest import PRECISION, assert_one_error_line, invoke_in, tflock_process, wait_for_rows

from tflock import outputs, simulation
from tflock.record import read_recording, verify_recording

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

SMALL = ["--set", "params.n=200", "--set", "params.box=10.0"]
ENGINE = ["--set", f"engine.precision={PRECISION}"]


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in ("stdout.txt", "stderr.txt"))


def sim(cwd: Path, *args: str) -> Any:
    return invoke_in(cwd, ["sim", *SMALL, *ENGINE, *args])


def test_a_second_run_on_the_same_path_is_refused_and_the_first_ends_verified(tmp_path: Path) -> None:
    first = tflock_process(tmp_path, "sim", *SMALL, "--steps", "1000000", "--out", "same.rrd")
    try:
        wait_for_rows(first, tmp_path / "same.metrics.csv", 3)
        assert (tmp_path / "same.rrd.lock").read_text().split()[0] == str(first.pid)
        size = (tmp_path / "same.rrd").stat().st_size
        second = subprocess.run([*first.args[:3], "sim", *SMALL, "--steps", "3", "--out", "same.rrd"],
                                cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
                                capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
        assert second.returncode == 2, second.stderr
        assert second.stdout == "" and second.stderr.splitlines() == [
            f"error: same.rrd is being written by another tflock run (pid {first.pid})"]
        assert (tmp_path / "same.rrd").stat().st_size >= size  # not truncated: the first run's file grows on
        first.send_signal(signal.SIGTERM)
        assert first.wait(timeout=60) == 130
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert verify_recording(tmp_path / "same.rrd")
    steps = read_recording(tmp_path / "same.rrd").steps
    rows = (tmp_path / "same.metrics.csv").read_text().splitlines()[1:]
    assert steps == list(range(len(steps))) and [int(r.split(",")[0]) for r in rows] == list(range(len(rows)))
    assert names(tmp_path) == ["same.metrics.csv", "same.rrd"]  # no lock, no temporary file


def test_an_earlier_runs_files_are_refused_unless_overwrite(cpu_engine: Any, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    assert sim(tmp_path, "--steps", "1", "--out", "x.rrd", "--checkpoint-every", "1").exit_code == 0
    before = {name: (tmp_path / name).read_bytes() for name in names(tmp_path)}
    assert sorted(before) == ["x.checkpoint.npz", "x.metrics.csv", "x.rrd"]
    line = assert_one_error_line(sim(tmp_path, "--steps", "3", "--out", "x.rrd"), "x.rrd exists", "--overwrite")
    assert "earlier run" in line
    (tmp_path / "x.rrd").rename(tmp_path / "kept.rrd")  # the metrics table alone is an earlier run's output too
    assert_one_error_line(sim(tmp_path, "--steps", "3", "--out", "x.rrd"), "x.metrics.csv exists")
    (tmp_path / "kept.rrd").rename(tmp_path / "x.rrd")
    assert_one_error_line(sim(tmp_path, "--steps", "3", "--out", "y.rrd", "--checkpoint", "x.checkpoint.npz"),
                          "x.checkpoint.npz exists")
    assert {name: (tmp_path / name).read_bytes() for name in names(tmp_path)} == before
    with monkeypatch.context() as patch:  # refused at its start (the engine), an overwriting run keeps them
        patch.setenv("TFLOCK_LANES", "7")
        assert_one_error_line(sim(tmp_path, "--steps", "3", "--out", "x.rrd", "--overwrite", "--checkpoint-every",
                                  "2"), "TFLOCK_LANES")
    assert {name: (tmp_path / name).read_bytes() for name in names(tmp_path)} == before

    assert sim(tmp_path, "--steps", "3", "--out", "x.rrd", "--overwrite", "--checkpoint-every", "2").exit_code == 0
    assert read_recording(tmp_path / "x.rrd").steps == [0, 1, 2, 3]
    assert int(simulation.read_checkpoint(tmp_path / "x.checkpoint.npz")["step"]) == 2  # the earlier run's: step 1
    assert names(tmp_path) == sorted(before)


def test_out_is_the_saved_configs_log_out(cpu_engine: Any, tmp_path: Path) -> None:
    """--out is a shortcut for log.out: the config a checkpoint keeps says where the recording went, so a resumed
    run without --out writes beside it, the next segment runs/a-2.rrd (it was refused before c4fd637: runs/a.rrd
    exists), not under a default name, and leaves the first segment as it was."""
    assert sim(tmp_path, "--steps", "2", "--out", "runs/a.rrd", "--checkpoint-every", "2").exit_code == 0
    saved = simulation.read_checkpoint(tmp_path / "runs" / "a.checkpoint.npz", arrays=False)
    assert tomllib.loads(str(saved["config_toml"]))["log"]["out"] == "runs/a.rrd"
    first = (tmp_path / "runs" / "a.rrd").read_bytes()
    resumed = invoke_in(tmp_path, ["sim", "--resume", "runs/a.checkpoint.npz", "--steps", "4"])
    assert resumed.exit_code == 0 and "runs/a-2.rrd" in resumed.stdout
    assert names(tmp_path) == ["runs"]
    assert names(tmp_path / "runs") == ["a-2.metrics.csv", "a-2.rrd", "a.checkpoint.npz", "a.metrics.csv", "a.rrd"]
    assert (tmp_path / "runs" / "a.rrd").read_bytes() == first
    assert read_recording(tmp_path / "runs" / "a-2.rrd").steps == [3, 4]


def test_a_resumed_run_may_keep_writing_its_own_checkpoint(cpu_engine: Any, tmp_path: Path) -> None:
    assert sim(tmp_path, "--steps", "4", "--no-log", "--checkpoint", "c.npz", "--checkpoint-every", "2").exit_code == 0
    result = invoke_in(tmp_path, ["sim", "--resume", "c.npz", "--steps", "8", "--no-log", "--checkpoint", "c.npz",
                                  "--checkpoint-every", "2"])
    assert result.exit_code == 0, result.output
    assert int(simulation.read_checkpoint(tmp_path / "c.npz")["step"]) == 8
    assert names(tmp_path) == ["c.npz"]


def test_a_taken_default_name_gets_a_number(cpu_engine: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(simulation, "default_recording_path", lambda model: Path("recordings") / f"{model}-T.rrd")
    for _ in range(3):
        assert sim(tmp_path, "--steps", "1", "--checkpoint-every", "1").exit_code == 0
    assert names(tmp_path / "recordings") == sorted(
        f"vicsek-T{k}{suffix}" for k in ("", "-2", "-3") for suffix in (".checkpoint.npz", ".metrics.csv", ".rrd"))


def test_an_open_simulation_holds_its_outputs_until_closed(make_sim: Any, tmp_path: Path) -> None:
    first = make_sim(params={"n": 50, "box": 5.0}, steps=2, record=tmp_path / "a.rrd")
    with pytest.raises(outputs.OutputBusyError, match=r"a\.rrd is being written .*this process that is still open"):
        make_sim(params={"n": 50, "box": 5.0}, steps=2, record=tmp_path / "a.rrd", overwrite=True)
    first.run()
    first.close()
    assert names(tmp_path) == ["a.metrics.csv", "a.rrd"]
    with make_sim(params={"n": 50, "box": 5.0}, steps=2, record=tmp_path / "a.rrd", overwrite=True) as second:
        second.run()
    assert verify_recording(tmp_path / "a.rrd") and names(tmp_path) == ["a.metrics.csv", "a.rrd"]


def test_a_refused_or_faulted_run_leaves_no_lock(cpu_engine: Any, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert_one_error_line(sim(tmp_path, "--out", "a.rrd", "--spawn"), "--spawn")  # refused after the claim
    assert names(tmp_path) == []
    monkeypatch.setattr(simulation, "lyapunov_test", lambda start, model: "the integration is unstable: test")
    line = assert_one_error_line(invoke_in(tmp_path, ["sim", "--model", "potential", "--set", "params.n=20",
                                                      "--set", "params.box=5.0", *ENGINE, "--out", "p.rrd"]))
    assert "at step 1: the integration is unstable: test" in line
    assert names(tmp_path) == ["p.lastgood.npz", "p.metrics.csv", "p.rrd"]
