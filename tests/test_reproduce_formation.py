"""`tflock reproduce formation --quick`: virtual-agent parallel formations (papers/004), Figs. 4, 6 and 7.

The reproduction runs at the default f32 engine, so in a subprocess (this process's Taichi is f64).
"""


import pandas as pd

CAP = 1200  # the quick runs' length and cap of tau
VAIR = 25.0


def test_formation_quick_reaches_the_desired_formation_and_fails_at_high_p(tmp_path, reproduce_quick):
    out = reproduce_quick("formation", tmp_path / "formation")
    for name in ("fig4-quantifiers.png", "fig6-convergence-s2-2.png", "fig7-tau-failure-noise.png", "table.csv",
                 "comparison.md"):
        assert (out / name).stat().st_size > 0
    table = pd.read_csv(out / "table.csv")
    paper = table[table["sweep"] == "fig4-paper"]
    assert list(paper["figure"]) == ["a", "b", "c", "d", "e", "f"]
    # Fig. 4: the paper's six configurations reach the desired formation (all inside the VAIR, parallel to the
    # VA, at its speed), after a transient of hundreds of time units
    assert (paper["converged_fraction"] == 1).all()
    assert paper["tau_mean"].between(300, CAP - 1).all()
    assert (paper["rho_mean"] <= VAIR).all() and paper["phi_mean"].between(0, 1).all()
    grid = table[table["sweep"] == "grid"]
    assert len(grid) == 2 and (grid["strategy"] == "S-2.2").all()
    # Fig. 7: without failures the DF is reached; at p = 0.9 the agents hardly steer and never reach it
    fig7 = table[table["sweep"] == "fig7"].set_index(["fail_prob", "noise_deg"])["tau_mean"]
    for delta in (0.0, 0.9):
        assert fig7[(0.0, delta)] < 0.8 * CAP
        assert fig7[(0.9, delta)] == CAP
    text = (out / "comparison.md").read_text()
    assert "95 % CI" in text and "### rho: what sets it" in text and "### The torus" in text
