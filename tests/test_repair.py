"""`tflock repair`: a run killed with SIGKILL leaves a recording without footer (rerun rrd verify fails), a complete
metrics table, its last checkpoint and a lock file that holds no lock; repair rewrites the recording through Rerun's
reader and writer into a verified file holding the same frames, and the checkpoint continues the run."""

import shutil
from pathlib import Path
from typing import Any

import pytest
from conftest import PRECISION, assert_one_error_line, invoke_in, tflock_process, wait_for_rows

from tflock import outputs
from tflock.cli import plural
from tflock.record import read_recording, verify_recording
from tflock.simulation import read_checkpoint

RUN = ["--set", "params.n=300", "--set", "params.box=12.0", "--set", f"engine.precision={PRECISION}"]


@pytest.fixture(scope="module")
def killed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with what a `tflock sim --out k.rrd --checkpoint-every 5` killed by SIGKILL in its step loop left."""
    folder = tmp_path_factory.mktemp("killed")
    run = tflock_process(folder, "sim", *RUN, "--steps", "1000000", "--checkpoint-every", "5", "--out", "k.rrd")
    try:
        wait_for_rows(run, folder / "k.metrics.csv", 40)
    finally:
        run.kill()
        run.wait()
    for name in ("stdout.txt", "stderr.txt"):
        (folder / name).unlink()
    return folder


def copy_of(killed: Path, tmp_path: Path) -> Path:
    for path in killed.iterdir():
        shutil.copy(path, tmp_path / path.name)
    return tmp_path


def table_steps(path: Path) -> list[int]:
    return [int(row.split(",", 1)[0]) for row in path.read_text(encoding="utf-8").splitlines()[1:]]


def test_what_a_killed_run_leaves(killed: Path) -> None:
    names = {p.name for p in killed.iterdir()}
    names.discard("k.checkpoint.npz.tmp")  # killed while writing a checkpoint: the previous one stays whole (below)
    assert sorted(names) == ["k.checkpoint.npz", "k.checkpoint.npz.lock", "k.metrics.csv", "k.rrd", "k.rrd.lock"]
    assert not verify_recording(killed / "k.rrd")
    steps = table_steps(killed / "k.metrics.csv")
    assert len(steps) >= 40 and steps == list(range(len(steps)))  # every row (the fixture waited for 40), flushed
    at = int(read_checkpoint(killed / "k.checkpoint.npz", arrays=False)["step"])
    assert at % 5 == 0 and at <= steps[-1]
    summary = read_recording(killed / "k.rrd")  # readable without its footer
    assert summary.steps == list(range(len(summary.steps))) and summary.steps


def test_repair_in_place_gives_a_verified_file_with_the_same_frames(killed: Path, tmp_path: Path,
                                                                   cpu_engine: Any) -> None:
    folder = copy_of(killed, tmp_path)
    before = read_recording(folder / "k.rrd")
    result = invoke_in(folder, ["repair", "k.rrd"])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("repaired k.rrd (rerun rrd verify passes)")
    assert f"{plural(before.frames, 'frame')} (steps 0 to {before.last_step})" in result.stdout
    assert "its metrics table k.metrics.csv has rows up to step" in result.stdout
    assert verify_recording(folder / "k.rrd")
    after = read_recording(folder / "k.rrd")
    assert (after.steps, after.metric_rows, after.config_toml) == (before.steps, before.metric_rows, before.config_toml)
    assert after.final_metrics == before.final_metrics
    assert not (folder / "k.rrd.lock").exists()

    again = invoke_in(folder, ["repair", "k.rrd"])
    assert again.exit_code == 0 and "k.rrd is complete already" in again.stdout
    at = int(read_checkpoint(folder / "k.checkpoint.npz", arrays=False)["step"])
    end = at + 20  # the killed run's pace decides where its last checkpoint is (60 and beyond, on a fast day)
    resumed = invoke_in(folder, ["sim", "--resume", "k.checkpoint.npz", "--steps", str(end), "--out", "k-2.rrd"])
    assert resumed.exit_code == 0, resumed.output
    assert read_recording(folder / "k-2.rrd").steps == list(range(at + 1, end + 1))


def test_repair_into_another_file_keeps_the_original(killed: Path, tmp_path: Path) -> None:
    folder = copy_of(killed, tmp_path)
    original = (folder / "k.rrd").read_bytes()
    result = invoke_in(folder, ["repair", "k.rrd", "--out", "fixed.rrd"])
    assert result.exit_code == 0, result.output
    assert verify_recording(folder / "fixed.rrd") and (folder / "k.rrd").read_bytes() == original
    assert_one_error_line(invoke_in(folder, ["repair", "k.rrd", "--out", "fixed.rrd"]), "fixed.rrd exists")
    assert invoke_in(folder, ["repair", "k.rrd", "--out", "fixed.rrd", "--overwrite"]).exit_code == 0


def test_a_recording_cut_mid_message_is_repaired_up_to_the_cut(killed: Path, tmp_path: Path) -> None:
    """Power loss or a full disk can cut the last message: the reader refuses the file, repair keeps the rest."""
    data = (killed / "k.rrd").read_bytes()
    cut = tmp_path / "cut.rrd"
    for lost in range(3000, 3400):  # the first cut that lands inside a message (one on a boundary leaves a whole file)
        cut.write_bytes(data[: len(data) - lost])
        if not verify_recording(cut):
            break
    line = assert_one_error_line(invoke_in(tmp_path, ["inspect", "cut.rrd"]), "cannot read cut.rrd")
    assert "`tflock repair cut.rrd` recovers what it holds" in line
    assert invoke_in(tmp_path, ["repair", "cut.rrd"]).exit_code == 0
    steps = read_recording(cut).steps
    assert verify_recording(cut) and steps == list(range(len(steps))) and steps


def test_a_recording_cut_before_the_runs_description_says_so(killed: Path, tmp_path: Path) -> None:
    """A file cut within its first Rerun messages repairs to a valid recording that holds none of the run's
    description: repair says so, rather than send the user from inspect to repair and back."""
    cut = tmp_path / "early.rrd"
    cut.write_bytes((killed / "k.rrd").read_bytes()[:3000])
    result = invoke_in(tmp_path, ["repair", "early.rrd"])
    assert result.exit_code == 0 and verify_recording(cut)
    assert "holds no tflock run's description" in result.output and "`rerun early.rrd` shows what it holds" in \
        " ".join(result.output.split())


def test_a_recording_a_run_still_writes_is_refused(killed: Path, tmp_path: Path) -> None:
    folder = copy_of(killed, tmp_path)
    held = outputs.lock(folder / "k.rrd")
    try:
        assert_one_error_line(invoke_in(folder, ["repair", "k.rrd"]), "k.rrd is being written by another tflock run")
    finally:
        held.release()
    assert not verify_recording(folder / "k.rrd")


@pytest.mark.parametrize(("content", "needles"), [
    (None, ["recording not found", "nope.rrd"]),
    (b"", ["nope.rrd is empty", "nothing to recover"]),
    (b"not a recording at all\n" * 10, ["nope.rrd is not a Rerun recording"]),
    (b"RRF2" + bytes(100), ["nope.rrd holds no readable recording"]),
], ids=["missing", "empty", "text", "header-only"])
def test_what_cannot_be_repaired_is_one_line(tmp_path: Path, content: bytes | None, needles: list[str]) -> None:
    if content is not None:
        (tmp_path / "nope.rrd").write_bytes(content)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert_one_error_line(invoke_in(tmp_path, ["repair", "nope.rrd"]), *needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_killed_runs_lock_file_holds_no_lock(killed: Path, tmp_path: Path, cpu_engine: Any) -> None:
    folder = copy_of(killed, tmp_path)
    assert (folder / "k.rrd.lock").is_file()  # SIGKILL: nothing ran to remove it; the kernel dropped the lock
    result = invoke_in(folder, ["sim", *RUN, "--steps", "2", "--out", "k.rrd", "--overwrite", "--checkpoint-every",
                                "2"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in folder.iterdir()) == ["k.checkpoint.npz", "k.metrics.csv", "k.rrd"]
