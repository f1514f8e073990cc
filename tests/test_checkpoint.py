"""Checkpoint and resume: a resumed run is bit-identical to the uninterrupted one, and its recording continues
the same timelines in a new file with the same recording id."""

import subprocess
import sys

import numpy as np
import pytest
from conftest import assert_same_run
from rerun.chunk import RrdReader

from tflock.record import read_recording, verify_recording

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

SMALL = ["--set", "params.n=500", "--set", "params.box=15.8"]


@pytest.mark.parametrize("extra", [{}, {"async_bound": 4, "leader": {"enabled": True}}])
def test_resumed_run_is_bit_identical(make_sim, tmp_path, extra):
    params = {"n": 800, "box": 20.0, "noise": 0.4, **extra}
    straight = make_sim(params=params, steps=40, seed=3)
    straight.run()
    first = make_sim(params=params, steps=40, seed=3)
    first.step(17)
    path = first.save_checkpoint(tmp_path / "run.checkpoint.npz")
    assert path.is_file() and not path.with_name(path.name + ".tmp").exists()
    from tflock import Simulation

    resumed = Simulation(resume=path)
    assert resumed.step_index == 17
    resumed.run()
    assert_same_run(straight, resumed)


@pytest.mark.parametrize("model,params", [
    ("formation", {"n": 12}),
    ("vicsek", {"n": 300, "box": 12.0}),
    ("vicsek", {"n": 300, "box": 12.0, "neighbours": "topological", "noise_type": "vectorial"}),
    ("vicsek", {"n": 300, "box": 5.0, "dim": 3, "neighbours": "topological"}),
    ("potential", {"n": 200, "box": 12.0}),
    ("potential", {"n": 60, "box": 8.0, "topology": "fixed", "graph": "tree"}),
    ("adaptive", {"n": 300, "box": 5.0, "noise": 0.3}),
    ("adaptive", {"n": 300, "box": 5.0, "dim": 3, "alpha": "inf"}),
])
def test_every_model_resumes_bit_identically(make_sim, tmp_path, model, params):
    from tflock import Simulation

    straight = make_sim(model=model, params=params, steps=30, seed=5)
    straight.run()
    first = make_sim(model=model, params=params, steps=30, seed=5)
    first.step(13)
    resumed = Simulation(resume=first.save_checkpoint(tmp_path / "c.npz"))
    resumed.run()
    a, b = straight.state(), resumed.state()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    for key, column in straight.metrics().items():
        assert np.array_equal(column, resumed.metrics()[key], equal_nan=True), key


@pytest.mark.parametrize("change", [{"params": {"noise": 6.0}}, {"seed": 5}, {"overrides": ["params.n=5"]},
                                    {"engine": {"precision": "f32"}}], ids=["param", "seed", "n", "precision"])
def test_a_resumed_run_takes_no_change_but_steps_threads_and_log(make_sim, tmp_path, change):
    """The CLI's rule (--steps, --threads, --set log.*) in Python too: a changed parameter would make the run no
    continuation of its checkpoint's, and a changed seed was reported by the config but never used."""
    from tflock import ConfigError, Simulation

    first = make_sim(params={"n": 200, "box": 10.0}, steps=20)
    first.step(5)
    path = first.save_checkpoint(tmp_path / "c.npz")
    key = next(iter(change)) if "overrides" not in change else "params.n"
    with pytest.raises(ConfigError, match=rf"^{key}\S*: a resumed run continues its checkpoint's config; only steps"):
        Simulation(resume=path, steps=40, **change)
    resumed = Simulation(resume=path, steps=40, log={"every": 5})  # allowed
    resumed.run()
    assert resumed.step_index == 40


