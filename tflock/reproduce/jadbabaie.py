"""Jadbabaie, Lin & Morse: heading agreement under joint connectivity, leaderless and with a leader.

papers/000_2f186d2b28ac1296.txt. The noise-free nearest-neighbour rule theta_i(t+1) = <theta_i(t)>_r (eqs. 1-2,
our ``rule = "average"``: the plain mean of the heading values of i and its neighbours within r) drives every
heading to one common value theta_ss when the agents are linked together (their neighbour graphs jointly
connected) across each of a sequence of contiguous bounded intervals (Theorems 1 and 2); theta_ss depends on
theta(0) and on the switching signal. The same holds for the Laplacian rule theta(t+1) = (I - L / g) theta(t) with
g > n (eqs. 17-20, ``rule = "laplacian"``). With a leader (agent 0, fixed heading theta0, eq. 22) the followers'
headings converge to theta0 when the group is linked to its leader across such intervals (Theorem 4). The paper
notes the obvious failure: an agent (or a group) that stays isolated never agrees.

The paper has no simulations and no numbers, so we test its statements on the mobile system whose graphs they are
about: n agents at density 1 in a periodic box (flocks keep meeting on the torus: the premise holds over long
enough intervals) and, as the contrast, in the open plane from the same initial square (flocks that part with
different headings fly apart and are never linked again: the premise fails). The connectivity knob is the radius r
(expected initial neighbour count k = pi r^2 (n - 1) / L^2). Per replica we record the final disagreement e_theta
(mean pairwise wrapped heading difference), the leader error, the R-graph's clusters and the mean pairwise distance
e_d; a replica *agreed* when e_theta < TOL at the end and *followed* when leader_error < TOL.
"""

import math
from typing import Any

import numpy as np
import pandas as pd

from tflock.config import config_to_dict, load_config, tomllib
from tflock.reference import wrap_pi
from tflock.reproduce.experiment import Experiment, Report, Results
from tflock.reproduce.stats import Estimate, mean_ci, proportion_ci, share_text

N = 50
BOX = math.sqrt(N)  # density 1
SPEED = 0.3
THETA0_DEG = 60.0
G = N + 1.0  # eq. (18): any g > n
TOL = 0.01  # rad: "agreed" / "followed"
FROZEN = 1e-6  # rad per step: headings move by f32 rounding only (a few ulp of ~pi)
FLOOR = 1e-7  # below float32's spacing of a heading (2.4e-7 near pi, 4.8e-7 near 2 pi); log plots are clipped there


def expected_neighbours(radius: float) -> float:
    """Mean initial neighbour count of n uniform agents in the L x L box (no edge effects: periodic)."""
    return math.pi * radius**2 * (N - 1) / BOX**2


def initial_mean(config_toml: str) -> float:
    """The plain mean of a replica's initial headings theta(0) in [0, 2 pi) (the model's own initial draw)."""
    from tflock.models.vicsek import initial_state

    config = load_config(tomllib.loads(config_toml))
    return float(initial_state(config.params, config.seed)["theta"].mean())


