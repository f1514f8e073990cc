"""`tflock reproduce tanner --quick`: Tanner, Jadbabaie & Pappas (papers/001), section 6 and Theorems 1-2.

The reproduction runs at the default f32 engine, so in a subprocess (this process's Taichi is f64).
"""


import pandas as pd


def test_tanner_quick_flocks_as_the_paper_proves(tmp_path, reproduce_quick):
    out = reproduce_quick("tanner", tmp_path / "tanner")
    for name in ("speeds.png", "valencies.png", "flocking.png", "table.csv", "comparison.md"):
        assert (out / name).stat().st_size > 0
    table = pd.read_csv(out / "table.csv").set_index("case")
    assert set(table.index) == {"fixed-random", "fixed-complete", "switching"}
    # Theorems 1-2: on a connected graph every velocity converges to the same vector
    assert (table["connected_fraction"] == 1).all()
    assert (table["sync_fraction"] == 1).all()
    assert (table["velocity_mismatch_max_median"] < 0.01).all()
    assert (table["polarization_mean"] > 0.99).all()
    # eqs. (8) and (12): W and Q never increase along a run (up to f32 rounding)
    for case in ("fixed-random", "fixed-complete", "switching"):
        assert table.loc[case, "lyapunov_nonincreasing_fraction"] == 1
        assert table.loc[case, "lyapunov_largest_relative_rise"] < 1e-4
    # Corollary 3 and section 5: no collisions on a complete graph or with distance-based neighbours; the
    # potential's barrier keeps the agents well apart (d = 1)
    for case in ("fixed-complete", "switching"):
        assert table.loc[case, "near_collision_fraction"] == 0
        assert table.loc[case, "min_distance_min"] > 0.3
        assert table.loc[case, "run_min_distance_min"] > 0.2  # at any sampled time, not only at the end
        assert table.loc[case, "single_min_distance_min"] > 0.2
    # Fig. 6 and Theorem 2 (1): switching stops; the steady graph is not complete (section 6: connectivity "high")
    assert table.loc["switching", "valencies_constant_fraction"] == 1
    assert table.loc["switching", "single_valency_grew_fraction"] == 1
    assert 4 < table.loc["switching", "valency_mean_final"] < 9
    assert table.loc["fixed-complete", "valency_mean_final"] == 9
    # a fixed random graph holds its edges at the potential's minimum V(d) = 1 or above (a local minimum)
    assert table.loc["fixed-random", "potential_per_edge"] >= 1 - 1e-3
    text = (out / "comparison.md").read_text()
    assert "agrees" in text and "does NOT agree" not in text
