"""`tflock reproduce jadbabaie --quick`: Jadbabaie-Lin-Morse heading agreement and leader following
(papers/000_2f186d2b28ac1296.txt, Theorems 1, 2 and 4, eqs. 1-2, 17-20, 22).

Reproductions run at the default f32 engine, so this one runs in a subprocess (this process's Taichi is f64).
"""


import pandas as pd

TOL = 0.01  # rad, the experiment's agreement tolerance


def test_jadbabaie_quick_agreement_leader_and_the_failed_premise(tmp_path, reproduce_quick):
    reproduce_quick("jadbabaie", tmp_path)
    for name in ("disagreement-vs-time.png", "agreement-vs-connectivity.png", "final-heading.png", "table.csv",
                 "comparison.md"):
        assert (tmp_path / name).stat().st_size > 0
    table = pd.read_csv(tmp_path / "table.csv")

    def point(leader: bool, rule: str, boundary: str, radius: float) -> pd.Series:
        rows = table[(table.leader == leader) & (table.rule == rule) & (table.boundary == boundary)
                     & (table.radius == radius)]
        assert len(rows) == 1
        return rows.iloc[0]

    small, large = table.radius.min(), table.radius.max()
    # Theorems 1-2: a swarm whose graph stays connected agrees, with either rule (eqs. 2 and 17-20)
    for rule in ("average", "laplacian"):
        best = point(False, rule, "periodic", large)
        assert best.agreed == 1 and best.connected_late == 1 and best.max_e_theta < TOL
    # rule laplacian keeps the plain mean of the headings (F symmetric, F 1 = 1): theta_ss = mean theta(0);
    # rule average's row-stochastic F does not, and the common heading moves off the initial mean
    assert point(False, "laplacian", "periodic", large).max_gap_to_initial_mean < 1e-3
    assert point(False, "average", "periodic", large).median_gap_to_initial_mean > 1e-3
    # more neighbours, more agreement
    assert point(False, "average", "periodic", large).agreed > point(False, "average", "periodic", small).agreed
    # premise violated: in the open plane at small r the groups agree internally and fly apart for good
    isolated = point(False, "average", "open", small)
    assert isolated.agreed == 0 and isolated.split >= 0.75 and isolated.median_e_theta > 0.3
    # Theorem 4: linked to the leader, the followers converge to theta0 itself
    lead = point(True, "average", "periodic", large)
    assert lead.followed == 1 and lead.max_gap_to_theta0 < TOL and lead.median_leader_error < TOL
    # ... but a leader that leaves its followers behind (open plane) is not followed
    lost = point(True, "average", "open", large)
    assert lost.followed == 0 and lost.split >= 0.5 and lost.median_leader_error > 0.3
    # a frozen disagreement in a connected graph is impossible under eqs. 2, 17 and 22
    assert (table.contradictions == 0).all()

    series = {path.name.rsplit("-", 1)[0]: pd.read_csv(path) for path in (tmp_path / "series").glob("*.csv")}
    follow = series["leader-periodic-r2"]["leader_error"].to_numpy()
    assert follow[-1] < TOL < 1 < follow[0]
    assert series["average-open-r0.5"]["e_theta"].iloc[-1] > 0.5  # isolated agents keep their headings

    comparison = (tmp_path / "comparison.md").read_text()
    assert "Our runs agree with the theorems" in comparison and "NO:" not in comparison