class Jadbabaie(Experiment):
    """Agreement vs connectivity (radius; periodic box vs open plane), rules average and laplacian, with and
    without a leader: sweeps for the statistics, a few seed-0 runs for the disagreement's time series."""

    name = "jadbabaie"
    title = "Jadbabaie-Lin-Morse: heading agreement under joint connectivity, without and with a leader"
    source = ("papers/000_2f186d2b28ac1296.txt: Theorems 1-2 (eqs. 1-2), the g > n rule (eqs. 17-20), "
              "Theorem 4 (leader, eq. 22); the paper has no figures or tables")
    full_size = "ours (the paper has no simulations; the setup below)"

    def steps(self, quick: bool) -> int:
        return 500 if quick else 3000

    def radii(self, quick: bool) -> list[float]:
        return [0.5, 2.0] if quick else [0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 3.0]

    def _fixed(self, quick: bool, every: int) -> dict[str, Any]:
        steps = self.steps(quick)
        return {"steps": steps, "params.n": N, "params.box": BOX, "params.speed": SPEED, "params.noise": 0.0,
                "params.g": G, "log.metrics_every": max(1, steps // every)}

    def sweeps(self, quick: bool) -> dict[str, dict[str, Any]]:
        radii = self.radii(quick)
        common = {"model": "vicsek", "replicas": 8 if quick else 50, "seed": 0, "set": self._fixed(quick, 50)}
        # quick (CI): rule laplacian and the leader at the largest radius only, rule laplacian in the periodic box
        laplacian = [("periodic", radii[-1])] if quick else [(b, r) for b in ("periodic", "open") for r in radii]
        return {
            "jadbabaie-leaderless": {**common, "grid": {
                "params.rule": ["average"], "params.boundary": ["periodic", "open"], "params.radius": radii,
                "params.leader.enabled": [False]},
                "points": [{"params.rule": "laplacian", "params.boundary": boundary, "params.radius": radius}
                           for boundary, radius in laplacian]},
            "jadbabaie-leader": {**common, "grid": {
                "params.rule": ["average"], "params.boundary": ["periodic", "open"],
                "params.radius": radii[-1:] if quick else radii, "params.leader.enabled": [True],
                "params.leader.heading_deg": [THETA0_DEG]}},
        }

    def series(self, quick: bool) -> dict[str, dict[str, Any]]:
        small, large = 0.5, 2.0
        runs = [("average", "periodic", small, False), ("laplacian", "periodic", large, False),
                ("average", "open", small, False), ("average", "periodic", large, True),
                ("average", "open", large, True)]
        if not quick:
            runs += [("average", "periodic", 1.0, False), ("average", "periodic", large, False),
                     ("average", "periodic", 1.0, True)]
        fixed = self._fixed(quick, 50 if quick else 100)
        return {f"{'leader' if leader else rule}-{boundary}-r{radius:g}": config_to_dict(load_config(
                    {"model": "vicsek", "seed": 0},
                    overrides={**fixed, "params.rule": rule, "params.boundary": boundary, "params.radius": radius,
                               "params.leader.enabled": leader, "params.leader.heading_deg": THETA0_DEG}))
                for rule, boundary, radius, leader in runs}

    def report(self, results: Results, quick: bool) -> Report:
        replicas = pd.concat([classify(results.sweeps["jadbabaie-leaderless"]),
                              classify(results.sweeps["jadbabaie-leader"])], ignore_index=True)
        table = summarise(replicas)
        figures = {"disagreement-vs-time": self._time_figure(results),
                   "agreement-vs-connectivity": self._fraction_figure(table),
                   "final-heading": self._heading_figure(replicas)}
        return Report(figures, table, comparison(table, replicas, self.steps(quick)))

    @staticmethod
    def _time_figure(results: Results) -> Any:
        import matplotlib.pyplot as plt

        figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        for name, series in results.series.items():
            style = {"ls": "--" if "laplacian" in name else ":" if "open" in name else "-"}
            if name.startswith("leader"):
                right.plot(series["step"], np.maximum(series["leader_error"], FLOOR), label=name, **style)
            else:
                left.plot(series["step"], np.maximum(series["e_theta"], FLOOR), label=name, **style)
        left.set_ylabel("heading disagreement (rad, log)")
        left.set_title("leaderless: e_theta (mean pairwise |heading difference|)")
        right.set_title(f"leader (theta0 = {THETA0_DEG:g} deg): leader_error")
        for ax in (left, right):
            ax.set_yscale("log")
            ax.axhline(TOL, color="grey", lw=0.8)
            ax.set_xlabel("step")
            ax.legend(fontsize=7)
        figure.suptitle(f"n = {N}, density 1, v0 = {SPEED}, no noise; seed 0 (grey: tolerance {TOL} rad)\nvalues "
                        f"below {FLOOR:g} rad (finer than float32 resolves a heading near pi) drawn at {FLOOR:g}",
                        fontsize=10)
        figure.tight_layout()
        return figure

    @staticmethod
    def _fraction_figure(table: pd.DataFrame) -> Any:
        import matplotlib.pyplot as plt

        figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        colors = {"periodic": "C0", "open": "C1"}
        for (leader, rule, boundary), group in table.groupby(["leader", "rule", "boundary"]):
            ax, value = (right, "followed") if leader else (left, "agreed")
            intervals = [proportion_ci(int(round(f * n)), n)
                         for f, n in zip(group[value], group["replicas"], strict=True)]
            bars = np.maximum(np.array([[e.value - e.lo, e.hi - e.value] for e in intervals]).T, 0.0)  # (rounding)
            ax.errorbar(group["k_expected"], group[value], yerr=bars, marker="o" if rule == "average" else "s",
                        color=colors[boundary], ls="--" if rule == "laplacian" else "-", capsize=2,
                        label=f"{rule}, {boundary}: {value}")
            if rule == "average":
                ax.plot(group["k_expected"], group["connected_late"], marker="x", color=colors[boundary], ls=":",
                        lw=0.8, label=f"{rule}, {boundary}: graph connected all 2nd half")
        left.set_ylabel("fraction of replicas (bars: Wilson 95 %)")
        left.set_title("leaderless: e_theta < tol at the end")
        right.set_title("leader: followers' leader_error < tol at the end")
        for ax in (left, right):
            ax.set_xscale("log")
            ax.set_xlabel("expected initial neighbours k = pi r^2 (n - 1) / L^2")
            ax.set_ylim(-0.03, 1.03)
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15))
        return figure

    @staticmethod
    def _heading_figure(replicas: pd.DataFrame) -> Any:
        import matplotlib.pyplot as plt

        figure, ax = plt.subplots(figsize=(5.5, 5))
        done = replicas[np.where(replicas["leader"], replicas["followed"], replicas["agreed"])]
        styles = {(False, "average"): ("o", "C0", "rule average, leaderless"),
                  (False, "laplacian"): ("x", "C1", "rule laplacian, leaderless"),
                  (True, "average"): ("s", "C3", "rule average, with leader")}
        for (leader, rule), group in done.groupby(["leader", "rule"]):
            marker, color, label = styles[leader, rule]
            paint = {"color": color} if marker == "x" else {"facecolors": "none", "edgecolors": color}
            ax.scatter(np.degrees(group["initial_mean"]), np.degrees(group["final_heading"]), s=16, marker=marker,
                       label=label, **paint)
        lo, hi = np.degrees(done["initial_mean"]).min() - 5, np.degrees(done["initial_mean"]).max() + 5
        ax.plot([lo, hi], [lo, hi], color="grey", lw=0.8, label="theta_ss = mean theta(0)")
        ax.axhline(THETA0_DEG, color="C3", lw=0.8, ls="--", label="theta0")
        ax.set_xlabel("mean of the initial headings theta(0) (deg)")
        ax.set_ylabel("common heading at the end (deg)")
        ax.set_title("replicas that agreed / followed (all boundaries and radii)", fontsize=9)
        ax.legend(fontsize=7)
        return figure


