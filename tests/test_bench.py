"""`tflock bench` at tiny sizes: the cases run, the peers are timed, the results are written as data."""

import csv
import json
import subprocess
import sys

import pytest


def test_bench_writes_json_csv_and_plot(tmp_path):
    prefix = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "tflock", "bench", "--models", "vicsek", "--sizes", "300,600",
                           "--states", "uniform,developed", "--develop-steps", "5", "--repeats", "2", "--log",
                           "--out", str(prefix)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(prefix.with_suffix(".json").read_text())
    assert data["command"].startswith("tflock bench") and data["machine"]["cores"] >= 1
    results = data["results"]
    assert [(r["case"]["n"], r["case"]["state"]) for r in results] == [
        (300, "uniform"), (300, "developed"), (600, "uniform"), (600, "developed")]
    for r in results:
        assert r["ms_min"] <= r["ms_median"] <= r["ms_max"]
        assert r["agent_steps_per_s"] == pytest.approx(r["case"]["n"] / r["ms_median"] * 1e3)
        assert r["build_ms"] > 0 and r["interactions_ms"] >= 0 and r["metrics_ms"] > 0 and r["logging_ms"] > 0
        assert r["mean_neighbors"] > 0 and r["first_step_s"] > 0
        assert 50 < r["device_bytes_per_agent"] < 400 and r["peak_rss_mb"] > 0
        assert set(r["peers"]) == {"numpy_reference", "ckdtree_sparse"}
        assert r["peers"]["numpy_reference"]["ratio"] == pytest.approx(r["peers"]["numpy_reference"]["ms"]
                                                                     / r["ms_median"])
    with open(prefix.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and "ckdtree_sparse_ratio" in rows[0]
    assert prefix.with_suffix(".png").stat().st_size > 10_000
    assert "agent-steps/s" in proc.stdout


@pytest.mark.parametrize("args,key", [(["--sizes", "0"], "--sizes"), (["--models", "boids"], "--models"),
                                      (["--states", "hot"], "--states")])
def test_bench_bad_input_is_one_line(args, key):
    proc = subprocess.run([sys.executable, "-m", "tflock", "bench", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in proc.stderr
