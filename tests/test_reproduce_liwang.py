"""`tflock reproduce liwang --quick`: Li & Wang's adaptive-velocity Figs. 3-6 (papers/002_d777ea4dd61f2aeb.txt).

The reproduction runs at the default f32 engine, so it runs in a subprocess (this process's Taichi is f64). The
assertions are the paper's findings on the quick data, loose enough for 8 realisations per point but not for a
model whose speed ignores alpha, whose tau is not the 98 % speed time, or whose noise misses the speed law.
"""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

FIGURES = ("fig3-convergence", "fig4-largest-cluster", "fig5-transient", "fig6-noise")


@pytest.fixture(scope="module")
def quick(tmp_path_factory, reproduce_quick) -> Path:
    return reproduce_quick("liwang", tmp_path_factory.mktemp("liwang"))


@pytest.fixture(scope="module")
def table(quick: Path) -> pd.DataFrame:
    return pd.read_csv(quick / "table.csv")


def test_writes_figures_table_and_comparison(quick):
    for name in [f"{stem}.png" for stem in FIGURES] + ["table.csv", "comparison.md"]:
        assert (quick / name).stat().st_size > 0, name
    text = (quick / "comparison.md").read_text()
    for heading in ("## Figs. 3-4", "## Fig. 5", "## Fig. 6"):
        assert heading in text
    assert text.count("Verdict:") == 3
    assert "beta ~ 4.0 and gamma ~ 1.4" in text  # the paper's eq. (10) coefficients are quoted


def test_figs3_4_adaptive_speed_raises_convergence_and_cluster_size(table):
    data = table[table.figure == "3-4"]
    inf = data[np.isinf(data.alpha)]
    assert (inf.p >= 0.75).all()  # "very close to 1 in the case of alpha = inf"
    assert (inf.S >= 0.99).all()
    fast = data[data.v0 == data.v0.max()].sort_values("alpha")
    assert (np.diff(fast.S) > 0).all()  # S rises with alpha (Fig. 4b)
    assert fast.p.iloc[-1] - fast.p.iloc[0] >= 0.5  # Vicsek (alpha = 0) rarely converges at v0 = 1; alpha = inf does
    vicsek = data[data.alpha == 0].sort_values("v0")
    assert (np.diff(vicsek.S) < 0).all()  # S falls with v0 (Fig. 4a)
    assert vicsek.p.iloc[0] > vicsek.p.iloc[-1]


def test_fig5_transient_time_is_logarithmic_in_alpha(table):
    curve = table[(table.figure == "5a") & (table.v0 == 1.0)].sort_values("alpha")
    assert (curve.tau_unreached == 0).all()
    assert (np.diff(curve.tau) > 0).all()
    gamma, beta = np.polyfit(np.log2(curve.alpha), curve.tau, 1)
    assert 2.5 <= beta <= 5.5 and 1.0 <= gamma <= 1.8  # eq. (10): beta ~ 4.0, gamma ~ 1.4
    assert 14 <= curve.tau.iloc[-1] <= 22  # "about 18 steps" at alpha = 1024
    wide = table[(table.figure == "5c-d") & (table.radius == 6.0)]
    assert (wide.tau <= 4).all()  # R -> 6: nearly global coupling, beta -> 1


def test_fig6_speed_coefficient_and_order_fall_with_noise(table):
    data = table[table.figure == "6"]
    assert np.allclose(data[data.alpha == 0].c_alpha, 1.0, atol=1e-3)  # C_alpha = 1 for alpha = 0
    adaptive = data[data.alpha > 0].sort_values("noise")
    assert (np.diff(adaptive.c_alpha) < 0).all() and adaptive.c_alpha.iloc[-1] < 0.1
    frozen = adaptive.iloc[-1]  # alpha = 4, eta = 2.5: phi^alpha ~ 0, one motionless, globally coupled cluster
    assert frozen.S > 0.95
    assert abs(frozen.phi_theta - math.sin(2.5) / 2.5) < 0.05  # |E exp(i xi)| for xi ~ U[-eta, eta] (eq. 12)
    vicsek = data[data.alpha == 0].sort_values("noise")
    assert vicsek.phi_theta.iloc[0] > 0.5 > 0.2 > vicsek.phi_theta.iloc[-1]  # alpha = 0: noise destroys the order


def _noise_sweep(curves: dict[float, list[float]], etas: list[float], replicas: int = 40) -> pd.DataFrame:
    """Per-realisation rows of the Fig. 6 sweep: Phi_theta = curve value + each seed's own offset (shared by the
    alphas, as one seed is one initial state) + a little independent noise."""
    rng = np.random.default_rng(3)
    offsets = rng.normal(0, 0.02, replicas)
    rows = [{"params.alpha": alpha, "params.noise": eta, "seed": seed,
             "mean_phi_theta": value + offsets[seed] + rng.normal(0, 0.001)}
            for alpha, values in curves.items() for eta, value in zip(etas, values, strict=True)
            for seed in range(replicas)]
    return pd.DataFrame(rows)


@pytest.mark.parametrize(("bend", "expected"), [(0.0, True), (0.05, False)])
def test_fig6_one_straight_line_is_judged_by_the_spread(bend, expected):
    """The two largest alphas are one curve where the 95 % interval of their paired difference lies within
    +-ONE_CURVE (here from eta = 2; at 1.75 they differ by 0.06: outside, although a comparison of the means with a
    tolerance of 0.06 would pass), and a straight one where a line through the means lies within their intervals
    (a bend of 0.05 at one eta, shared by both curves, is far outside them)."""
    from tflock.reproduce.experiment import Results
    from tflock.reproduce.liwang import NOISE, ONE_CURVE, LiWang, _with_interval

    etas = [1.75, 2.0, 2.25, 2.5]
    line = [0.9 - 0.3 * e for e in etas]
    line[2] += bend
    sweep = _noise_sweep({4.0: [line[0] + ONE_CURVE + 0.01, *line[1:]], 16.0: line}, etas)
    data = pd.DataFrame([{"alpha": alpha, "noise": eta, **_with_interval("phi_theta", group["mean_phi_theta"])}
                         for (alpha, eta), group in sweep.groupby(["params.alpha", "params.noise"])])
    (text, ok), = LiWang._one_line(data, Results(sweeps={NOISE: sweep}), [4.0, 16.0], etas).items()
    assert ok is expected
    assert "at the 3 largest eta (from 2:" in text and "not at eta = 1.75" in text