def classify(sweep: pd.DataFrame) -> pd.DataFrame:
    """One row per replica: its point's values and what happened to it.

    ``agreed``: final e_theta < TOL. ``followed`` (leader runs): final leader_error < TOL. ``connected_late``: the
    R-graph had one component at every logged step of the second half (Theorem 1's premise, seen on that window).
    ``split``: not agreed (or, with a leader, not followed) although the headings froze in the second half
    (de_theta, the agents' mean change per step, averaged over the logged steps, < FROZEN), in a disconnected
    graph, while the mean pairwise distance still grows: the groups move apart rigidly with different headings,
    and in the open plane they do not turn towards each other again (the premise of Theorems 2 and 4 fails).
    ``contradiction``: frozen disagreement in a connected graph, which eqs. (2), (17) and (22) forbid (a fixed
    point of a connected F has one common heading, the leader's with a leader).
    """
    leader = sweep["params.leader.enabled"].astype(bool).to_numpy()
    agreed = sweep["final_e_theta"].to_numpy() < TOL
    error = sweep["final_leader_error"].to_numpy() if "final_leader_error" in sweep else np.full(len(sweep), np.nan)
    followed = error < TOL
    done = np.where(leader, followed, agreed)
    frozen = sweep["mean_de_theta"].to_numpy() < FROZEN
    apart = sweep["final_e_d"].to_numpy() > sweep["mean_e_d"].to_numpy() * (1 + 1e-3)
    connected_end = sweep["final_clusters"].to_numpy() == 1
    return pd.DataFrame({
        "rule": sweep["params.rule"], "boundary": sweep["params.boundary"], "leader": leader,
        "radius": sweep["params.radius"], "k_expected": sweep["params.radius"].map(expected_neighbours),
        "replica": sweep["replica"], "seed": sweep["seed"],
        "agreed": agreed, "followed": np.where(leader, followed, False),
        "connected_late": np.isclose(sweep["mean_clusters"].to_numpy(), 1.0),
        "frozen": frozen, "split": ~done & frozen & ~connected_end & apart,
        "contradiction": ~done & frozen & connected_end,
        "final_e_theta": sweep["final_e_theta"], "final_leader_error": error,
        "final_clusters": sweep["final_clusters"], "final_largest_cluster": sweep["final_largest_cluster"],
        "final_heading": sweep["final_mean_heading"], "initial_mean": sweep["config"].map(initial_mean),
    })


