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
  their weights. We run those six configurations (10 replicas, as the paper), and a REDUCED grid: every weight
  in {1, 4, 7, 10} (64 configurations for the S-x.1 and S-x.2 strategies, which do not use alpha_c, 256 for the
  others), 1280 configurations in all, with 10 replicas each as the paper. Fig. 6 (the convergence ratio of S-2.2
  over alpha_a and alpha_av) comes out of the S-2.2 grid.
- Fig. 7: S-2.2 with the weights of Fig. 4a, tau averaged over runs for communication-failure probability p in
  {0, 0.1, ..., 0.9} and heading noise delta in {0, 0.1, ..., 0.9} (degrees: the paper gives no unit), 50 runs
  each, as the paper. The paper reports tau rising smoothly for p <= 0.8, jumping at p = 0.9, and no effect of the
  noise; that last claim is checked on its own on 50 paired runs at p = 0 (delta 0 and 0.9 degrees, replica r with
  the same initial state in both).
- Not in the paper: the torus size, on which tau depends (the six configurations again on a 1000 bl torus, the
  same initial states), and what sets rho (Fig. 4e's configuration without the ramp jitter, and also with a 1 bl
  minimum separation).

Every number is reported with its replicas and 95 % confidence interval (:mod:`tflock.reproduce.stats`). phi and
rho are taken at the end of the run (the formation then moves rigidly with the VA, so they equal their values when
the DF is first reached, up to the last few degrees of alignment); tau is exact (checked every step) and equals the
cap when the DF is not reached. The formation replicas are not batched: one run after another, each running the
steps between its observations in one launch on one thread (about 45 ms a run of 3000 steps on the project's 2-core
host; the 18,040 runs of the full size about 8 minutes with --workers 2): see docs/reproduce.md.
"""

import math
from fractions import Fraction
from typing import Any

import pandas as pd

from tflock.reproduce.experiment import Experiment, Report, Results
from tflock.reproduce.stats import Estimate, mean_ci, paired_difference_ci, proportion_ci, verdict

STRATEGIES = ("S-1.1", "S-1.2", "S-1.3", "S-1.4", "S-2.1", "S-2.2", "S-2.3", "S-2.4")
WEIGHTS = ("align", "cohesion", "va_align", "va_cohesion")
SETUP = {  # section 4, "Initial conditions" (see configs/papers/formation-*.toml)
    "params.n": 12, "params.radius": 5.5, "params.min_separation": 2.5, "params.vair": 25.0,
    "params.va_speed": 1.0, "params.out_speed": 1.4, "params.va_heading_deg": 180.0, "params.beta_lim_deg": 5.0,
    "params.world": 200.0, "params.init_length": 76.0, "params.init_width": 36.0,
}
#: the forces each strategy's agents use outside and inside the VAIR (Table 1; the strategy's last digit), by
#: their weights' names
TABLE1 = {"1": (("align", "va_cohesion"), ("va_align",)), "2": (("va_cohesion",), ("va_align", "align")),
          "3": (("va_cohesion", "cohesion"), ("va_align", "align")),
          "4": (("va_cohesion", "cohesion", "va_align", "align"), ("va_align", "align"))}


def effective_weights(row: Any) -> tuple:
    """What of a configuration's weights the model can tell apart: eq. (3), F = sum(alpha_k F_k) / sum(alpha_k)
    over the forces acting, depends only on the ratios of the weights of the forces acting together, so each side
    of the VAIR counts by its weights divided by their sum (a force acting alone: 1, whatever its weight).
    Configurations with equal keys are the same model in exact arithmetic (our kernel may round them apart)."""
    key: list[Any] = [str(row["strategy"])]
    for forces in TABLE1[str(row["strategy"])[-1]]:
        weights = [Fraction(row[k]).limit_denominator() for k in forces]
        total = sum(weights)
        key.append(tuple(w / total if total else w for w in weights))
    return tuple(key)


def weights_text(row: Any) -> str:
    """A configuration's weights (align, cohesion, va_align, va_cohesion) as the reports write them: "-" for a weight
    whose force the strategy does not use (Table 1: cohesion in S-x.1, S-x.2), and in brackets one that cancels in
    eq. (3) because its force acts alone wherever it acts (Fav inside the VAIR in S-x.1, Fcv outside it in S-x.2),
    so that configurations differing only there are one model (:func:`effective_weights`)."""
    sides = TABLE1[str(row["strategy"])[-1]]
    together = {k for forces in sides if len(forces) > 1 for k in forces}
    used = {k for forces in sides for k in forces}
    return ", ".join("-" if k not in used else f"{row[k]:g}" if k in together else f"({row[k]:g})" for k in WEIGHTS)


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
#: our reduced grid of every weight (the paper: 1, 2, ..., 10), for every strategy; S-2.2's alpha_a x alpha_av plane
#: is Fig. 6 (the paper's ~44,000 configurations x 10 runs would take about 5 hours of one core at ~45 ms a run,
#: these 1280 about 9 minutes)
LEVELS = (1.0, 4.0, 7.0, 10.0)
#: replicas at full size: the paper's configurations, each grid configuration, each (p, delta) of Fig. 7
PAPER_REPLICAS, GRID_REPLICAS, FIG7_REPLICAS = 10, 10, 50
#: Fig. 7's failure probabilities p and heading noises delta (degrees), as the paper's
FIG7_FAILURES = tuple(round(0.1 * k, 1) for k in range(10))
FIG7_NOISES = tuple(round(0.1 * k, 1) for k in range(10))
#: parameters a point may set besides the strategy and weights, with their defaults (the sweep table's columns)
POINT_KEYS = {"fail_prob": 0.0, "noise_deg": 0.0, "world": 200.0, "ramp_jitter": 1.0, "min_separation": 2.5}
SUMMARY_COLUMNS = ["converged_fraction", "converged_lo", "converged_hi", "tau_mean", "tau_lo", "tau_hi", "tau_min",
                   "tau_max", "tau_std", "phi_mean", "phi_lo", "phi_hi", "phi_min", "phi_max", "rho_mean", "rho_lo",
                   "rho_hi", "rho_min", "rho_max"]
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
        return 1200 if quick else 3000  # the cap of tau (the paper's 3000 tu; quick: the six seed-0 runs reach the DF)

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
            grids = {s: {w: list(LEVELS) if w != "cohesion" or _uses_cohesion(s)
                         else [1.0] for w in WEIGHTS} for s in STRATEGIES}
        for strategy, levels in grids.items():
            sweeps[f"formation-grid-{_slug(strategy)}"] = {
                "model": "formation", "replicas": 1 if quick else GRID_REPLICAS, "seed": 0, "set": fixed,
                "grid": {"params.strategy": [strategy], **{f"params.weights.{w}": v for w, v in levels.items()}},
            }
        best = {"params.strategy": ["S-2.2"], **{k: [v] for k, v in _weights(BEST).items()}}
        sweeps["formation-fig7"] = {
            "model": "formation", "replicas": 1 if quick else FIG7_REPLICAS, "seed": 0, "set": fixed,
            "grid": {**best,
                     "params.fail_prob": [0.0, 0.9] if quick else list(FIG7_FAILURES),
                     "params.noise_deg": [0.0, 0.9] if quick else list(FIG7_NOISES)},
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
            "model": "formation", "replicas": 1 if quick else PAPER_REPLICAS, "seed": 0,
            "set": {k: v for k, v in fixed.items() if k != "params.min_separation"},
            "points": [{"params.strategy": PAPER_FIG4["e"][2], **_weights(PAPER_FIG4["e"][3]),
                        "params.ramp_jitter": jitter, "params.min_separation": separation}
                       for jitter, separation in RHO_VARIANTS[1:]],
        }
        return sweeps

    def report(self, results: Results, quick: bool) -> Report:
        cap = self.steps(quick)
        sweeps = results.sweeps
        paper = self._summary(sweeps["formation-fig4-paper"], cap)
        paper["figure"] = list(PAPER_FIG4)  # the points are in PAPER_FIG4's order
        paper["paper_quantity"] = [q for q, *_ in PAPER_FIG4.values()]
        paper["paper_value"] = [v for *_, v in PAPER_FIG4.values()]
        grid = pd.concat([self._summary(t, cap) for name, t in sweeps.items() if name.startswith("formation-grid-")],
                         ignore_index=True)
        fig7 = self._summary(sweeps["formation-fig7"], cap)
        noise = self._summary(sweeps["formation-noise"], cap)
        torus = self._summary(sweeps["formation-torus"], cap)
        torus["figure"], torus["world"] = list(PAPER_FIG4)[:len(torus)], WORLDS[1]  # world: set, not swept
        rho = self._summary(sweeps["formation-rho"], cap)
        rho["figure"] = "e"
        table = pd.concat([paper.assign(sweep="fig4-paper"), grid.assign(sweep="grid"), fig7.assign(sweep="fig7"),
                           noise.assign(sweep="noise"), torus.assign(sweep="torus"), rho.assign(sweep="rho")],
                          ignore_index=True)
        table = table[["sweep", "figure", "strategy", *WEIGHTS, *POINT_KEYS, "replicas", *SUMMARY_COLUMNS,
                       "paper_quantity", "paper_value"]]
        figures = {"fig4-quantifiers": self._fig4(paper, grid), "fig6-convergence-s2-2": self._fig6(grid),
                   "fig7-tau-failure-noise": self._fig7(fig7)}
        comparison = self._comparison(paper, grid, fig7, cap, quick, sweeps=sweeps, torus=torus, rho=rho)
        return Report(figures, table, comparison)

    # ------------------------------------------------------------------------------------------------------
    # Numbers.

    @staticmethod
    def _summary(sweep: pd.DataFrame, cap: int) -> pd.DataFrame:
        """One row per configuration, in the sweep's order: the fraction of replicas that reach the DF before the
        cap (Wilson 95 % interval), tau over all replicas (the cap where not reached) and phi, rho over those that
        reach it, each as mean, 95 % t interval, min and max."""
        frame = sweep.copy()
        for key, default in POINT_KEYS.items():
            if f"params.{key}" not in frame:
                frame[f"params.{key}"] = default
        keys = ["params.strategy", *[f"params.weights.{w}" for w in WEIGHTS], *[f"params.{k}" for k in POINT_KEYS]]
        rows = []
        for values, group in frame.groupby(keys, sort=False):
            done = (group["final_tau"] < cap).to_numpy()
            reached = proportion_ci(int(done.sum()), len(group))
            row = {"strategy": values[0], **dict(zip(WEIGHTS, values[1:5], strict=True)),
                   **dict(zip(POINT_KEYS, values[5:], strict=True)), "replicas": len(group),
                   "converged_fraction": reached.value, "converged_lo": reached.lo, "converged_hi": reached.hi,
                   "tau_std": group["final_tau"].std(ddof=1)}
            for q, values_q in (("tau", group["final_tau"]), ("phi", group.loc[done, "final_phi"]),
                                ("rho", group.loc[done, "final_rho"])):
                estimate = mean_ci(values_q.to_numpy())
                row.update({f"{q}_mean": estimate.value, f"{q}_lo": estimate.lo, f"{q}_hi": estimate.hi,
                            f"{q}_min": values_q.min() if len(values_q) else math.nan,
                            f"{q}_max": values_q.max() if len(values_q) else math.nan})
            rows.append(row)
        return pd.DataFrame(rows)

    @staticmethod
    def _estimate(row: pd.Series, q: str) -> Estimate:
        """A summary row's mean of `q` with its interval (n: the replicas it is over)."""
        n = int(row["replicas"]) if q == "tau" else int(round(row["converged_fraction"] * row["replicas"]))
        return Estimate(row[f"{q}_mean"], row[f"{q}_lo"], row[f"{q}_hi"], n)

    @staticmethod
    def _reached(row: pd.Series) -> Estimate:
        """A summary row's fraction of runs that reach the DF, with its Wilson interval."""
        return Estimate(row["converged_fraction"], row["converged_lo"], row["converged_hi"], int(row["replicas"]))

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
            ax.errorbar([x[s] for s in mine["strategy"]], mine[f"{q}_mean"],
                        yerr=[mine[f"{q}_mean"] - mine[f"{q}_lo"], mine[f"{q}_hi"] - mine[f"{q}_mean"]], fmt="D",
                        color="C1", capsize=3, label="ours, the paper's configuration (95 % CI)")
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
        for delta, rows in fig7.groupby("noise_deg"):
            rows = rows.sort_values("fail_prob")
            right.errorbar(rows["fail_prob"], rows["tau_mean"], capsize=2, marker="o", ms=3,
                           yerr=[rows["tau_mean"] - rows["tau_lo"], rows["tau_hi"] - rows["tau_mean"]],
                           label=f"delta = {delta:g} deg")
        right.set_xlabel("communication failure p")
        right.set_ylabel("mean tau, 95 % CI (tu; the cap if no DF)")
        right.legend(fontsize=7, ncol=2)
        figure.suptitle("Fig. 7: tau over p and delta, S-2.2 with alpha_a = 8, alpha_av = 9, alpha_cv = 4")
        figure.tight_layout()
        return figure

    # ------------------------------------------------------------------------------------------------------
    # Comparison.

    @staticmethod
    def _runs_of(sweep: pd.DataFrame, row: pd.Series) -> pd.DataFrame:
        """The runs of `sweep` with the strategy and weights of summary `row`, by seed."""
        same = sweep["params.strategy"] == row["strategy"]
        for w in WEIGHTS:
            same &= sweep[f"params.weights.{w}"] == row[w]
        return sweep[same].sort_values("seed")

    def _comparison(self, paper: pd.DataFrame, grid: pd.DataFrame, fig7: pd.DataFrame, cap: int, quick: bool, *,
                    sweeps: dict[str, pd.DataFrame], torus: pd.DataFrame, rho: pd.DataFrame) -> str:
        set_ = self._set(quick)
        vair, va, vout = set_["params.vair"], set_["params.va_speed"], set_["params.out_speed"]
        ramp = 2 * vair / (vout - va)  # T of the model's speed ramps (FormationParams.ramp_time)
        radius = vout / math.radians(1.0)  # turning radius at |vout| and the paper's 1 degree per tu
        # a digit more than the paper prints (tau in whole tu), so a number the check puts off the paper's
        # never prints as the paper's
        digits = {"tau": 0, "phi": 3, "rho": 2}
        checks: list[tuple[str, bool]] = []

        # Fig. 4: each configuration's quantifier against the paper's number
        lines = ["| Fig. 4 | strategy | weights (a, c, av, cv) | paper | reach the DF | tau (tu) | phi | rho (bl) |",
                 "|---|---|---|---|---|---|---|---|"]
        one_run = []  # the single-run reading: the paper's number within our runs' range
        for _, r in paper.iterrows():
            q = r["paper_quantity"]
            mine = self._estimate(r, q)
            w = weights_text(r)
            over = "runs that reach the DF" if q != "tau" else "runs"
            in_range = bool(r[f"{q}_min"] <= r["paper_value"] <= r[f"{q}_max"])
            one_run.append(in_range)
            checks.append((f"({r['figure']}) {PAPER_FIG4[r['figure']][1]} {q} = {r['paper_value']:g} ({r['strategy']},"
                           f" weights {w}): ours {mine.text(digits[q], runs=over)}, single runs "
                           f"{r[f'{q}_min']:.{digits[q]}f} to {r[f'{q}_max']:.{digits[q]}f} (as one run's value, the "
                           f"paper's number lies {'within' if in_range else 'outside'} that range)",
                           mine.holds(r["paper_value"])))
            lines.append(f"| ({r['figure']}) | {r['strategy']} | {w} | {q} = {r['paper_value']:g} | "
                         f"{self._reached(r).short(2)} of {r['replicas']} | "
                         + " | ".join(self._estimate(r, k).short(digits[k]) for k in ("tau", "phi", "rho")) + " |")
        converged, total = int(round((paper["converged_fraction"] * paper["replicas"]).sum())), paper["replicas"].sum()
        checks.append((f"the six configurations reach the DF in every run (the paper selected them so): "
                       f"{converged} of {total} runs do ({proportion_ci(converged, total).short(2)})",
                       bool(converged == total)))
        bounds = {"tau": (871.0, 1971.0), "phi": (0.09, 0.36), "rho": (5.20, 13.88)}
        for q, (low, high) in bounds.items():
            meet = [self._estimate(r, q).overlaps(low, high) for _, r in paper.iterrows()]
            checks.append((f"{q} of every one of the six lies within the paper's extremes over all configurations, "
                           f"{low:g} to {high:g}: the 95 % intervals of {sum(meet)} of 6 meet that range "
                           f"(means {paper[f'{q}_mean'].min():.{digits[q]}f} to "
                           f"{paper[f'{q}_mean'].max():.{digits[q]}f})",
                           all(meet)))

        # Fig. 4's selection on our reduced grid
        extremes = self._extremes(grid)
        ext = ["| quantifier | paper (Fig. 4) | ours on the reduced grid, that configuration's mean [95 % CI] | "
               "strategy, weights (a, c, av, cv) |", "|---|---|---|---|"]
        for (q, which, strategy, _, value) in PAPER_FIG4.values():
            row = extremes.get((q, which))
            if row is None:
                ext.append(f"| {which} {q} | {value:g} ({strategy}) | no configuration reached the DF in all runs | |")
                continue
            w = weights_text(row)
            ext.append(f"| {which} {q} | {value:g} ({strategy}) | {self._estimate(row, q).short(digits[q])} | "
                       f"{row['strategy']}, {w} |")
        n_ok = int((grid["converged_fraction"] == 1).sum())
        distinct_grid = grid[~grid.apply(effective_weights, axis=1).duplicated()]  # each model once
        distinct_ok = int((distinct_grid["converged_fraction"] == 1).sum())

        # Fig. 6: S-2.2's convergence above and below the diagonal, each distinct model once (effective_weights)
        s22 = grid[grid["strategy"] == "S-2.2"]
        distinct = distinct_grid[distinct_grid["strategy"] == "S-2.2"]
        runs = (distinct["converged_fraction"] * distinct["replicas"]).round()
        upper = distinct["va_align"] >= distinct["align"]
        above = proportion_ci(int(runs[upper].sum()), int(distinct.loc[upper, "replicas"].sum()))
        below = proportion_ci(int(runs[~upper].sum()), int(distinct.loc[~upper, "replicas"].sum()))
        checks.append((f"Fig. 6: S-2.2 reaches the DF more often with alpha_av >= alpha_a: {above.text(2)} of the "
                       f"runs there against {below.text(2)} below the diagonal (over the {len(distinct)} distinct "
                       f"models among its {len(s22)} grid configurations: eq. (3) normalises the weights, so "
                       "configurations whose weights differ only by a common factor among the forces acting "
                       "together, or only in the weight of a force acting alone, are one model, counted once)",
                       bool(above.lo > below.hi)))

        # Fig. 7: tau over p (the runs of all deltas pooled) and over delta
        raw7 = sweeps["formation-fig7"]
        by_p = {p: mean_ci(g["final_tau"].to_numpy()) for p, g in raw7.groupby("params.fail_prob")}
        none_at = {p for p, g in raw7.groupby("params.fail_prob") if (g["final_tau"] >= cap).all()}

        def tau_at(p: float) -> str:  # tau over p's runs, or that none of them reached the DF (no interval then)
            runs = int((raw7["params.fail_prob"] == p).sum())
            return f"none of {runs} runs reached the DF by {cap} tu" if p in none_at else by_p[p].text(0, "tu")

        p_values = sorted(by_p)
        low_p = [p for p in p_values if p <= 0.8]
        below_cap = all(by_p[p].hi < 0.9 * cap for p in low_p)  # "increasing smoothly": no jump to the cap yet
        capped = [p for p in low_p if by_p[p].hi >= 0.9 * cap]
        rises = len(low_p) > 1 and by_p[low_p[-1]].lo > by_p[low_p[0]].hi and below_cap
        jump = 0.9 in by_p and by_p[0.9].lo >= 0.9 * cap and below_cap
        checks.append((f"Fig. 7: tau rises smoothly with p up to 0.8, 'increasing smoothly for p in [0, 0.8]' (our "
                       f"bar: the whole interval below 90 % of the cap, {0.9 * cap:g} tu, at every p up to 0.8; "
                       f"p = {low_p[0]:g}: {tau_at(low_p[0])}"
                       + (f"; p = {low_p[-1]:g}: {tau_at(low_p[-1])}" if len(low_p) > 1 else
                          "; no other p at most 0.8 was run")
                       + (f"; an interval reaching {0.9 * cap:g} tu already at p = "
                          f"{', '.join(f'{p:g}' for p in capped)}" if capped else "")
                       + "; the runs of every delta pooled)", bool(rises)))
        if 0.9 in by_p:
            checks.append((f"Fig. 7: tau jumps near the cap only at p = 0.9 ({tau_at(0.9)}; the cap "
                           f"{cap} where the DF is not reached)", bool(jump)))
        table7 = fig7.pivot_table(index="fail_prob", columns="noise_deg", values="tau_mean")
        none_by = f"none by {cap}"  # a cell whose runs all stop at the cap: tau is not reached (no interval)
        deltas = list(table7.columns)
        lines7 = ["| p | " + " | ".join(f"delta = {d:g} deg" for d in deltas) + " | all deltas |",
                  "|---|" + "---|" * (len(deltas) + 1)]
        for p in table7.index:
            cells = []
            for d in deltas:
                row = fig7[(fig7["fail_prob"] == p) & (fig7["noise_deg"] == d)].iloc[0]
                cells.append(none_by if row["converged_fraction"] == 0 else self._estimate(row, "tau").short(0))
            lines7.append(f"| {p:g} | " + " | ".join(cells) + f" | {none_by if p in none_at else by_p[p].short(0)} |")

        # the noise claim: paired runs at p = 0
        raw = sweeps["formation-noise"]
        levels = sorted(raw["params.noise_deg"].unique())
        tau_at = {d: raw[raw["params.noise_deg"] == d].sort_values("seed")["final_tau"].to_numpy() for d in levels}
        noise_means = {d: mean_ci(v) for d, v in tau_at.items()}
        effect = paired_difference_ci(tau_at[levels[0]], tau_at[levels[-1]])
        checks.append((f"'epsilon does not affect the convergence' (Fig. 7): at p = 0, tau is "
                       f"{noise_means[levels[0]].text(0, 'tu')} without noise and "
                       f"{noise_means[levels[-1]].text(0, 'tu')} at delta = {levels[-1]:g} degrees; paired by "
                       f"initial state, the noise changes it by {effect.text(0, 'tu', runs='pairs')}",
                       effect.holds(0.0)))

        # the torus: the Fig. 4 configurations at our 200 bl and at 1000 bl, paired by initial state
        raw_small, raw_large = sweeps["formation-fig4-paper"], sweeps["formation-torus"]
        lines_t = [f"| Fig. 4 | strategy | tau, torus {WORLDS[0]:g} bl | tau, torus {WORLDS[1]:g} bl | paired "
                   "difference (large - small) |", "|---|---|---|---|---|"]
        torus_moves = []
        for k, (_, r) in enumerate(torus.iterrows()):
            small = paper.iloc[k]
            small_runs, large_runs = self._runs_of(raw_small, r), self._runs_of(raw_large, r)
            both = small_runs.merge(large_runs, on="seed", suffixes=("_small", "_large"))
            diff = paired_difference_ci(both["final_tau_small"], both["final_tau_large"])
            torus_moves.append(diff.excludes(0.0))
            lines_t.append(f"| ({r['figure']}) | {r['strategy']} | {self._estimate(small, 'tau').short(0)} | "
                           f"{self._estimate(r, 'tau').short(0)} | {diff.short(0)} |")
        taus = [(figure, value) for figure, (kind, _, _, _, value) in PAPER_FIG4.items() if kind == "tau"]
        on_large = "; ".join(  # whether the torus size accounts for a disagreement on tau
            f"Fig. 4{figure}'s {value:g} tu {'within' if self._estimate(r, 'tau').holds(value) else 'outside'} "
            f"{self._estimate(r, 'tau').short(0)}" for figure, value in taus
            for _, r in torus[torus["figure"] == figure].iterrows())

        # rho: what sets it (Fig. 4e)
        e = paper[paper["figure"] == "e"].iloc[0]
        variants = [("the paper's gamma = T, minimum separation 2.5 bl", e)]
        for _, r in rho.iterrows():
            gamma = f"{r['ramp_jitter']:g} T" if r["ramp_jitter"] else "0"
            variants.append((f"gamma = {gamma}, minimum separation {r['min_separation']:g} bl", r))
        lines_r = [f"| Fig. 4e ({e['strategy']}; {weights_text(e)}) | reach the DF | tau (tu) | phi | rho (bl) |",
                   "|---|---|---|---|---|"]
        for label, r in variants:
            lines_r.append(f"| {label} | {self._reached(r).short(2)} of {r['replicas']} | "
                           + " | ".join(self._estimate(r, k).short(digits[k]) for k in ("tau", "phi", "rho")) + " |")
        rho_all = mean_ci(paper["rho_mean"].to_numpy())

        levels_text = ", ".join(f"{v:g}" for v in LEVELS)
        size = (f"quick: 1 replica (2 for the noise pairs), runs and tau capped at {cap} tu, a 2-configuration grid: "
                "no interval, so no agreement, can be claimed" if quick else
                f"the paper's six configurations x {paper['replicas'].max()} runs as the paper; our grid: weights in "
                f"{{{levels_text}}}, {len(grid)} of the paper's ~44,000 configurations, {grid['replicas'].max()} runs "
                f"each; Fig. 7: {fig7['replicas'].max()} runs per (p, delta)"
                f"{' as the paper' if fig7['replicas'].max() == 50 else ' instead of 50'}, and the noise claim on "
                f"{len(tau_at[levels[0]])} pairs")
        agree = sum(ok for _, ok in checks)
        return "\n".join([
            "The paper (section 4) runs every weight configuration 10 times and reports, over ~44,000 of them, the "
            "configurations that reach the desired formation (DF) in all runs with the extreme values of tau, phi "
            "and rho (Fig. 4); for S-2.2 that convergence is more likely when alpha_av >= alpha_a (Fig. 6); and for "
            "S-2.2 with alpha_a = 8, alpha_av = 9, alpha_cv = 4, tau rises smoothly with the communication-failure "
            "probability p up to 0.8, jumps at p = 0.9, and 'epsilon does not affect the convergence' (Fig. 7). "
            f"Ours ({size}). Every number of ours is a mean over runs with its 95 % confidence interval, written "
            "mean [low, high] in the tables (Student's t for means, Wilson's interval for fractions); tau counts "
            "the cap for a run that does not reach the DF; phi and rho are over the runs that reach it, at the end "
            "of the run. A claim **agrees** only where the paper's number lies within our interval. The paper does "
            "not say whether Fig. 4's values are means over a configuration's 10 runs or one run's ('we calculate "
            "the three indexes for each combination'; its Fig. 5, a run of Fig. 4a's configuration, ends at "
            "t = 870 tu, next to Fig. 4a's 871): we compare means; read as one run's values, "
            f"{sum(one_run)} of the six lie within the range of our {int(paper['replicas'].min())} runs (each check "
            "says which).",
            "",
            f"**{agree} of {len(checks)} checks agree.**",
            "",
            *[f"- {claim}: **{verdict(ok)}**" for claim, ok in checks],
            "",
            "### Fig. 4: the paper's six configurations, run as published",
            "",
            "Weights: '-' where the strategy has no such force (Table 1) and the paper gives none; in brackets a "
            "weight that cancels in eq. (3), F = sum(alpha_k F_k) / sum(alpha_k) over the forces acting, since its "
            "force acts alone (Fav inside the VAIR in S-x.1, Fcv outside it in S-x.2): the paper gives it, and in "
            "our reading it changes nothing but the rounding.",
            "",
            *lines,
            "",
            f"Fig. 4's selection on our reduced grid ({n_ok} of {len(grid)} configurations reach the DF in every "
            f"run; {distinct_ok} of its {len(distinct_grid)} distinct models, as only the ratios of the weights "
            "of forces acting together matter; a minimum or maximum over many configurations of few runs each "
            "leans toward the extreme, so the selected configuration's interval is its own, not that of the "
            "selection):",
            "",
            *ext,
            "",
            "### rho: what sets it",
            "",
            "Nothing inside the VAIR pulls an agent toward the VA: Table 1 leaves only Fav and Fa there (Fav alone "
            "for S-x.1), and Fs when a neighbour is too close. An agent therefore keeps the place relative to the VA "
            "where its speed ramp ends (eq. 1), and rho follows from the ramps and from the separation. The ramp "
            f"lasts T + rnd, T = 2 VAIR / (|vout| - |va|) = {ramp:g} tu (the time from the VAIR boundary to the VA "
            "while slowing down), rnd ~ U(-gamma, gamma), and with the paper's gamma = T an agent entering from "
            f"behind stops anywhere on the VAIR's diameter, up to {vair:g} bl behind or in front of the VA: the "
            "'homogeneous distribution of agents inside the VAIR' that the paper asks of gamma = T. Of agents "
            "spread uniformly inside the VAIR the paper says (section 4, on what the quantifiers mean, not of a "
            "run) that rho would be 'around the half of VAIR size'. That is what we get for every configuration: "
            f"the six configurations' mean rho are {paper['rho_mean'].min():.1f} to {paper['rho_mean'].max():.1f} bl "
            f"(their average {rho_all.value:.1f} bl). The paper's smallest rho, 5.20 bl (Fig. 4e, with the same "
            "gamma), packs 12 agents "
            "within about 8 bl of the VA (a uniform disc of radius R has mean distance 2R / 3). Fig. 4e's "
            "configuration without the ramp jitter (every agent then stops at the VA's depth), and also with a 1 bl "
            "minimum separation instead of the paper's 2.5 bl (neither of which the paper states):",
            "",
            *lines_r,
            "",
            "The paper's 5.20 lies within our interval for "
            + (", ".join(label for label, r in variants if self._estimate(r, "rho").holds(5.20)) or "none of these")
            + ": the spread of the ramps sets rho, and the minimum separation how closely the agents can pack.",
            "",
            "### The torus",
            "",
            "The paper's arena is a torus of unstated size; ours is 200 bl (more than twice the initial rectangle's "
            "reach from the VA). Agents that start heading away from the VA turn back at 1 degree per tu, on circles "
            f"of {radius:.0f} bl radius at |vout|, and on a small torus some meet the VA again across the edge: tau "
            f"depends on the size. The six configurations on a {WORLDS[1]:g} bl torus, where nobody wraps before "
            f"the DF (the same initial states, relative to the VA; {sum(torus_moves)} of {len(torus_moves)} paired "
            "differences exclude zero):",
            "",
            *lines_t,
            "",
            f"On the {WORLDS[1]:g} bl torus the paper's tau lies: {on_large}. Where it lies outside on both tori, "
            "the torus size does not account for the difference; we have no tested explanation for it (the paper "
            "gives neither its torus nor whether Fig. 4's numbers are means or one run's).",
            "",
            "### Fig. 7: tau over p and delta",
            "",
            *lines7,
            "",
            f"'{none_by}': none of the cell's runs reached the DF within the cap (tau is not known, so no "
            "interval); a mean near the cap counts the cap for the runs that did not. "
            "Fig. 7 has no numbers in the text, only the shape checked above. The paper gives the noise strength "
            "delta no unit (epsilon in [-delta, delta] is added to the heading's rate, eq. 7); we read it in "
            "degrees. It also says 'the values of epsilon were proportional to theta-dot' without saying how; ours "
            "are drawn uniform in [-delta, delta] whatever the turn, a reading that may differ from the paper's. The "
            "failure p silences every force "
            "of the agent for the step (as the paper says for S-2.2 outside the VAIR: 'they will only try to go "
            "towards VA 10 % of the cases' at p = 0.9), so with turns of at most 1 degree per tu an agent at "
            f"|vout| = {vout:g} circles with radius {radius:.0f} / (1 - p) bl on average and then closes on the VA "
            f"at only |vout| - |va| = {vout - va:g} bl/tu: the agents that start heading away arrive late, and the "
            "DF waits for the last one.",
        ])