def test_checkpoint_now_saves_the_step_unless_this_run_wrote_it(make_sim, tmp_path):
    """What a stopped run saves (Simulation.checkpoint_now): the current step, unless the run itself wrote that
    step to its checkpoint file; a resumed run at a multiple of its cadence has not (it once skipped the save by
    arithmetic, and its file did not exist)."""
    from tflock import Simulation
    from tflock.simulation import read_checkpoint

    first = make_sim(params={"n": 200, "box": 10.0}, steps=20)
    first.step(10)
    start = first.save_checkpoint(tmp_path / "a.npz")
    resumed = Simulation(resume=start, steps=40, checkpoint=tmp_path / "b.npz", checkpoint_every=5)
    assert resumed.checkpoint_now() == tmp_path / "b.npz"  # step 10, a multiple of 5, not yet in b.npz
    assert int(read_checkpoint(tmp_path / "b.npz", arrays=False)["step"]) == 10
    resumed.step(5)  # the run writes step 15 itself
    stamp = (tmp_path / "b.npz").stat().st_mtime_ns
    said = []
    assert resumed.checkpoint_now(lambda path, step: said.append(step)) == tmp_path / "b.npz"
    assert said == [] and (tmp_path / "b.npz").stat().st_mtime_ns == stamp  # not written again
    resumed.step(2)
    resumed.checkpoint_now(lambda path, step: said.append(step))
    assert said == [17] and int(read_checkpoint(tmp_path / "b.npz", arrays=False)["step"]) == 17
    assert Simulation(resume=start, steps=40).checkpoint_now() is None  # no checkpoints asked


def test_an_interrupted_save_keeps_the_previous_checkpoint(make_sim, tmp_path, monkeypatch):
    """A second Ctrl-C (or a full disk) while a checkpoint is written leaves the previous one and no .tmp."""
    from tflock.simulation import read_checkpoint

    sim = make_sim(params={"n": 200, "box": 10.0}, steps=20)
    sim.step(3)
    path = sim.save_checkpoint(tmp_path / "c.npz")
    sim.step(2)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.save_checkpoint(path)
    assert int(read_checkpoint(path, arrays=False)["step"]) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz", "c.npz.lock"]  # held by the open run: no .tmp
    sim.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz"]