def summarise(replicas: pd.DataFrame) -> pd.DataFrame:
    """One row per point: fractions of replicas agreed / followed / connected / split, medians of the final
    errors, clusters, and the gaps of the common heading to the mean of theta(0) (leaderless) and to theta0."""
    rows = []
    keys = ["leader", "rule", "boundary", "radius"]
    for (leader, rule, boundary, radius), group in replicas.groupby(keys, sort=True):
        follow, agree = group[group["followed"]], group[group["agreed"] & ~group["leader"]]
        rows.append({
            "leader": bool(leader), "rule": rule, "boundary": boundary, "radius": float(radius),
            "k_expected": expected_neighbours(radius), "replicas": len(group),
            "agreed": group["agreed"].mean(), "followed": group["followed"].mean() if leader else np.nan,
            "connected_late": group["connected_late"].mean(), "split": group["split"].mean(),
            "contradictions": int(group["contradiction"].sum()),
            "agreed_if_connected_late": group.loc[group["connected_late"], "agreed"].mean()
            if group["connected_late"].any() else np.nan,
            "median_e_theta": group["final_e_theta"].median(), "max_e_theta": group["final_e_theta"].max(),
            "median_leader_error": group["final_leader_error"].median() if leader else np.nan,
            "max_leader_error": group["final_leader_error"].max() if leader else np.nan,
            "clusters": group["final_clusters"].mean(), "clusters_lo": mean_ci(group["final_clusters"]).lo,
            "clusters_hi": mean_ci(group["final_clusters"]).hi,
            "largest_cluster": group["final_largest_cluster"].mean(),
            "median_gap_to_initial_mean": float(np.median(np.abs(wrap_pi(
                agree["final_heading"] - agree["initial_mean"])))) if len(agree) else np.nan,
            "max_gap_to_initial_mean": float(np.abs(wrap_pi(agree["final_heading"] - agree["initial_mean"])).max())
            if len(agree) else np.nan,
            "max_gap_to_theta0": float(np.abs(wrap_pi(follow["final_heading"] - math.radians(THETA0_DEG))).max())
            if len(follow) else np.nan,
        })
    return pd.DataFrame(rows)


