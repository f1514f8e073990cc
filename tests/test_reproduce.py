"""`tflock reproduce`: the framework (listing, errors, resume) and the Vicsek order-noise experiment.

Reproductions run at the default f32 engine, so they run in a subprocess (this process's Taichi is f64).
"""

import math
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
from typer.testing import CliRunner

from tflock.cli import app

REPO = Path(__file__).resolve().parents[1]


def reproduce(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "tflock", "reproduce", *args], capture_output=True, text=True,
                          env=env, timeout=600)


def test_list_names_every_experiment():
    from tflock.reproduce import EXPERIMENTS

    result = CliRunner().invoke(app, ["reproduce", "--list"])
    assert result.exit_code == 0
    for name in EXPERIMENTS:
        assert name in result.output


def test_unknown_experiment_is_one_line_and_exit_2():
    result = CliRunner().invoke(app, ["reproduce", "vicsek-typo", "--quick"])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "unknown experiment 'vicsek-typo'" in lines[0] and "vicsek-noise" in lines[0]


def test_vicsek_noise_quick_reproduces_the_transition_and_resumes(tmp_path):
    out = tmp_path / "vn"
    first = reproduce("vicsek-noise", "--quick", "--out", str(out))
    assert first.returncode == 0, first.stderr[-3000:]
    for name in ("polarization-vs-noise.png", "table.csv", "comparison.md"):
        assert (out / name).stat().st_size > 0
    table = pd.read_csv(out / "table.csv")
    for n, group in table.groupby("n"):
        order = group.sort_values("noise")["polarization"].to_numpy()
        assert order[0] > 0.9  # ordered at low noise
        assert order[-1] < 3 / math.sqrt(n)  # random headings' level at eta = 2 pi
        assert (order[1:] <= order[:-1] + 0.05).all()  # decreasing, up to sampling noise
        assert order[0] - order[-1] > 0.7
    big, small = (table[table.n == n].sort_values("noise")["polarization"].to_numpy() for n in (400, 40))
    assert big[-1] < small[-1]  # finite size: the disordered level falls like 1 / sqrt(N)
    assert "agrees" in (out / "comparison.md").read_text()
    again = reproduce("vicsek-noise", "--quick", "--out", str(out))  # everything is read back, nothing rerun
    assert again.returncode == 0, again.stderr[-3000:]
    assert "0 computed" in again.stdout
    pd.testing.assert_frame_equal(pd.read_csv(out / "table.csv"), table)
