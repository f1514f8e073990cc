"""Parallel formations behind a virtual agent: the best configurations (Fig. 4) and tau over p and delta (Fig. 7).

papers/004_db13ec8ccd743dce.txt, section 4: N = 12 reactive agents start in a 76 x 36 bl rectangle behind a virtual
agent (VA) heading 180 degrees at |va| = 1 bl/tu; vision 5.5 bl, minimum separation 2.5 bl, VAIR 25 bl, |vout| =
1.4 bl/tu, beta_lim 5 degrees, runs capped at 3000 tu. The eight strategies of Table 1 (S-1.x: one vision radius,
S-2.x: perception rings) combine Fa, Fc, Fav, Fcv with the weights of eq. (3). The quantifiers: tau, the time to the
desired formation (Definition 1), phi = |mean exp(i Theta_j)| of the agents' angles seen from the VA (eq. 6), and
rho, their mean distance to the VA.

- Fig. 4: over alpha_a, alpha_c, alpha_av, alpha_cv in {1, ..., 10} (about 44,000 configurations, 10 runs each),
  among the configurations that reach the DF in all runs, the extremes: min tau = 871 (S-2.2), max tau = 1971
  (S-1.1), min phi = 0.09 (S-1.3), max phi = 0.36 (S-1.4), min rho = 5.20 (S-1.2), max rho = 13.88 (S-2.4), with
  their weights. We run those six configurations (10 replicas), and a REDUCED grid: every weight in {1, 3, 10}
  (27 configurations for the S-x.1 and S-x.2 strategies, which do not use alpha_c, 81 for the others: 432 in all,
  1 % of the paper's) with 5 replicas each instead of 10. Fig. 6 (the convergence ratio of S-2.2 over alpha_a and
  alpha_av) comes out of the same grid.
- Fig. 7: S-2.2 with the weights of Fig. 4a, tau averaged over runs for communication-failure probability p in
  {0, 0.1, ..., 0.9} and heading noise delta in [0, 0.9] degrees (the paper: delta in steps of 0.1 and 50 runs;
  ours: delta in {0, 0.3, 0.6, 0.9} and 10 replicas). The paper reports tau rising smoothly for p <= 0.8, jumping
  at p = 0.9, and little effect of the noise.

phi and rho are taken at the end of the run (the formation then moves rigidly with the VA, so they equal their
values when the DF is first reached); tau is exact (checked every step) and equals the cap when the DF is not
reached. The formation replicas are not batched (one run after another), so the full size is long (see
docs/reproduce.md).
"""

import math
from typing import Any

import numpy as np
import pandas as pd

from tflock.reproduce.experiment import Experiment, Report, Results

STRATEGIES = ("S-1.1", "S-1.2", "S-1.3", "S-1.4", "S-2.1", "S-2.2", "S-2.3", "S-2.4")
WEIGHTS = ("align", "cohesion", "va_align", "va_cohesion")
SETUP = {  # section 4, "Initial conditions" (see configs/papers/formation-*.toml)
    "params.n": 12, "params.radius": 5.5, "params.min_separation": 2.5, "params.vair": 25.0,
    "params.va_speed": 1.0, "params.out_speed": 1.4, "params.va_heading_deg": 180.0, "params.beta_lim_deg": 5.0,
    "params.world": 200.0, "params.init_length": 76.0, "params.init_width": 36.0,
}
#: Fig. 4 (a)-(f): what each configuration extremises, its strategy, weights (align, cohesion, va_align,
#: va_cohesion; cohesion 1 where the strategy does not use it) and the paper's value
PAPER_FIG4 = {
    "a": ("tau", "min", "S-2.2", (8, 1, 9, 4), 871.0),
    "b": ("tau", "max", "S-1.1", (7, 1, 1, 3), 1971.0),
    "c": ("phi", "min", "S-1.3", (1, 4, 4, 9), 0.09),
    "d": ("phi", "max", "S-1.4", (3, 5, 7, 9), 0.36),
    "e": ("rho", "min", "S-1.2", (3, 1, 10, 10), 5.20),
    "f": ("rho", "max", "S-2.4", (2, 3, 6, 9), 13.88),
}
BEST = PAPER_FIG4["a"][3]  # the configuration of Figs. 5 and 7
LEVELS = (1.0, 3.0, 10.0)  # our reduced grid of every weight (the paper: 1, 2, ..., 10)
#: replicas at full size: the paper's configurations, each grid configuration, each (p, delta) of Fig. 7
PAPER_REPLICAS, GRID_REPLICAS, FIG7_REPLICAS = 10, 5, 10
#: the noise claim of Fig. 7: tau at p = 0 without and with the largest noise, over the paper's 50 runs, paired
#: (replica r has seed r at both, so the same initial state)
NOISE_LEVELS, NOISE_REPLICAS = (0.0, 0.9), 50
#: the torus side is not in the paper: ours (200 bl) and one so large that no agent wraps before the DF
WORLDS = (200.0, 1000.0)
#: rho of Fig. 4e: the paper's ramp jitter gamma = T, none (every agent stops at the VA's depth), and none with a
#: smaller minimum separation (values of params.ramp_jitter and params.min_separation)
RHO_VARIANTS = ((1.0, 2.5), (0.0, 2.5), (0.0, 1.0))