def tflock(*args, cwd):
    return subprocess.run([sys.executable, "-m", "tflock", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_cli_checkpoint_and_resume_continue_the_recording(tmp_path):
    first = tflock("sim", *SMALL, "--steps", "30", "--checkpoint-every", "10", "--out", "a.rrd", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    checkpoint = tmp_path / "a.checkpoint.npz"
    assert checkpoint.is_file() and "a.checkpoint.npz" in first.stdout
    second = tflock("sim", "--resume", str(checkpoint), "--steps", "50", "--out", "b.rrd", cwd=tmp_path)
    assert second.returncode == 0, second.stderr
    assert verify_recording(tmp_path / "b.rrd")
    a, b = read_recording(tmp_path / "a.rrd"), read_recording(tmp_path / "b.rrd")
    assert a.steps == list(range(31)) and b.steps == list(range(31, 51))
    ids = {RrdReader(str(tmp_path / name)).recordings()[0].recording_id for name in ("a.rrd", "b.rrd")}
    assert len(ids) == 1


def test_resume_without_out_writes_the_next_segment_beside_the_first(tmp_path):
    """Resumed without --out, a run whose checkpoint names its recording (a.rrd) writes the next free segment,
    a-2.rrd, then a-3.rrd: it was refused before (a.rrd exists), and it never replaces the first segment."""
    first = tflock("sim", *SMALL, "--steps", "30", "--checkpoint-every", "10", "--out", "a.rrd", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    before = (tmp_path / "a.rrd").read_bytes()
    for name, steps in (("a-2.rrd", 50), ("a-3.rrd", 40)):
        resumed = tflock("sim", "--resume", "a.checkpoint.npz", "--steps", str(steps), cwd=tmp_path)
        assert resumed.returncode == 0, resumed.stderr
        assert name in resumed.stdout and verify_recording(tmp_path / name)
        assert read_recording(tmp_path / name).steps == list(range(31, steps + 1))
        assert (tmp_path / name).with_suffix(".metrics.csv").is_file()
    assert (tmp_path / "a.rrd").read_bytes() == before


@pytest.mark.parametrize("args,key", [
    (["--resume", "missing.npz"], "checkpoint not found"),
    (["--resume", "notes.txt"], "not a tflock checkpoint"),
    (["--resume", "notes.txt", "--model", "vicsek"], "--resume"),
    (["--resume", "notes.txt", "--set", "params.n=5"], "--resume"),
    (["--resume", "notes.txt", "--set", "params.n=5"], "params.n may not change"),  # the key changed is named
    (["--resume", "notes.txt", "--seed", "3"], "--resume with --seed"),
    (["--checkpoint-every", "-1"], "--checkpoint-every"),
])
def test_bad_resume_input_is_one_line(tmp_path, args, key):
    (tmp_path / "notes.txt").write_text("not a checkpoint\n")
    result = tflock("sim", *args, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in result.stderr


def test_python_outputs_are_checked_as_the_cli_checks_them(make_sim, tmp_path):
    """The Python API refuses what the CLI refuses: a negative checkpoint interval (it hung the run: the next
    checkpoint step never came), a checkpoint that is not an .npz, a recording that is not an .rrd; and
    save_checkpoint does not replace a file this run did not write (it silently turned a recording into an .npz)
    unless overwrite=True."""
    from tflock import ConfigError, Simulation
    from tflock.outputs import OutputBusyError, OutputExistsError
    from tflock.simulation import read_checkpoint

    params = {"n": 100, "box": 5.0}
    for kwargs, message in (({"checkpoint_every": -1}, "checkpoint_every: must be an integer >= 0"),
                            ({"checkpoint_every": 2.5}, "checkpoint_every: must be an integer >= 0"),
                            ({"checkpoint": tmp_path / "x.rrd", "checkpoint_every": 1}, "checkpoint: must be a .npz"),
                            ({"record": tmp_path / "x.txt"}, "record: must be True, False or a .rrd file")):
        with pytest.raises(ConfigError, match=message):
            Simulation(model="vicsek", params=params, steps=3, **kwargs)
    assert not list(tmp_path.iterdir())  # nothing written
    sim = make_sim(params=params, steps=3)
    sim.run()
    victim = tmp_path / "run.rrd"
    victim.write_bytes(b"a recording")
    with pytest.raises(ConfigError, match="checkpoint: must be a .npz"):
        sim.save_checkpoint(victim)
    other = tmp_path / "other.checkpoint.npz"
    other.write_bytes(b"another run's checkpoint")
    with pytest.raises(OutputExistsError, match="exists"):
        sim.save_checkpoint(other)
    assert victim.read_bytes() == b"a recording" and other.read_bytes() == b"another run's checkpoint"
    mine = sim.save_checkpoint(tmp_path / "mine.npz")
    sim.step(1)
    assert sim.save_checkpoint(mine) == mine  # its own file: written again
    assert sim.save_checkpoint(other, overwrite=True) == other
    saved = read_checkpoint(other)
    assert saved["step"] == 4 and isinstance(saved["step"], int)
    assert isinstance(saved["config_toml"], str) and isinstance(saved["recording_id"], str)
    assert tomllib.loads(saved["config_toml"])["model"] == "vicsek"  # as checkpoints.md shows it
    sim.close()  # (it holds the files it saved to until then)
    # a resumed run may write its own checkpoint again; record=None is no recording, as False
    resumed = Simulation(resume=other, steps=8, record=None)
    resumed.run()
    assert resumed.save_checkpoint(other) == other and read_checkpoint(other)["step"] == 8
    # a path this run saved to is held until it closes: another run may not write it meanwhile
    with pytest.raises(OutputBusyError):
        resumed_too = Simulation(resume=other, steps=9)
        try:
            resumed_too.save_checkpoint(other, overwrite=True)
        finally:
            resumed_too.close()
    resumed.close()
