"""Tanner, Jadbabaie & Pappas: flocking with fixed and switching interconnection topology (section 6, Figs. 4-8).

papers/001_af6368bcf7ea0ea2.txt, section 6: ten double integrators (eq. 1) under the control law (3), alignment
plus the gradient of a pair potential V, positions uniform in (-2.5, 2.5)^2 m, speeds uniform in (0, 1) m/s in
random directions, 100 simulated seconds; fixed topology: a random connected 0-1 adjacency matrix (Figs. 4, 7);
switching topology: neighbours within R = 2 m (Figs. 5, 6, 8). The paper gives neither V's formula (Definition 2
and Fig. 2 give its properties), nor d, nor its integrator, nor its random graph: we use V(r) = d^2 / r^2 + ln r^2
with d = 1 m, semi-implicit Euler with dt = 0.01 s (so 10,000 steps), edges with probability 0.3 and at least
0.25 m between agents at the start (configs/papers/tanner-*.toml).

What the paper shows and proves, and what we measure:

- Theorems 1-2: the velocities converge to a common vector (all pairwise differences -> 0) if the graph is
  connected; Figs. 7-8 show the speeds converging. Ours: the per-agent speeds of one fixed and one switching run
  (the figures' equivalents), and over replicas the fraction with ``velocity_mismatch_max`` below 1 cm/s at the end.
- eq. (8) / eq. (12): W (fixed, eq. 5) and Q (switching, eq. 10) never increase. Ours: the largest one-step rise
  of W / Q along each single run (metrics every step at full size), relative to its total fall.
- Corollary 3 and section 5: no collisions, at any time, with a complete fixed graph or with the distance-based
  switching graph; section 6 (Fig. 4): with a fixed incomplete graph, agents that are not neighbours "may come
  dangerously close". Ours: the smallest pairwise distance over the whole run (sampled every 0.1 s) in replicas of
  a random fixed graph, a complete one and switching.
- Theorem 2, conclusion (1), and Fig. 6: switching stops, the valencies grow and then stay constant; the steady
  graph is well connected but "not necessarily complete". Ours: the valencies over time, the mean valency's growth
  in every single switching run, and over replicas the fraction whose valencies do not change over the second
  half.
- The potential is (locally) minimised: the agents stop changing their relative positions, so the potential energy
  is constant at the end. Ours: its standard deviation over the second half.

Figs. 4-5 are position snapshots; the metrics hold no positions (``tflock sim --config
configs/papers/tanner-fixed.toml`` records them for the viewer), so the reproduction plots the quantities the
snapshots illustrate: the velocity mismatch, W / Q, the minimum distance and lambda_2.
"""

import math
from typing import Any

import numpy as np
import pandas as pd

from tflock.reproduce.experiment import Experiment, Report, Results, Series
from tflock.reproduce.stats import Estimate, mean_ci, share_text

N = 10
D = 1.0  # desired distance d: the minimum of V
SETUP = {  # section 6 (see configs/papers/tanner-*.toml)
    "params.n": N, "params.dim": 2, "params.box": 5.0, "params.radius": 2.0, "params.desired_distance": D,
    "params.speed": 1.0, "params.dt": 0.01, "params.graph_p": 0.3, "params.min_separation": 0.25,
    "params.lambda2_every": 10,
}
CASES = {  # name -> the topology keys of the sweep point
    "fixed-random": {"params.topology": "fixed", "params.graph": "random"},
    "fixed-complete": {"params.topology": "fixed", "params.graph": "complete"},
    "switching": {"params.topology": "switching"},
}
SYNC_TOL = 0.01  # m/s: velocities "synchronised" when max |v_i - mean v| is below 1 % of the initial speed scale
CLOSE = 0.01 * D  # a minimum distance below 1 % of d, at any sample of the run, counts as a (near) collision
RISE_TOL = 1e-4  # largest one-step rise of W / Q allowed, relative to its total fall (f32 rounding)
STILL_TOL = 1e-3  # potential energy "at rest": its std over the second half (50 s at full size) below this


