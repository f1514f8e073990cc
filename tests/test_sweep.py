"""Tests for `tflock sweep` and tflock.sweep: sweep files, the table, Dask execution, resume, CLI errors.

Every sweep is tiny (30 agents, 5 steps, 3 points x 2 replicas). One Dask LocalCluster (2 worker processes)
serves the module, and one `--workers 2` CLI run checks the local-process path end to end.
"""

import logging
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import PRECISION
from typer.testing import CliRunner

from tflock.cli import app
from tflock.config import ConfigError, load_config, tomllib
from tflock.sweep import execute as sweep_execute
from tflock.sweep import load_sweep, run_point, run_sweep
from tflock.sweep.table import assemble

REPO = Path(__file__).resolve().parents[1]
REPLICAS = 2
SEED = 7
SWEEP = f"""
model = "vicsek"
replicas = {REPLICAS}
seed = {SEED}

[set]
steps = 5
params.n = 30
"params.box" = 4.0
"engine.precision" = "{PRECISION}"

[grid]
"params.noise" = [0.5, 3.0]

[[points]]
"params.radius" = 1.5
"""
POINTS = 3  # the grid's two, then the explicit one


@pytest.fixture
def sweep_file(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(SWEEP, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory, cpu_engine) -> pd.DataFrame:
    """The tiny sweep run in this process, uninterrupted."""
    folder = tmp_path_factory.mktemp("reference")
    (folder / "tiny.toml").write_text(SWEEP, encoding="utf-8")
    return run_sweep(folder / "tiny.toml", out=folder / "out")


@pytest.fixture(scope="module")
def cluster():
    """One local Dask cluster for the module (its start-up is the expensive part)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as local:
        yield local


def without_wall_time(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns="wall_s")


# ----------------------------------------------------------------------------------------------------------
# Sweep files and points (no simulation)


def test_points_are_the_grid_then_the_explicit_points(sweep_file: Path) -> None:
    sweep = load_sweep(sweep_file)
    assert sweep.name == "tiny" and sweep.model == "vicsek"
    assert sweep.keys == ["params.noise", "params.radius"]
    assert [p.values for p in sweep.points] == [
        {"params.noise": 0.5, "params.radius": 1.0},  # a key a point does not set: its resolved value
        {"params.noise": 3.0, "params.radius": 1.0},
        {"params.noise": 0.5, "params.radius": 1.5},  # vicsek's default noise
    ]
    config = sweep.points[2].config
    assert (config.seed, config.steps, config.params.n, config.params.radius) == (SEED, 5, 30, 1.5)
    assert len({p.key for p in sweep.points}) == POINTS


def test_quoted_and_nested_dotted_keys_are_the_same_point() -> None:
    quoted = load_sweep({"model": "vicsek", "set": {"params.n": 30}, "grid": {"params.noise": [1.0]}})
    nested = load_sweep({"model": "vicsek", "set": {"params": {"n": 30}}, "grid": {"params": {"noise": [1.0]}}})
    assert [p.key for p in quoted.points] == [p.key for p in nested.points]


def test_no_grid_is_one_point_an_ensemble() -> None:
    sweep = load_sweep({"model": "vicsek", "replicas": 4})
    assert len(sweep.points) == 1 and sweep.keys == [] and sweep.replicas == 4


def test_point_key_changes_with_config_and_replicas(sweep_file: Path) -> None:
    keys = [p.key for p in load_sweep(sweep_file).points]
    assert [p.key for p in load_sweep(sweep_file).points] == keys
    more_replicas = [p.key for p in load_sweep(sweep_file, replicas=3).points]
    more_steps = [p.key for p in load_sweep(sweep_file, overrides=["steps=6"]).points]
    assert not set(keys) & set(more_replicas) and not set(keys) & set(more_steps)


def test_base_config_is_relative_to_the_sweep_file(tmp_path: Path) -> None:
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "base.toml").write_text('model = "vicsek"\nseed = 11\n[params]\nn = 40\n')
    (tmp_path / "sweeps").mkdir()
    (tmp_path / "sweeps" / "s.toml").write_text('base = "../configs/base.toml"\n[grid]\n"params.noise" = [1.0]\n')
    sweep = load_sweep(tmp_path / "sweeps" / "s.toml")
    assert sweep.seed == 11 and sweep.points[0].config.params.n == 40  # the base's seed when the sweep has none


def test_mixed_kinds_in_a_swept_column_become_text() -> None:
    frames = [pd.DataFrame({"point": [i], "replica": [0], "seed": [0], "params.alpha": [v], "steps": [1],
                            "wall_s": [0.1], "config": [""]}) for i, v in enumerate([1.0, "inf"])]
    assert assemble(frames, ["params.alpha"])["params.alpha"].tolist() == ["1.0", "inf"]


# ----------------------------------------------------------------------------------------------------------
# Running: the table, Dask, resume


def test_table_has_a_row_per_point_and_replica(reference: pd.DataFrame) -> None:
    table = reference
    assert len(table) == POINTS * REPLICAS
    assert table["point"].tolist() == [0, 0, 1, 1, 2, 2]
    assert table["replica"].tolist() == [0, 1] * POINTS
    assert table["seed"].tolist() == [SEED, SEED + 1] * POINTS
    assert table["params.noise"].tolist() == [0.5, 0.5, 3.0, 3.0, 0.5, 0.5]
    assert table["params.radius"].tolist() == [1.0] * 4 + [1.5] * 2
    assert list(table.columns[:6]) == ["point", "replica", "seed", "params.noise", "params.radius", "steps"]
    assert list(table.columns[-2:]) == ["wall_s", "config"]
    for prefix in ("final", "mean", "std", "min", "max"):
        assert f"{prefix}_polarization" in table.columns and f"{prefix}_largest_cluster" in table.columns
    assert table["final_polarization"].between(0, 1).all() and (table["wall_s"] > 0).all()
    for row in table.itertuples():  # each row's config reruns that replica
        config = load_config(tomllib.loads(row.config))
        assert (config.seed, config.params.noise, config.params.radius) == (row.seed, row[4], row[5])


def test_rows_summarise_the_simulation(cpu_engine, make_sim) -> None:
    config = {"model": "vicsek", "steps": 6, "params": {"n": 30, "box": 4.0, "noise": 1.0},
              "engine": {"precision": PRECISION}}
    rows = run_point(config, 2, 3)
    assert [(r["replica"], r["seed"]) for r in rows] == [(0, 3), (1, 4)]
    sim = make_sim(model="vicsek", steps=6, seed=4, params={"n": 30, "box": 4.0, "noise": 1.0})
    sim.run()
    polarization = sim.metrics()["polarization"]
    # replicas run batched: the same states bit for bit (test_ensemble.py), metrics summed in another order
    assert rows[1]["final_polarization"] == pytest.approx(polarization[-1], rel=1e-9)
    assert rows[1]["mean_polarization"] == pytest.approx(np.mean(polarization[3:]))  # steps 3..6 of 6
    assert rows[1]["std_polarization"] == pytest.approx(np.std(polarization[3:]))
    assert rows[1]["min_polarization"] == pytest.approx(np.min(polarization), rel=1e-9)  # steps 0..6: all of them
    assert rows[1]["max_polarization"] == pytest.approx(np.max(polarization), rel=1e-9)


def test_dask_cluster_gives_the_same_table(reference: pd.DataFrame, sweep_file: Path, cluster) -> None:
    table = run_sweep(sweep_file, out=sweep_file.parent / "dask", scheduler=cluster.scheduler_address)
    pd.testing.assert_frame_equal(without_wall_time(table), without_wall_time(reference))
    assert table.attrs["sweep"]["computed"] == POINTS


def test_resume_after_an_interruption_skips_finished_points(reference: pd.DataFrame, sweep_file: Path) -> None:
    out = sweep_file.parent / "out"

    def stop_after_two(done: int, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep_file, out=out, progress=stop_after_two)
    finished = sorted((out / "points").glob("*.parquet"))
    assert len(finished) == 2 and not (out / "table.parquet").exists()
    stamps = [path.stat().st_mtime_ns for path in finished]

    table = run_sweep(sweep_file, out=out)
    assert [path.stat().st_mtime_ns for path in finished] == stamps  # read, not recomputed
    assert (table.attrs["sweep"]["loaded"], table.attrs["sweep"]["computed"]) == (2, POINTS - 2)
    pd.testing.assert_frame_equal(without_wall_time(table), without_wall_time(reference))
    again = run_sweep(sweep_file, out=out)
    pd.testing.assert_frame_equal(again, table)  # wall times too: every row read back


def test_cli_interruption_counts_the_points_on_disk(sweep_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The stop message counts the points saved on disk: a point written just before the signal, whose progress
    call had not come yet, counts (the progress bar's count once said 1 where 2 were saved)."""
    from conftest import invoke_in

    import tflock.sweep
    from tflock.sweep import load_sweep
    from tflock.sweep.table import point_path

    def two_written_then_stopped(plan, *, out, progress, **_):
        progress(0, len(plan.points))
        for point in plan.points[:2]:  # written, the progress bar not told
            path = point_path(Path(out) / "points", point)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"")
        raise KeyboardInterrupt

    monkeypatch.setattr(tflock.sweep, "run_sweep", two_written_then_stopped)
    result = invoke_in(sweep_file.parent, ["sweep", sweep_file.name, "--out", "out"])
    assert result.exit_code == 130
    assert f"interrupted: 2 of {len(load_sweep(sweep_file).points)} points saved" in result.output


