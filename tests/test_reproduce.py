"""`tflock reproduce`: the framework (listing, errors, resume) and the Vicsek order-noise experiment.

Reproductions run at the default f32 engine, so they run in a subprocess (this process's Taichi is f64).
"""

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
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
    assert "…" not in result.output  # every source whole: a paper's file name wrapped, not cut to "papers/00…"


def test_unknown_experiment_is_one_line_and_exit_2():
    result = CliRunner().invoke(app, ["reproduce", "vicsek-typo", "--quick"])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "unknown experiment 'vicsek-typo'" in lines[0] and "vicsek-noise" in lines[0]


@pytest.mark.parametrize("n", [40, 400])
def test_vicsek_noise_random_level_is_the_mean_order_of_random_headings(n):
    """The level the comparison checks at eta = 2 pi, sqrt(pi / (4 N)), is the mean v_a of N independent uniform
    headings (20000 draws: within 1 %; the 1 / sqrt(N) it replaced is 13 % above it)."""
    from tflock.reproduce.vicsek_noise import random_level

    angles = np.random.default_rng(n).uniform(0, 2 * np.pi, (20000, n))
    order = np.hypot(np.cos(angles).mean(axis=1), np.sin(angles).mean(axis=1)).mean()
    assert random_level(n) == pytest.approx(order, rel=0.01)
    assert 1 / math.sqrt(n) > 1.1 * order


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
    assert f"Command: `tflock reproduce vicsek-noise --quick --out {out}`." in (out / "comparison.md").read_text()
    again = reproduce("vicsek-noise", "--quick", "--out", str(out))  # everything is read back, nothing rerun
    assert again.returncode == 0, again.stderr[-3000:]
    assert "0 computed" in again.stdout
    pd.testing.assert_frame_equal(pd.read_csv(out / "table.csv"), table)
