"""Values that are legal but almost surely a mistake (tflock/advice.py): the run goes on, and stderr carries one
`warning: ...` line for each, naming the key and its value; any other Python warning is one line too, and NumPy's
overflow warnings on values beyond the float range are not printed at all (the guards report those)."""

import shutil
import warnings
from pathlib import Path
from typing import Any

import pytest
from conftest import PRECISION, invoke_in

from tflock.advice import TflockWarning, mistakes, recording_bytes
from tflock.config import load_config

ENGINE = ["--set", f"engine.precision={PRECISION}", "--no-log"]


def warning_lines(result: Any) -> list[str]:
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    return [line for line in result.stderr.splitlines() if line.strip()]


@pytest.mark.parametrize(("args", "needles"), [
    (["--set", "params.n=50", "--set", "params.box=10.0", "--set", "params.radius=6"],
     ["params.radius (= 6) > params.box / 2 (= 5) in a periodic box", "not a disc"]),
    (["--set", "params.n=50", "--set", "params.box=10.0", "--set", "params.radius=15", "--set",
      "params.boundary=reflecting"], ["params.radius (= 15) >= the box's diagonal (= 14.1421)", "every agent"]),
    (["--model", "adaptive", "--set", "params.n=50", "--set", "params.boundary=periodic", "--set", "params.box=3.0",
      "--set", "params.radius=2"], ["params.radius (= 2) > params.box / 2 (= 1.5)"]),
    (["--set", "params.n=3", "--set", "params.box=10.0", "--set", "params.async_bound=1000"],
     ["params.async_bound (= 1000) > the steps to run (= 3)", "1/1000"]),
    (["--set", "params.n=50", "--set", "params.box=10.0", "--checkpoint-every", "5"],
     ["--checkpoint-every (= 5): no multiple of it lies between step 0 and the last step (3)"]),
], ids=["radius-periodic", "radius-reflecting", "radius-adaptive", "async-bound", "checkpoint-every"])
def test_each_mistake_is_one_warning_line(cpu_engine: Any, tmp_path: Path, args: list[str],
                                          needles: list[str]) -> None:
    lines = warning_lines(invoke_in(tmp_path, ["sim", *args, "--steps", "3", *ENGINE]))
    assert len(lines) == 1 and lines[0].startswith("warning: "), lines
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_more_threads_than_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    """(Checked on the config: the engine of this test process runs at its own thread count.)"""
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    found = mistakes(load_config(overrides=["engine.threads=999"]))
    assert found == ["engine.threads (= 999) > the 2 cores of this machine: the extra threads only take turns on "
                     "the same cores (0 = one per core)"]
    assert mistakes(load_config(overrides=["engine.threads=2"])) == []


def test_the_default_configs_have_no_mistakes() -> None:
    repo = Path(__file__).resolve().parents[1]
    for path in sorted((repo / "configs").rglob("*.toml")):
        if "sweeps" not in path.parts:
            assert mistakes(load_config(path)) == [], path


def test_the_python_api_issues_them_as_warnings(make_sim: Any) -> None:
    with pytest.warns(TflockWarning, match=r"params\.async_bound \(= 50\)"):
        make_sim(params={"n": 20, "box": 5.0, "async_bound": 50}, steps=10)


def test_any_other_python_warning_is_one_line(cpu_engine: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from tflock.models.vicsek import Vicsek

    metrics = Vicsek.metrics

    def noisy(self: Any) -> dict[str, float]:
        warnings.warn("something\nlibrary-ish", DeprecationWarning, stacklevel=1)
        return metrics(self)

    monkeypatch.setattr(Vicsek, "metrics", noisy)
    lines = warning_lines(invoke_in(tmp_path, ["sim", "--set", "params.n=50", "--set", "params.box=5.0", "--steps",
                                               "2", *ENGINE]))
    assert lines, "no warning line"  # one per metrics call: how often depends on the warnings filter in force
    for line in lines:
        assert line.startswith("warning: DeprecationWarning: something library-ish (test_mistakes.py:"), line


@pytest.mark.skipif(PRECISION != "f64", reason="a box of 1e300 is a finite f64 run")
@pytest.mark.parametrize("model", ["vicsek", "adaptive", "potential"])
def test_positions_beyond_float32_are_drawn_without_numpy_warnings(cpu_engine: Any, tmp_path: Path,
                                                                   model: str) -> None:
    """An f64 run in a box of 1e300 is finite; its frames (float32) and squared distances overflow to inf."""
    result = invoke_in(tmp_path, ["sim", "--model", model, "--set", "params.box=1e300", "--set", "params.n=30",
                                  "--steps", "2", "--set", f"engine.precision={PRECISION}", "--out", "far.rrd"])
    assert warning_lines(result) == []


def test_a_recording_larger_than_the_limit_or_the_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """2000 agents drawn every step for 100,000 steps is about 11 GB (a user's run wrote 10.5 GB): one warning line
    naming log.every; a frame every 100 steps is not; a recording larger than the free space is, whatever its size."""
    long = load_config(overrides=["params.n=2000", "params.box=31.6", "steps=100000"])
    found = mistakes(long, recording=tmp_path / "k.rrd", drawn=2000)
    assert len(found) == 1 and found[0].startswith("log.every (= 1): ")
    assert "every step to step 100,000, up to about 11.6 GB" in found[0] and "\n" not in found[0]
    thinned = load_config(overrides=["params.n=2000", "params.box=31.6", "steps=100000", "log.every=100"])
    assert mistakes(thinned, recording=tmp_path / "k.rrd", drawn=2000) == []
    assert mistakes(long, drawn=2000) == []  # no recording
    monkeypatch.setattr("shutil.disk_usage", lambda path: shutil._ntuple_diskusage(10**9, 10**9 - 10**6, 10**6))
    short = load_config(overrides=["params.n=2000", "params.box=31.6", "steps=100"])
    (line,) = mistakes(short, recording=tmp_path / "k.rrd", drawn=2000)
    assert "up to about 0.0117 GB, more than the 0.001 GB free there" in line


def test_the_recording_estimate_bounds_a_real_recording(make_sim: Any, tmp_path: Path) -> None:
    """recording_bytes is an upper estimate, within 1.5x, of what a recording of drawn agents and edges takes."""
    with make_sim(params={"n": 2000, "box": 31.6}, steps=50, record=tmp_path / "r.rrd") as sim:
        sim.run()
        estimate = recording_bytes(sim.config, len(sim._selected), sim._field_size)
    size = (tmp_path / "r.rrd").stat().st_size
    assert size <= estimate <= 1.5 * size, (size, estimate)