def pair_potential(r: float) -> float:
    """The pair potential V(r) = d^2 / r^2 + ln r^2 (papers/001 Fig. 2; our potential model)."""
    return D * D / (r * r) + math.log(r * r)


def _config(topology: str, seed: int, steps: int, metrics_every: int) -> dict[str, Any]:
    """A single run's config dict (nested, as a config file)."""
    params = {key.removeprefix("params."): value for key, value in SETUP.items()}
    params.update({key.removeprefix("params."): value for key, value in CASES[topology].items()})
    return {"model": "potential", "seed": seed, "steps": steps, "params": params,
            "log": {"metrics_every": metrics_every}}


def _lyapunov(series: Series) -> np.ndarray:
    return np.asarray(series["W"] if "W" in series else series["Q"], dtype=float)


def _valency_ends(series: Series) -> tuple[float, float]:
    """The mean valency of a switching run at its first and last sample."""
    start, end = (float(np.mean([series[f"valency_{i}"][k] for i in range(N)])) for k in (0, -1))
    return start, end


def _sync_time(series: Series) -> float:
    """First time after which max |v_i - mean v| stays below SYNC_TOL (nan if it never does)."""
    below = np.asarray(series["velocity_mismatch_max"]) < SYNC_TOL
    if not below[-1]:
        return math.nan
    last_above = np.flatnonzero(~below)
    index = 0 if last_above.size == 0 else last_above[-1] + 1
    return float(series["time"][index])