def _uses_cohesion(strategy: str) -> bool:
    """Table 1: Fc appears only in S-x.3 and S-x.4."""
    return strategy[-1] in "34"


def _weights(values: tuple[float, ...]) -> dict[str, float]:
    return {f"params.weights.{w}": float(v) for w, v in zip(WEIGHTS, values, strict=True)}


def _slug(strategy: str) -> str:
    return strategy.lower().replace(".", "-")


class Formation(Experiment):
    name = "formation"
    title = "Virtual-agent parallel formations: best configurations (Fig. 4) and tau over failure p and noise (Fig. 7)"
    source = "papers/004_db13ec8ccd743dce.txt, section 4, Figs. 4, 6 and 7"

    @staticmethod
    def steps(quick: bool) -> int:
        return 1000 if quick else 3000  # also the cap of tau (the paper's 3000 tu)

    def _set(self, quick: bool) -> dict[str, Any]:
        steps = self.steps(quick)
        return {"steps": steps, "params.tau_cap": steps, **SETUP, "log.metrics_every": 100}

    def sweeps(self, quick: bool) -> dict[str, dict[str, Any]]:
        fixed = self._set(quick)
        sweeps = {
            "formation-fig4-paper": {
                "model": "formation", "replicas": 1 if quick else PAPER_REPLICAS, "seed": 0, "set": fixed,
                "points": [{"params.strategy": strategy, **_weights(w)}
                           for _, _, strategy, w, _ in PAPER_FIG4.values()],
            },
        }
        if quick:  # a tiny grid: S-2.2, alpha_a against a large alpha_av (Fig. 6's axis)
            grids = {"S-2.2": {"align": [1.0, 10.0], "cohesion": [1.0], "va_align": [10.0], "va_cohesion": [4.0]}}
        else:
            grids = {s: {w: list(LEVELS) if w != "cohesion" or _uses_cohesion(s) else [1.0] for w in WEIGHTS}
                     for s in STRATEGIES}
        for strategy, levels in grids.items():
            sweeps[f"formation-grid-{_slug(strategy)}"] = {
                "model": "formation", "replicas": 1 if quick else GRID_REPLICAS, "seed": 0, "set": fixed,
                "grid": {"params.strategy": [strategy], **{f"params.weights.{w}": v for w, v in levels.items()}},
            }
        best = {"params.strategy": ["S-2.2"], **{k: [v] for k, v in _weights(BEST).items()}}
        sweeps["formation-fig7"] = {
            "model": "formation", "replicas": 1 if quick else FIG7_REPLICAS, "seed": 0, "set": fixed,
            "grid": {**best,
                     "params.fail_prob": [0.0, 0.9] if quick else [round(0.1 * k, 1) for k in range(10)],
                     "params.noise_deg": [0.0, 0.9] if quick else [0.0, 0.3, 0.6, 0.9]},
        }
        sweeps["formation-noise"] = {
            "model": "formation", "replicas": 2 if quick else NOISE_REPLICAS, "seed": 0, "set": fixed,
            "grid": {**best, "params.fail_prob": [0.0], "params.noise_deg": list(NOISE_LEVELS)},
        }
        sweeps["formation-torus"] = {  # the Fig. 4 configurations on a torus where nobody wraps
            "model": "formation", "replicas": 1 if quick else PAPER_REPLICAS, "seed": 0,
            "set": {**fixed, "params.world": WORLDS[1]},
            "points": sweeps["formation-fig4-paper"]["points"][:1 if quick else None],
        }
        sweeps["formation-rho"] = {  # Fig. 4e: what sets rho
            "model": "formation", "replicas": 1 if quick else PAPER_REPLICAS, "seed": 0, "set": fixed,
            "points": [{"params.strategy": PAPER_FIG4["e"][2], **_weights(PAPER_FIG4["e"][3]),
                        "params.ramp_jitter": jitter, "params.min_separation": separation}
                       for jitter, separation in RHO_VARIANTS[1:]],
        }
        return sweeps

    def report(self, results: Results, quick: bool) -> Report:
        cap = self.steps(quick)
        paper = self._summary(results.sweeps["formation-fig4-paper"], cap)
        paper["figure"] = list(PAPER_FIG4)  # the points are in PAPER_FIG4's order
        paper["paper_quantity"] = [q for q, *_ in PAPER_FIG4.values()]
        paper["paper_value"] = [v for *_, v in PAPER_FIG4.values()]
        grid = pd.concat([self._summary(t, cap) for name, t in results.sweeps.items()
                          if name.startswith("formation-grid-")], ignore_index=True)
        fig7 = self._summary(results.sweeps["formation-fig7"], cap)
        table = pd.concat([paper.assign(sweep="fig4-paper"), grid.assign(sweep="grid"),
                           fig7.assign(sweep="fig7")], ignore_index=True)
        table = table[["sweep", "figure", "strategy", *WEIGHTS, "fail_prob", "noise_deg", "replicas",
                       "converged_fraction", "tau_mean", "tau_std", "phi_mean", "rho_mean", "paper_quantity",
                       "paper_value"]]
        figures = {"fig4-quantifiers": self._fig4(paper, grid), "fig6-convergence-s2-2": self._fig6(grid),
                   "fig7-tau-failure-noise": self._fig7(fig7)}
        return Report(figures, table, self._comparison(paper, grid, fig7, cap, quick))

    # ------------------------------------------------------------------------------------------------------
    # Numbers.

    @staticmethod
    def _summary(sweep: pd.DataFrame, cap: int) -> pd.DataFrame:
        """One row per configuration: the fraction of replicas that reach the DF before the cap, tau (mean and
        std over all replicas, the cap where not reached) and phi, rho (means over the replicas that reach it)."""
        keys = ["params.strategy", *[f"params.weights.{w}" for w in WEIGHTS], "params.fail_prob",
                "params.noise_deg"]
        frame = sweep.copy()
        for key in keys[-2:]:
            if key not in frame:
                frame[key] = 0.0
        rows = []
        for values, group in frame.groupby(keys, sort=False):
            done = group["final_tau"] < cap
            rows.append({
                "strategy": values[0], **dict(zip(WEIGHTS, values[1:5], strict=True)),
                "fail_prob": values[5], "noise_deg": values[6], "replicas": len(group),
                "converged_fraction": done.mean(),
                "tau_mean": group["final_tau"].mean(), "tau_std": group["final_tau"].std(ddof=1),
                "phi_mean": group.loc[done, "final_phi"].mean() if done.any() else math.nan,
                "rho_mean": group.loc[done, "final_rho"].mean() if done.any() else math.nan,
            })
        return pd.DataFrame(rows)

    @staticmethod
    def _extremes(grid: pd.DataFrame) -> dict[tuple[str, str], pd.Series]:
        """Fig. 4's selection on our grid: among the configurations that reach the DF in every replica, the one
        with the smallest and the largest mean of each quantifier."""
        ok = grid[grid["converged_fraction"] == 1]
        out = {}
        for q in ("tau", "phi", "rho"):
            if len(ok):
                out[(q, "min")] = ok.loc[ok[f"{q}_mean"].idxmin()]
                out[(q, "max")] = ok.loc[ok[f"{q}_mean"].idxmax()]
        return out

    # ------------------------------------------------------------------------------------------------------
    # Figures.

    @staticmethod
    def _fig4(paper: pd.DataFrame, grid: pd.DataFrame) -> Any:
        """Per strategy: the range of each quantifier over the grid's fully converged configurations, our value
        for the paper's six configurations, and the paper's value."""
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(1, 3, figsize=(13, 4))
        x = {s: k for k, s in enumerate(STRATEGIES)}
        ok = grid[grid["converged_fraction"] == 1]
        for ax, q, label in zip(axes, ("tau", "phi", "rho"), ("tau (tu)", "phi", "rho (bl)"), strict=True):
            for k, (strategy, group) in enumerate(ok.groupby("strategy")):
                ax.vlines(x[strategy], group[f"{q}_mean"].min(), group[f"{q}_mean"].max(), color="C0", lw=6,
                          alpha=0.4, label="our grid: min-max over converged configs" if k == 0 else None)
            mine = paper[paper["paper_quantity"] == q]
            ax.plot([x[s] for s in mine["strategy"]], mine[f"{q}_mean"], "D", color="C1",
                    label="ours, the paper's configuration")
            ax.plot([x[s] for s in mine["strategy"]], mine["paper_value"], "*", ms=12, color="C3",
                    label="paper, Fig. 4")
            for _, row in mine.iterrows():
                ax.annotate(f"({row['figure']})", (x[row["strategy"]], row["paper_value"]), textcoords="offset points",
                            xytext=(6, 0), fontsize=8)
            ax.set_xticks(range(len(STRATEGIES)), STRATEGIES, rotation=45)
            ax.set_ylabel(label)
        axes[0].legend(fontsize=7)
        figure.suptitle("Fig. 4: quantifiers of the desired formations by strategy")
        figure.tight_layout()
        return figure

    @staticmethod
    def _fig6(grid: pd.DataFrame) -> Any:
        """Fig. 6: the convergence ratio of S-2.2 over alpha_a and alpha_av (mean over the other weights)."""
        import matplotlib.pyplot as plt

        s22 = grid[grid["strategy"] == "S-2.2"]
        ratio = s22.pivot_table(index="va_align", columns="align", values="converged_fraction", aggfunc="mean")
        figure, ax = plt.subplots(figsize=(4.8, 4))
        image = ax.imshow(ratio.to_numpy(), origin="lower", vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(ratio.columns)), [f"{v:g}" for v in ratio.columns])
        ax.set_yticks(range(len(ratio.index)), [f"{v:g}" for v in ratio.index])
        ax.set_xlabel("alpha_a")
        ax.set_ylabel("alpha_av")
        figure.colorbar(image, ax=ax, label="fraction reaching the DF")
        ax.set_title("Fig. 6: S-2.2 convergence ratio")
        return figure

    @staticmethod
    def _fig7(fig7: pd.DataFrame) -> Any:
        """Fig. 7: mean tau over p and delta, as a map and as curves over p."""
        import matplotlib.pyplot as plt

        tau = fig7.pivot_table(index="noise_deg", columns="fail_prob", values="tau_mean")
        figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
        image = left.imshow(tau.to_numpy(), origin="lower", aspect="auto", cmap="viridis")
        left.set_xticks(range(len(tau.columns)), [f"{v:g}" for v in tau.columns])
        left.set_yticks(range(len(tau.index)), [f"{v:g}" for v in tau.index])
        left.set_xlabel("communication failure p")
        left.set_ylabel("noise delta (degrees)")
        figure.colorbar(image, ax=left, label="mean tau (tu)")
        for delta, row in tau.iterrows():
            right.plot(row.index, row.to_numpy(), marker="o", ms=3, label=f"delta = {delta:g} deg")
        right.set_xlabel("communication failure p")
        right.set_ylabel("mean tau (tu; the cap if no DF)")
        right.legend()
        figure.suptitle("Fig. 7: tau over p and delta, S-2.2 with alpha_a = 8, alpha_av = 9, alpha_cv = 4")
        figure.tight_layout()
        return figure

    # ------------------------------------------------------------------------------------------------------
    # Comparison.

    def _comparison(self, paper: pd.DataFrame, grid: pd.DataFrame, fig7: pd.DataFrame, cap: int,
                    quick: bool) -> str:
        set_ = self._set(quick)
        vair, va, vout = set_["params.vair"], set_["params.va_speed"], set_["params.out_speed"]
        ramp = vair / (vout - va)  # T of the model's speed ramps (FormationParams.ramp_time)
        radius = vout / math.radians(1.0)  # turning radius at |vout| and the paper's 1 degree per tu

        lines = ["| Fig. 4 | strategy | weights (a, c, av, cv) | paper | ours: reach the DF | tau | phi | rho |",
                 "|---|---|---|---|---|---|---|---|"]
        for _, r in paper.iterrows():
            w = ", ".join(f"{r[k]:g}" for k in WEIGHTS)
            lines.append(f"| ({r['figure']}) | {r['strategy']} | {w} | {r['paper_quantity']} = {r['paper_value']:g} | "
                         f"{100 * r['converged_fraction']:.0f} % of {r['replicas']} | {r['tau_mean']:.0f} | "
                         f"{r['phi_mean']:.2f} | {r['rho_mean']:.1f} |")
        extremes = self._extremes(grid)
        ext = ["| quantifier | paper (Fig. 4) | ours on the reduced grid | strategy, weights (a, c, av, cv) |",
               "|---|---|---|---|"]
        for (q, which, strategy, _, value) in PAPER_FIG4.values():
            row = extremes.get((q, which))
            if row is None:
                ext.append(f"| {which} {q} | {value:g} ({strategy}) | no configuration converged in all replicas | |")
                continue
            w = ", ".join(f"{row[k]:g}" for k in WEIGHTS)
            digits = {"tau": 0, "phi": 2, "rho": 1}[q]
            ext.append(f"| {which} {q} | {value:g} ({strategy}) | {row[f'{q}_mean']:.{digits}f} | {row['strategy']}, "
                       f"{w} |")
        n_ok = int((grid["converged_fraction"] == 1).sum())

        s22 = grid[grid["strategy"] == "S-2.2"]
        above = s22[s22["va_align"] >= s22["align"]]["converged_fraction"].mean()
        below = s22[s22["va_align"] < s22["align"]]["converged_fraction"].mean()

        def pct(x: float) -> str:
            return "no configuration" if math.isnan(x) else f"{100 * x:.0f} %"

        tau = fig7.pivot_table(index="noise_deg", columns="fail_prob", values="tau_mean")
        by_p = tau.mean(axis=0)
        p_values = by_p.index.to_numpy()
        noise_effect = float((tau.max(axis=0) - tau.min(axis=0)).loc[by_p < 0.9 * cap].mean()) \
            if (by_p < 0.9 * cap).any() else math.nan
        capped = [p for p in p_values if by_p[p] >= 0.9 * cap]
        first_capped = min(capped) if capped else None
        rising = bool(np.all(np.diff(by_p.to_numpy()) > -0.05 * cap))

        phis = paper["phi_mean"].dropna()
        rhos = paper["rho_mean"].dropna()
        grid_ok = grid[grid["converged_fraction"] == 1]
        phi_ok = bool(phis.between(0.0, 0.46).all()) if len(phis) else False
        rho_ok = bool(rhos.between(5.2 * 0.75, 13.88 * 1.25).all()) if len(rhos) else False
        checks = [
            ("the paper's six Fig. 4 configurations reach the DF in every run",
             bool((paper["converged_fraction"] == 1).all()),
             f"{100 * paper['converged_fraction'].mean():.0f} % of their runs do"),
            ("tau of those configurations lies within 25 % of the paper's range 871-1971 tu (its extremes over all "
             "configurations)",
             bool(paper["tau_mean"].between(871 * 0.75, 1971 * 1.25).all()),
             f"ours {paper['tau_mean'].min():.0f}-{paper['tau_mean'].max():.0f} tu"),
            ("phi lies within 0.1 of the paper's range 0.09-0.36",
             phi_ok,
             f"ours {phis.min():.2f}-{phis.max():.2f}" if len(phis) else "no converged run"),
            ("rho lies within 25 % of the paper's range 5.20-13.88 bl",
             rho_ok,
             f"ours {rhos.min():.1f}-{rhos.max():.1f} bl" if len(rhos) else "no converged run"),
            ("Fig. 7: tau grows with p and jumps near the cap (>= 90 % of it) only at p = 0.9",
             rising and first_capped is not None and first_capped >= 0.9,
             f"mean tau over delta: {', '.join(f'p = {p:g}: {by_p[p]:.0f}' for p in p_values)}"),
            ("Fig. 7: the noise delta hardly changes tau",
             bool(noise_effect < 0.25 * (by_p.max() - by_p.min() + 1e-9)) if not math.isnan(noise_effect) else False,
             f"spread of tau over delta at fixed p (where the DF is reached): {noise_effect:.0f} tu on average"),
        ]
        verdicts = [f"- {claim}: **{'agrees' if ok else 'does NOT agree'}** ({detail})" for claim, ok, detail in checks]
        levels = ", ".join(f"{v:g}" for v in LEVELS)
        size = ("quick: 1 replica, runs and tau capped at 1000 tu, a 2-configuration grid" if quick else
                f"the paper's configurations x {paper['replicas'].max()} replicas; our grid: weights in {{{levels}}}, "
                f"{len(grid)} of the paper's ~44,000 configurations, {grid['replicas'].max()} replicas each; Fig. 7: "
                f"{fig7['replicas'].max()} replicas instead of 50")
        return "\n".join([
            "The paper (section 4) reports, over ~44,000 weight configurations x 10 runs, the configurations that "
            "reach the desired formation (DF) in all runs with the extreme values of tau, phi and rho (Fig. 4), and "
            "for S-2.2 with alpha_a = 8, alpha_av = 9, alpha_cv = 4 a tau that rises smoothly with the "
            "communication-failure probability p up to 0.8, jumps at p = 0.9, and barely depends on the noise "
            f"(Fig. 7). Ours ({size}):",
            "",
            *verdicts,
            "",
            "The paper's Fig. 4 configurations, run as published (tau: mean over all replicas, the cap where the DF "
            "is not reached; phi, rho: means over the replicas that reach it):",
            "",
            *lines,
            "",
            f"Fig. 4's selection on our reduced grid ({n_ok} of {len(grid)} configurations reach the DF in every "
            "replica):",
            "",
            *ext,
            "",
            f"**phi and rho {'agree' if phi_ok and rho_ok else 'disagree'} with the paper.** Where the agents "
            f"settle in the VAIR: phi {phis.min():.2f}-{phis.max():.2f} (paper 0.09-0.36) and rho "
            f"{rhos.min():.1f}-{rhos.max():.1f} bl (paper 5.20-13.88) for the paper's configurations; over the "
            f"whole grid phi {grid_ok['phi_mean'].min():.2f}-{grid_ok['phi_mean'].max():.2f} and rho "
            f"{grid_ok['rho_mean'].min():.1f}-{grid_ok['rho_mean'].max():.1f} bl."
            + ("" if phi_ok else
               " The speed ramp of eq. (1) lasts T = VAIR / (|vout| - |va|) = "
               f"{ramp:.1f} tu (+- T), so an entering agent gains a depth uniform in (0, {vair:g}) bl on the VA, "
               "the paper's 'homogeneous distribution of agents inside the VAIR'; that is what puts rho in range. "
               "phi stays high because every agent starts behind the VA (the paper's initial rectangle) and, "
               f"once inside, moves at |va| = {va:g} like the VA: it keeps its place behind it and the agents end "
               "on one side. A phi of 0.09-0.36 needs agents all around the VA, which the text does not say how "
               "its model reaches (agents inside the VAIR would have to overtake the VA)."),
            "",
            f"Fig. 6: S-2.2 reaches the DF in {pct(above)} of the runs with alpha_av >= alpha_a and {pct(below)} "
            "with alpha_av < alpha_a (the paper: more likely when alpha_av >= alpha_a, with regions that never "
            "converge).",
            "",
            "Fig. 7 has no numbers in the text, only the shape compared above; "
            + (f"our mean tau is within 10 % of the cap from p = {first_capped:g} on, earlier than the paper's jump. "
               if first_capped is not None and first_capped < 0.9 else "") +
            "The failure p silences every force of the agent for the step (as the paper says "
            "for S-2.2 outside the VAIR: 'they will only try to go towards VA 10 % of the cases' at p = 0.9), so "
            f"with turns of at most 1 degree per tu an agent at |vout| = {vout:g} circles with radius "
            f"{radius:.0f} / (1 - p) bl on average ({radius / 0.4:.0f} bl, the torus side being "
            f"{set_['params.world']:g}, at p = 0.6) and then closes on the VA at only |vout| - |va| = "
            f"{vout - va:g} bl/tu: the agents that start heading away arrive late, and the DF waits for the last "
            "one. What keeps the paper's tau moderate up to p = 0.8 the text does not say.",
        ])