def _rows(table: pd.DataFrame) -> list[str]:
    lines = ["| leader | rule | boundary | r | k | agreed | followed | graph connected all 2nd half | "
             "agreed if so | split for good | median e_theta (max) | median leader_error (max) | final clusters |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table.itertuples():
        n, connected = row.replicas, row.connected_late * row.replicas
        clusters = Estimate(row.clusters, row.clusters_lo, row.clusters_hi, n)
        lines.append(f"| {'yes' if row.leader else 'no'} | {row.rule} | {row.boundary} | {row.radius:g} | "
                     f"{row.k_expected:.1f} | {share_text(row.agreed, n)} | {share_text(row.followed, n)} | "
                     f"{share_text(row.connected_late, n)} | {share_text(row.agreed_if_connected_late, connected)} | "
                     f"{share_text(row.split, n)} | {row.median_e_theta:.2g} ({row.max_e_theta:.2g}) | "
                     f"{'-' if not row.leader else f'{row.median_leader_error:.2g} ({row.max_leader_error:.2g})'} | "
                     f"{clusters.short(1)} |")
    return lines


def comparison(table: pd.DataFrame, replicas: pd.DataFrame, steps: int) -> str:
    """The theorems' statements next to what the replicas did, with a verdict computed from the data."""

    def point(leader: bool, rule: str, boundary: str, radius: float) -> pd.Series:
        return table[(table.leader == leader) & (table.rule == rule) & (table.boundary == boundary)
                     & (table.radius == radius)].iloc[0]

    r_max, r_min = table["radius"].max(), table["radius"].min()
    best = {rule: point(False, rule, "periodic", r_max) for rule in ("average", "laplacian")}
    lead = point(True, "average", "periodic", r_max)
    lone_open = point(False, "average", "open", r_min)
    lone, led = replicas[~replicas["leader"]], replicas[replicas["leader"]]
    connected, led_connected = lone[lone["connected_late"]], led[led["connected_late"]]
    undone = replicas[~np.where(replicas["leader"], replicas["followed"], replicas["agreed"])]
    open_undone = undone[undone["boundary"] == "open"]
    periodic_undone = undone[undone["boundary"] == "periodic"]
    contradictions = int(replicas["contradiction"].sum())
    followed = led[led["followed"]]
    followed_gap = float(np.abs(wrap_pi(followed["final_heading"] - math.radians(THETA0_DEG))).max()) \
        if len(followed) else math.nan
    agreed = lone[lone["agreed"]].assign(gap=lambda f: np.abs(wrap_pi(f["final_heading"] - f["initial_mean"])))
    gap = {rule: group["gap"].to_numpy() for rule, group in agreed.groupby("rule")}
    laplacian_gap = float(gap["laplacian"].max()) if "laplacian" in gap else math.inf
    average_gap = gap.get("average", np.array([math.nan]))
    # the same theta(0) (seed) under different switching signals (radii, boundaries): theta_ss moves with sigma
    spread = agreed.groupby(["rule", "seed"])["final_heading"].agg(lambda h: float(np.ptp(np.unwrap(h))))
    moved = {rule: float(np.median(spread[rule])) if rule in spread.index.get_level_values(0) else math.nan
             for rule in ("average", "laplacian")}
    pairs = table[~table["leader"]].pivot_table(index=["boundary", "radius"], columns="rule",
                                                values=["agreed", "clusters"]).dropna()
    def share(row: pd.Series, column: str) -> str:
        return share_text(row[column], row["replicas"])

    checks = {
        f"well-connected periodic swarms agree (Theorems 1-2, both rules; r = {r_max:g}, agreed: "
        f"{', '.join(rule + ' ' + share(b, 'agreed') for rule, b in best.items())})":
            all(b["agreed"] == 1 for b in best.values()),
        f"every replica whose graph stayed connected agreed (Theorem 1; {int(connected['agreed'].sum())} of "
        f"{len(connected)})":
            len(connected) > 0 and bool(connected["agreed"].all()),
        f"with a leader they follow theta0 (Theorem 4; periodic box, r = {r_max:g}, followed: "
        f"{share(lead, 'followed')})":
            lead["followed"] == 1 and lead["max_gap_to_theta0"] < TOL,
        "rule laplacian: theta_ss = mean theta(0), whatever the graphs (not stated in the paper: it follows from "
        "eqs. 17-20, whose I - L / g keeps the mean of the headings)": laplacian_gap < TOL,
        f"where the premise fails, agreement fails (the paper: an agent that stays isolated cannot agree; here "
        f"groups: in the open plane at r = {r_min:g}, split for good {share(lone_open, 'split')}, a proxy that "
        f"counts only replicas that did not agree, and agreed {share(lone_open, 'agreed')}; our bar: at least half "
        "split, at most a quarter agree)":
            lone_open["agreed"] <= 0.25 and lone_open["split"] >= 0.5,
        "no frozen disagreement in a connected graph (not stated in the paper: a consequence of Theorem 1)":
            contradictions == 0,
    }
    verdict = "agree" if all(checks.values()) else "do NOT fully agree"
    return "\n".join([
        "The paper proves (no simulations, no numbers): without a leader, all headings converge to one common "
        "theta_ss, depending on theta(0) and the switching signal, whenever the agents are linked together "
        "(neighbour graphs jointly connected) across each of a sequence of contiguous bounded intervals "
        "(Theorem 2; Theorem 1 when the graph is connected at every step), for the Vicsek average (eqs. 1-2) and "
        "for the g > n Laplacian rule (eqs. 17-20); with a leader, the followers converge to the leader's theta0 "
        "whenever they are linked to it across such intervals (Theorem 4). An agent or group that stays "
        "isolated cannot agree.",
        "",
        f"Setup: n = {N} agents (with a leader, agent 0 is the leader), density 1 (L = {BOX:.3f}), v0 = {SPEED}, "
        f"no noise, g = {G:g}, theta0 = {THETA0_DEG:g} deg, {steps} steps, {int(table['replicas'].iloc[0])} "
        f"replicas per point (the same seeds, so the same theta(0), at every point); agreed = final e_theta < "
        f"{TOL} rad, followed = final leader_error < {TOL} rad; k = pi r^2 (n - 1) / L^2, the expected initial "
        "neighbour count. The premise (joint connectivity over bounded intervals, forever) cannot be checked on "
        "a finite run; two proxies: *graph connected all 2nd half* (one R-graph component at every logged step "
        "of the second half: Theorem 1's premise on that window), and *split for good* (not agreed, the headings "
        f"frozen: their mean change per step (de_theta, the mean over the agents of the step's |change|), averaged "
        f"over the logged steps of the second half, below {FROZEN:g} rad, the final graph disconnected and the "
        "mean pairwise distance still growing: groups that move apart rigidly with different headings; in the "
        "open plane such groups do not turn towards each other again, so the premise fails). Fractions are written "
        "mean [low, high] with "
        "Wilson's 95 % interval over the replicas of the point (over those whose graph stayed connected for "
        "*agreed if so*), final clusters with the t interval, median e_theta with the largest in parentheses.",
        "",
        *_rows(table),
        "",
        f"Our runs {verdict} with the theorems:",
        "",
        *[f"- {'yes' if ok else 'NO'}: {claim}" for claim, ok in checks.items()],
        "",
        f"- Theorem 1 on the window: {len(connected)} leaderless replicas kept a connected graph through the "
        f"second half; {int(connected['agreed'].sum())} of them agreed. With a leader, {len(led_connected)} did, "
        f"and {int(led_connected['followed'].sum())} of those followed theta0.",
        f"- Replicas that did not reach the common heading (theta0 with a leader): {len(undone)}. In the open "
        f"plane: {len(open_undone)}, of which {int(open_undone['split'].sum())} split for good: the premise is "
        "violated, their groups, each internally agreed, fly apart with different headings; with a leader, the "
        "followers that lost the link to the leader keep headings other than theta0. In the periodic box: "
        f"{len(periodic_undone)}, {int((periodic_undone['frozen'] & (periodic_undone['final_clusters'] > 1)).sum())}"
        " of them frozen in disconnected groups at the end, the others still changing; on the torus the groups "
        "meet again, so these runs were cut short (the premise holds only over intervals longer than the run), "
        "they are not counterexamples.",
        "- theta_ss depends on theta(0) and on the switching signal (Theorems 1-2). Rule laplacian: F = I - L / g "
        "is symmetric with F 1 = 1 (eq. 20), so it keeps the plain mean of the headings and theta_ss is the mean "
        f"of theta(0) whatever the graphs (largest gap over {len(gap.get('laplacian', []))} agreed replicas: "
        f"{laplacian_gap:.1e} rad; median spread of theta_ss of one seed across points {moved['laplacian']:.1e} "
        "rad). Rule average: F = (I + D)^-1 (I + A) is not symmetric, so theta_ss is another weighted mean of "
        f"theta(0) (gap to the plain mean: median {np.median(average_gap):.3f}, largest {np.max(average_gap):.3f} "
        f"rad over {len(average_gap)} agreed replicas) that moves with the graphs (median spread of one seed's "
        f"theta_ss across points: {moved['average']:.3f} rad). Both lie near pi: headings are real numbers drawn "
        f"in [0, 2 pi), not circular averages. With the leader every one of the {len(followed)} replicas that "
        f"followed ends at theta0 whatever theta(0) (largest |mean heading - theta0| over them: {followed_gap:.1e} "
        f"rad; {lead['max_gap_to_theta0']:.1e} rad at r = {r_max:g} in the periodic box). Figure final-heading.",
        "- Rule laplacian moves a heading by (1/g) sum (theta_j - theta_i) per step, less than rule average's "
        "full step to the local mean since g > n: where both rules ran, laplacian agreed in "
        f"{int((pairs['agreed']['laplacian'] <= pairs['agreed']['average']).sum())} of {len(pairs)} points no "
        f"more often than average, and left at least as many clusters in "
        f"{int((pairs['clusters']['laplacian'] >= pairs['clusters']['average']).sum())} of {len(pairs)}"
        + (" (in the open plane its agents scatter before they align)." if "open" in pairs.index else "."),
        f"- Frozen disagreements in a connected final graph (impossible under eqs. 2, 17, 22): {contradictions}.",
    ])
