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
    # a Fig. 7 cell whose runs all stop at the cap says so, with no interval for a tau that is not known
    assert f"| 0.9 | none by {CAP} |" in text and f"{CAP} [{CAP}, {CAP}]" not in text
    # the rho variants' fractions that reach the DF with their Wilson interval
    assert "| gamma = 0, minimum separation 1 bl | 1.00 [" in text


def test_report_brackets_the_weights_that_cancel_and_the_model_agrees(make_sim):
    """The report writes '-' for a weight whose force the strategy lacks and brackets one whose force acts alone
    where it acts (Table 1), which eq. (3)'s normalisation cancels, and counts configurations whose weights differ
    only by such a weight or by a common factor of the forces acting together as one model: two S-2.2 runs
    differing only in alpha_cv (Fcv alone outside the VAIR) and two S-1.1 runs differing only in alpha_av (Fav alone
    inside) are the same run to rounding; one differing in alpha_av of S-2.2 is not."""
    import numpy as np

    from tflock.reproduce.formation import effective_weights, weights_text

    row = {"align": 8.0, "cohesion": 1.0, "va_align": 9.0, "va_cohesion": 4.0}
    assert weights_text({**row, "strategy": "S-2.2"}) == "8, -, 9, (4)"
    assert weights_text({**row, "strategy": "S-1.1"}) == "8, -, (9), 4"
    assert weights_text({**row, "strategy": "S-1.3"}) == "8, 1, 9, 4"
    s22 = {**row, "strategy": "S-2.2"}
    assert effective_weights(s22) == effective_weights({**s22, "va_cohesion": 10.0})
    assert effective_weights(s22) == effective_weights({**s22, "align": 16.0, "va_align": 18.0})  # a factor of 2
    assert effective_weights(s22) != effective_weights({**s22, "va_align": 10.0})
    assert effective_weights(s22) != effective_weights({**row, "strategy": "S-1.2"})

    def final(strategy: str, weights: dict[str, float]) -> dict[str, np.ndarray]:
        sim = make_sim(model="formation", steps=400, seed=2, params={"strategy": strategy, "weights": weights})
        sim.run()
        return sim.model.state()

    def same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
        return all(np.allclose(a[k], b[k], rtol=0.0, atol=1e-9) for k in a)

    for strategy, key, values in (("S-2.2", "va_cohesion", (4.0, 10.0)), ("S-1.1", "va_align", (1.0, 7.0))):
        assert same(final(strategy, {key: values[0]}), final(strategy, {key: values[1]})), strategy
    assert not same(final("S-2.2", {"va_align": 4.0}), final("S-2.2", {"va_align": 10.0}))