def test_cli_says_when_every_point_was_read_back(reference: pd.DataFrame, sweep_file: Path) -> None:
    """With every point on disk nothing runs, so no scheduler is reached: the summary says that, not that the points
    ran on Dask at the address given (a new user's unreachable --scheduler was reported as where the sweep ran)."""
    from conftest import invoke_in

    out = sweep_file.parent / "out"
    run_sweep(sweep_file, out=out)
    result = invoke_in(sweep_file.parent, ["sweep", sweep_file.name, "--out", "out", "--scheduler", "tcp://127.0.0.1:1"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "nothing to compute (every point read back)" in text and "Dask at" not in text


def test_a_changed_sweep_does_not_reuse_stale_points(reference: pd.DataFrame, sweep_file: Path) -> None:
    out = sweep_file.parent / "out"
    run_sweep(sweep_file, out=out)
    sweep_file.write_text(SWEEP.replace("steps = 5", "steps = 4"), encoding="utf-8")
    table = run_sweep(sweep_file, out=out)
    assert table.attrs["sweep"]["computed"] == POINTS
    assert (table["steps"] == 4).all()
    assert len(list((out / "points").glob("*.parquet"))) == 2 * POINTS


# ----------------------------------------------------------------------------------------------------------
# The CLI


def test_cli_with_local_workers_writes_parquet_and_csv(reference: pd.DataFrame, sweep_file: Path) -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-m", "tflock", "sweep", sweep_file.name, "--workers", "2"],
                            cwd=sweep_file.parent, env=env, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stderr == ""  # no Dask chatter
    out = sweep_file.parent / "results" / "sweeps" / "tiny"
    assert "2 local processes" in result.stdout and str(Path("results/sweeps/tiny/table.parquet")) in result.stdout
    parquet = pd.read_parquet(out / "table.parquet")
    pd.testing.assert_frame_equal(without_wall_time(parquet), without_wall_time(reference))
    csv = pd.read_csv(out / "table.csv")
    assert csv.shape == reference.shape and list(csv.columns) == list(reference.columns)
    assert csv["config"].tolist() == reference["config"].tolist()
    np.testing.assert_array_equal(csv["final_polarization"], reference["final_polarization"])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


BAD_SWEEPS = {
    "bad TOML": ("model = ", [], "invalid TOML"),
    "unknown key": ('model = "vicsek"\nreplica = 3\n', [], "replica: unknown key; allowed: name, model"),
    "no model": ("replicas = 2\n", [], "model: required key is missing"),
    "bad model": ('model = "boids"\n', [], "model: must be one of"),
    "replicas 0": ('model = "vicsek"\nreplicas = 0\n', [], "replicas: must be >= 1, got 0"),
    "replicas 1.5": ('model = "vicsek"\nreplicas = 1.5\n', [], "replicas: expected an integer >= 1, got 1.5"),
    "a run config": ('model = "vicsek"\n[params]\nn = 50\n', [], "params: unknown key; allowed: name, model, "
                     "base, replicas, seed, set, grid, points (this looks like a run config, which `tflock sim"),
    "grid not a list": ('model = "vicsek"\n[grid]\n"params.noise" = 0.5\n', [], "grid.params.noise: expected a list"),
    "empty grid": ('model = "vicsek"\n[grid]\n"params.noise" = []\n', [], "grid.params.noise: expected a non-empty"),
    "bad grid value": ('model = "vicsek"\n[grid]\n"params.noise" = [0.5, -1.0]\n', [],
                       "point 1 (params.noise = -1.0): params.noise: must be between 0 and 6.283"),
    "unknown config key": ('model = "vicsek"\n[set]\n"params.nois" = 1.0\n', [], "params.nois: unknown key"),
    "swept seed": ('model = "vicsek"\n[grid]\nseed = [1, 2]\n', [], "grid.seed: cannot vary within a sweep"),
    "swept engine": ('model = "vicsek"\n[[points]]\n"engine.precision" = "f64"\n', [],
                     "points.engine.precision: cannot vary"),
    "set and grid": ('model = "vicsek"\n[set]\n"params.noise" = 1.0\n[grid]\n"params.noise" = [0.5]\n', [],
                     "set.params.noise: this key is swept"),
    "missing base": ('base = "nope.toml"\n', [], "base: config file not found"),
    "missing file": (None, [], "sweep file not found: sweep.toml"),
    "workers 0": ('model = "vicsek"\n', ["--workers", "0"], "--workers: must be >= 1, got 0"),
    "workers and scheduler": ('model = "vicsek"\n', ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
                              "--workers and --scheduler"),
    "replicas option": ('model = "vicsek"\n', ["--replicas", "-1"], "--replicas: must be >= 1, got -1"),
    "bad --set": ('model = "vicsek"\n', ["--set", "params.speed=-1"], "params.speed: must be >= 0"),
    "unwritable out": ('model = "vicsek"\n', ["--out", "afile/sub"], "--out: cannot create afile/sub/points"),
    "unreachable scheduler": ('model = "vicsek"\n', ["--scheduler", "tcp://127.0.0.1:{port}"],
                              "--scheduler: cannot connect to 'tcp://127.0.0.1:"),
}


@pytest.mark.parametrize("case", BAD_SWEEPS, ids=list(BAD_SWEEPS))
def test_bad_input_is_one_line_and_exit_2(case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text, options, needle = BAD_SWEEPS[case]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sweep_execute, "CONNECT_TIMEOUT_S", 1)
    if text is not None:
        Path("sweep.toml").write_text(text, encoding="utf-8")
    Path("afile").write_text("", encoding="utf-8")
    options = [o.format(port=free_port()) for o in options]
    result = CliRunner().invoke(app, ["sweep", "sweep.toml", *options])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert needle in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", *(["sweep.toml"] if text is not None else [])]


def test_a_point_that_turns_non_finite_is_one_line_and_exit_2(tmp_path: Path, cpu_engine) -> None:
    """Agents flying at nearly the largest float leave the float range in a batch of replicas: the guard stops the
    sweep with its one-line fault, naming the point and the replica (no table, no NumPy warning lines)."""
    largest = np.finfo(np.float32 if PRECISION == "f32" else np.float64).max
    (tmp_path / "sweep.toml").write_text(
        f'model = "vicsek"\nreplicas = 2\n[set]\nsteps = 6\n"params.n" = 10\n"params.boundary" = "open"\n'
        f'"params.speed" = {float(0.9 * largest)!r}\n"log.metrics_every" = 3\n"engine.precision" = "{PRECISION}"\n',
        encoding="utf-8")
    result = CliRunner().invoke(app, ["sweep", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: point 0: numerical fault in vicsek at step 3: replica 0 (seed 0), agent ")
    assert not (tmp_path / "out" / "table.parquet").exists()


def test_load_sweep_errors_are_config_errors() -> None:
    with pytest.raises(ConfigError, match=r"^point 0 \(params.n = 0\): params.n: must be > 0, got 0$"):
        load_sweep({"model": "vicsek", "grid": {"params.n": [0]}})


def test_local_workers_drop_only_the_shutdown_heartbeat_error(monkeypatch) -> None:
    """A local worker whose last heartbeat meets the closed scheduler logs an error at shutdown: it is dropped (the
    CLI's stderr stays empty, see above); other errors of the worker still show."""
    monkeypatch.setattr(sweep_execute.signal, "signal", lambda *args: None)  # this process keeps its Ctrl-C
    log = logging.getLogger("distributed.worker")
    monkeypatch.setattr(log, "filters", [])
    sweep_execute.dask_setup(None)
    race = log.makeRecord(log.name, logging.ERROR, __file__, 0, sweep_execute.HEARTBEAT_RACE + ".", None, None)
    other = log.makeRecord(log.name, logging.ERROR, __file__, 0, "Compute Failed", None, None)
    assert not log.filter(race) and log.filter(other)