class Tanner(Experiment):
    name = "tanner"
    title = "Tanner-Jadbabaie-Pappas flocking: fixed vs switching topology (speeds, valencies, Lyapunov function)"
    source = ("Tanner, Jadbabaie & Pappas, papers/001_af6368bcf7ea0ea2.txt, section 6, Figs. 4-8 "
              "(Theorems 1-2, Corollary 3)")

    @staticmethod
    def steps(quick: bool) -> int:
        return 3000 if quick else 10000  # 30 s (speeds within 1 cm/s) or the paper's 100 s

    @staticmethod
    def seeds(quick: bool) -> list[int]:
        """Seeds of the single runs of each topology (seed 0 is the one plotted)."""
        return [0] if quick else list(range(5))

    def sweeps(self, quick: bool) -> dict[str, dict[str, Any]]:
        steps = self.steps(quick)
        return {
            "tanner-replicas": {
                "model": "potential",
                "replicas": 1 if quick else 20,
                "seed": 1 if quick else 0,  # quick: another seed than the single runs'
                "set": {"steps": steps, **SETUP, "log.metrics_every": 10},  # min_min_distance: every 0.1 s
                "points": list(CASES.values()),
            },
        }

    @staticmethod
    def every(quick: bool) -> int:
        """Steps between the single runs' samples: every step at full size (W / Q's one-step rises), every 0.3 s
        with --quick."""
        return 30 if quick else 1

    def series(self, quick: bool) -> dict[str, dict[str, Any]]:
        return {f"{topology}-s{seed}": _config(topology, seed, self.steps(quick), self.every(quick))
                for topology in CASES for seed in self.seeds(quick)}

    def report(self, results: Results, quick: bool) -> Report:
        table = self._table(results)
        figures = {"speeds": self._speeds(results), "valencies": self._valencies(results),
                   "flocking": self._flocking(results)}
        return Report(figures, table, self._comparison(table, results, quick))

    # ------------------------------------------------------------------------------------------------------
    # Numbers.

    @staticmethod
    def _case(row: pd.Series) -> str:
        if row["params.topology"] == "switching":
            return "switching"
        return f"fixed-{row['params.graph']}"

    def _table(self, results: Results) -> pd.DataFrame:
        """One row per case: statistics over the sweep's replicas, and over the single runs of that case."""
        sweep = results.sweeps["tanner-replicas"].copy()
        sweep["case"] = sweep.apply(self._case, axis=1)
        rows = []
        for case in CASES:
            group = sweep[sweep["case"] == case]
            connected = group["mean_connected"] >= 1
            synced = group["final_velocity_mismatch_max"] < SYNC_TOL
            edges = group["final_valency_mean"] * N / 2
            valencies_still = (group[["std_valency_mean", "std_valency_min", "std_valency_max"]] < 1e-9).all(axis=1)
            row = {
                "case": case, "replicas": len(group),
                "connected_fraction": connected.mean(),  # connected over the whole second half
                "sync_fraction": synced.mean(),
                "sync_fraction_connected": synced[connected].mean() if connected.any() else math.nan,
                "velocity_mismatch_max_median": group["final_velocity_mismatch_max"].median(),
                "polarization_mean": group["final_polarization"].mean(),
                "min_distance_min": group["final_min_distance"].min(),
                "min_distance_median": group["final_min_distance"].median(),
                "run_min_distance_min": group["min_min_distance"].min(),  # over the whole run
                "near_collision_fraction": (group["min_min_distance"] < CLOSE).mean(),
                "valencies_constant_fraction": valencies_still.mean(),
                "valency_mean_final": group["final_valency_mean"].mean(),
                "valency_mean_final_lo": mean_ci(group["final_valency_mean"]).lo,
                "valency_mean_final_hi": mean_ci(group["final_valency_mean"]).hi,
                "potential_still_fraction": (group["std_potential_energy"] < STILL_TOL).mean(),
                # fixed graphs: the potential per edge, V(d) (= 1 for d = 1) when every edge sits at d
                "potential_per_edge": (group["final_potential_energy"] / edges).mean()
                if case != "switching" else math.nan,
                "lambda2_mean": group["final_lambda2"].mean(),
            }
            runs = [s for name, s in results.series.items() if name.rsplit("-s", 1)[0] == case]
            if runs:
                rises = [self._rise(s) for s in runs]
                synced = [t for t in map(_sync_time, runs) if not math.isnan(t)]  # the runs that synchronised
                row.update({
                    "single_runs": len(runs),
                    "lyapunov_nonincreasing_fraction": float(np.mean([r <= RISE_TOL for r in rises])),
                    "lyapunov_largest_relative_rise": float(np.max(rises)),
                    "single_min_distance_min": float(min(np.min(s["min_distance"]) for s in runs)),
                    "single_valency_grew_fraction": float(np.mean([end > start for start, end
                                                                   in map(_valency_ends, runs)]))
                    if case == "switching" else math.nan,
                    **{f"single_sync_time_{name}": float(statistic(synced)) if len(synced) else math.nan
                       for name, statistic in (("median", np.median), ("min", np.min), ("max", np.max))},
                })
            rows.append(row)
        return pd.DataFrame(rows)

    @staticmethod
    def _rise(series: Series) -> float:
        """Largest rise of W / Q from one sample to the next (one step at full size) relative to its total fall
        (<= 0: never rises)."""
        w = _lyapunov(series)
        fall = max(w[0] - w.min(), 1e-12)
        return float(np.max(np.diff(w)) / fall)

    # ------------------------------------------------------------------------------------------------------
    # Figures.

    @staticmethod
    def _first(results: Results, case: str) -> Series:
        return results.series[f"{case}-s0"]

    def _speeds(self, results: Results) -> Any:
        """Figs. 7-8: every agent's speed over time, fixed and switching topology."""
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
        for ax, case, label in zip(axes, ("fixed-random", "switching"), ("Fig. 7: fixed topology",
                                                                          "Fig. 8: switching topology (R = 2 m)"),
                                   strict=True):
            series = self._first(results, case)
            for i in range(N):
                ax.plot(series["time"], series[f"speed_{i}"], lw=1)
            ax.set_xlabel("time (s)")
            ax.set_title(label)
        axes[0].set_ylabel("speed |v_i| (m/s)")
        figure.suptitle("Convergence of speeds (N = 10, seed 0)")
        return figure

    def _valencies(self, results: Results) -> Any:
        """Fig. 6: the valency of every agent over time, switching topology."""
        import matplotlib.pyplot as plt

        series = self._first(results, "switching")
        figure, ax = plt.subplots(figsize=(6, 3.8))
        for i in range(N):
            ax.step(series["time"], np.asarray(series[f"valency_{i}"]) + 0.04 * (i - N / 2), where="post", lw=1)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("valency (neighbours within R)")
        ax.set_ylim(-0.5, N - 0.5)
        ax.set_title("Fig. 6: valencies, switching topology (seed 0; lines offset slightly)")
        return figure

    def _flocking(self, results: Results) -> Any:
        """Figs. 4-5 in numbers: velocity mismatch, W / Q, minimum distance and lambda_2, fixed and switching."""
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(2, 2, figsize=(10, 7))
        for case, label in (("fixed-random", "fixed"), ("switching", "switching")):
            series = self._first(results, case)
            t = series["time"]
            axes[0, 0].semilogy(t, np.maximum(series["velocity_mismatch_max"], 1e-9), label=label)
            axes[0, 1].plot(t, _lyapunov(series), label="W (eq. 5)" if "W" in series else "Q (eq. 10) - const")
            axes[1, 0].semilogy(t, np.maximum(series["min_distance"], 1e-9), label=label)
            axes[1, 1].plot(t, series["lambda2"], label=label)
        axes[0, 0].axhline(SYNC_TOL, color="grey", ls=":", lw=1)
        axes[0, 0].set_ylabel("max |v_i - mean v| (m/s)")
        axes[0, 1].set_ylabel("Lyapunov function")
        axes[1, 0].axhline(D, color="grey", ls=":", lw=1)
        axes[1, 0].set_ylabel("min pairwise distance (m)")
        axes[1, 1].set_ylabel("lambda_2 of the graph Laplacian")
        for ax in axes.flat:
            ax.set_xlabel("time (s)")
            ax.legend()
        figure.suptitle("Flocking with fixed vs switching topology (N = 10, seed 0; dotted: the 0.01 m/s sync "
                        "threshold, top left, and d = 1 m, bottom left)")
        figure.tight_layout()
        return figure

    # ------------------------------------------------------------------------------------------------------
    # Comparison.

    @staticmethod
    def _comparison(table: pd.DataFrame, results: Results, quick: bool) -> str:
        rows = table.set_index("case")
        fr, fc, sw = rows.loc["fixed-random"], rows.loc["fixed-complete"], rows.loc["switching"]
        switching = results.series["switching-s0"]
        runs = [series for name, series in results.series.items() if name.startswith("switching-")]
        starts, ends = ([bool(series["connected"][k]) for series in runs] for k in (0, -1))
        valency_start, valency_end = _valency_ends(switching)

        def pct(x: float, n: float | None = None) -> str:
            """A fraction in per cent; of `n` replicas, with its Wilson 95 % interval."""
            if n is not None:
                return share_text(x, n, percent=True)
            return "n/a" if math.isnan(x) else f"{100 * x:.0f} %"

        lines = ["| case | replicas | connected | velocities synchronised (all / connected) | "
                 "final min distance (min / median, m) | min distance over the run (m) | near collisions over the "
                 "run (< 0.01 d) | valencies constant (2nd half) | mean final valency | potential at rest |",
                 "|---|---|---|---|---|---|---|---|---|---|"]
        for case, r in rows.iterrows():
            n, connected = r.replicas, r.connected_fraction * r.replicas
            valency = Estimate(r.valency_mean_final, r.valency_mean_final_lo, r.valency_mean_final_hi, n)
            lines.append(f"| {case} | {int(n)} | {pct(r.connected_fraction, n)} | {pct(r.sync_fraction, n)} / "
                         f"{pct(r.sync_fraction_connected, connected)} | {r.min_distance_min:.3g} / "
                         f"{r.min_distance_median:.3g} | {r.run_min_distance_min:.3g} | "
                         f"{pct(r.near_collision_fraction, n)} | "
                         f"{pct(r.valencies_constant_fraction, n)} | "
                         f"{valency.short()} | "
                         f"{pct(r.potential_still_fraction, n)} |")
        every = Tanner.every(quick)
        step = "one-step" if every == 1 else f"{every}-step"
        single = [f"| case | single runs | W / Q non-increasing | largest {step} rise / total fall | "
                  "min distance over the run (m) | time to sync (median, min-max, s) |", "|---|---|---|---|---|---|"]
        for case in CASES:
            r = rows.loc[case]
            single.append(f"| {case} | {int(r.single_runs)} | {pct(r.lyapunov_nonincreasing_fraction)} | "
                          f"{r.lyapunov_largest_relative_rise:.1e} | {r.single_min_distance_min:.3g} | "
                          f"{r.single_sync_time_median:.1f} ({r.single_sync_time_min:.1f}-"
                          f"{r.single_sync_time_max:.1f}) |")

        still = {case: r.potential_still_fraction for case, r in rows.iterrows()}
        if quick:
            at_rest = "not checked at the quick size (30 s runs: the potential is still settling)"
        elif min(still.values()) == 1:
            at_rest = "agrees"
        else:
            at_rest = "agrees only in part: still settling at the end in " + ", ".join(
                f"{pct(1 - f, rows.loc[case].replicas)} of the {case} runs" for case, f in still.items() if f < 1) \
                + " (the theorems say where the motion ends, not how soon: a run of the paper's 100 s may stop short)"
        sw_valency = Estimate(sw.valency_mean_final, sw.valency_mean_final_lo, sw.valency_mean_final_hi, sw.replicas)
        grew = sw.single_valency_grew_fraction
        checks = {
            f"velocities converge to a common vector on a connected graph (Theorems 1-2; synchronised among the "
            f"replicas connected throughout the second half: fixed random "
            f"{pct(fr.sync_fraction_connected, fr.connected_fraction * fr.replicas)},"
            f" complete {pct(fc.sync_fraction_connected, fc.connected_fraction * fc.replicas)}, switching "
            f"{pct(sw.sync_fraction_connected, sw.connected_fraction * sw.replicas)}, of the "
            f"{round(sw.connected_fraction * sw.replicas)} of {int(sw.replicas)} switching replicas connected; over "
            f"all switching replicas {pct(sw.sync_fraction, sw.replicas)} synchronised, where the paper's one "
            "switching run did: our random start does not keep the graph connected, which the theorems assume)":
                min(fr.sync_fraction_connected, fc.sync_fraction_connected, sw.sync_fraction_connected) == 1,
            f"W and Q never increase (eqs. 8, 12; non-increasing, up to {step} rises of {RISE_TOL:g} of the "
            f"total fall (float32 rounding), over the whole run in "
            f"{pct(fr.lyapunov_nonincreasing_fraction, fr.single_runs)} of the fixed-random, "
            f"{pct(fc.lyapunov_nonincreasing_fraction, fc.single_runs)} of the fixed-complete and "
            f"{pct(sw.lyapunov_nonincreasing_fraction, sw.single_runs)} of the switching single runs, largest {step} "
            f"rise {rows['lyapunov_largest_relative_rise'].max():.1e} of the total fall)":
                rows["lyapunov_nonincreasing_fraction"].min() == 1,
            f"no collisions at any time with a complete fixed graph (Corollary 3) or with switching (section 5; "
            f"replicas that came within {CLOSE:g} m at a sample, every 0.1 s: "
            f"{pct(fc.near_collision_fraction, fc.replicas)} and {pct(sw.near_collision_fraction, sw.replicas)}; "
            f"smallest distance in the single runs, sampled every {'step' if every == 1 else f'{every} steps'}: "
            f"{fc.single_min_distance_min:.3g} and "
            f"{sw.single_min_distance_min:.3g} m)":
                fc.near_collision_fraction == 0 and sw.near_collision_fraction == 0
                and min(fc.single_min_distance_min, sw.single_min_distance_min) >= CLOSE,
            f"switching stops and the valencies settle (Theorem 2 (1), Fig. 6; constant in the second half in "
            f"{pct(sw.valencies_constant_fraction, sw.replicas)} of the replicas)": sw.valencies_constant_fraction == 1,
            f"the valencies grow (section 6, Fig. 6; the mean valency ends above its start in "
            f"{pct(grew, sw.single_runs)} of the {int(sw.single_runs)} single switching runs)": grew == 1,
            "the potential settles at a (local) minimum: relative positions at rest (Theorems 1-2)": at_rest,
        }
        words = {True: "agrees", False: "does NOT agree"}
        verdicts = [f"- {claim}: **{words.get(ok, ok)}**" for claim, ok in checks.items()]
        return "\n".join([
            "Tanner, Jadbabaie & Pappas prove that under control law (3) on a connected graph all velocities become "
            "the same, W (eq. 5; fixed graph) or Q (eq. 10; switching graph) never increases, the agents' potentials "
            "reach a local minimum and, on a complete or distance-based graph, no two agents collide; their section "
            "6 (N = 10, 100 s) shows the speeds converging (Figs. 7-8), the valencies of the switching graph rising "
            "then freezing (Fig. 6), and on a fixed incomplete graph two agents that are not neighbours ending "
            "'dangerously close' (Fig. 4). Our runs (V(r) = d^2 / r^2 + ln r^2 with d = 1 m, dt = 0.01 s, random "
            "graphs with edge probability 0.3 and 0.25 m between agents at the start, none of which the paper gives; "
            f"velocities 'synchronised' when max |v_i - mean v| < {SYNC_TOL} m/s at the end):",
            "",
            *verdicts,
            "",
            "Replicas (sweep; final values, or statistics over the second half of the run; fractions with Wilson's "
            "95 % interval over the replicas, in brackets, the mean final valency with its t interval):",
            "",
            *lines,
            "",
            "Single runs (whole time series; seed 0 is the one plotted):",
            "",
            *single,
            "",
            f"Fixed random graph: near collisions between agents that are not neighbours, at some sample of the "
            f"run, in {pct(fr.near_collision_fraction, fr.replicas)} of the replicas (smallest distance at the end "
            f"{fr.min_distance_min:.2g} m): "
            "the paper says a fixed incomplete graph cannot prevent them and shows, in its one run (Fig. 4), two "
            "agents 'dangerously close' that 'do not collide'; ours go further, two agents converging onto the same "
            "point: a difference from the paper's run (its theorems allow both). Our reading, not tested: nothing "
            "pushes two agents that are not neighbours apart, two that share neighbours are pulled by them toward "
            "the same places, and where their neighbour sets coincide the potential's minimum is one point for "
            "both (the paper does not give its graph). The potential per edge of the "
            "fixed graphs at the end is "
            f"{fr.potential_per_edge:.3f} (random) and {fc.potential_per_edge:.3f} (complete), V(d) = "
            f"{pair_potential(D):.0f}: every edge sits at d only where the graph allows it (Corollary 1, trees); "
            "elsewhere the minimum is a compromise. Switching runs whose graph is disconnected in the second half "
            f"({pct(1 - sw.connected_fraction, sw.replicas)}) break the theorems' assumption, and their components "
            "need not "
            f"share a velocity (synchronised in {pct(sw.sync_fraction, sw.replicas)} of all switching runs); of the "
            f"{len(starts)} single switching runs, {sum(starts)} start and {sum(ends)} end with a connected graph: "
            "the paper's random initial draw does not guarantee the connectivity its theorems assume. The mean "
            f"valency of the plotted switching run grows from {valency_start:.1f} to {valency_end:.1f}. The paper "
            "calls the steady switching graph's connectivity 'high' and the graph 'not necessarily complete', "
            f"without a number; ours {'is not' if sw_valency.excludes(N - 1) else 'may be'} complete: mean final "
            f"valency {sw_valency.short()} over {int(sw.replicas)} replicas (complete: {N - 1}; the replicas left "
            "disconnected included).",
            "",
            "Not reproduced: the position snapshots of Figs. 4-5 (the metrics hold no positions; record a run with "
            "`tflock sim --config configs/papers/tanner-fixed.toml` to see them), and the paper's exact graph and "
            "initial draw, which it does not give.",
        ])
