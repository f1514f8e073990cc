"""Li & Wang's adaptive-velocity swarm: convergence, largest cluster, transient time and noise (Figs. 3-6).

Li & Wang, PRE 75, 021917 (2007), papers/002_d777ea4dd61f2aeb.txt, section IV. N = 300 agents start uniform in an
L x L = 5 x 5 square of the open plane with directions uniform in [0, 2 pi), R = 2; each moves at v0 phi_i^alpha
along its neighbourhood's mean direction (eqs. 4-5; alpha = inf is eq. 6). The paper averages 400 realisations
per point (200 in Fig. 6) and states no run length or convergence test; we run 1000 steps and call a realisation
converged when its final R-graph is one cluster (S = 1) and Phi_theta >= 0.999 (the model's ``converged``). The
paper's p also asks that all N agents move "with the same maximum speed v0", which this test leaves out: with a
large alpha an aligned flock can still hold slow agents, so there our p may read high (the report says so).

- Fig. 3: convergence probability p against v0 for several alpha (a), and against alpha for several v0 (b);
  p falls with v0, rises with alpha, and is "very close to 1" at alpha = inf.
- Fig. 4: the relative size S of the largest cluster in the steady state, against v0 and alpha, same trends.
- Fig. 5: the transient time tau (first step where the mean speed reaches 0.98 v0) against alpha >= 1, eq. (10):
  tau ~ beta + gamma log2 alpha with beta ~ 4.0 and gamma ~ 1.4, independent of v0 (5a) and of the density N / L^2
  (5b); beta and gamma fall as R grows, beta -> 1 as R approaches 6 (5c, 5d).
- Fig. 6: Phi_theta (eq. 3) and C_alpha (eq. 11) against the noise eta in [0, 2.5] (eq. 12: xi ~ U[-eta, eta]),
  v0 = 0.6, the time mean over the second half of each run. C_alpha = 1 for alpha = 0 and falls faster with eta
  for larger alpha; for large eta and alpha Phi_theta falls along one straight line.

All replicas of a point run batched (one kernel launch per step for the whole point).
"""

import math
from typing import Any

import numpy as np
import pandas as pd

from tflock.reproduce.experiment import Experiment, Report, Results
from tflock.reproduce.stats import (
    BOOTSTRAP_RESAMPLES,
    Estimate,
    bootstrap_ci,
    difference_ci,
    mean_ci,
    paired_difference_ci,
    proportion_ci,
)

#: the paper's system (section IV): N = 300, initial square L = 5, R = 2, open plane
N, BOX, RADIUS = 300, 5.0, 2.0
#: eq. (10) as the paper states it: tau ~ BETA + GAMMA log2 alpha (Figs. 5a-b), about 18 steps at alpha = 1024
BETA, GAMMA = 4.0, 1.4
FIG6_SPEED = 0.6

CONVERGENCE, NOISE = "liwang-convergence", "liwang-noise"
TAU_SPEED, TAU_DENSITY, TAU_RADIUS = "liwang-tau-v0", "liwang-tau-density", "liwang-tau-radius"


def _alpha_label(alpha: float) -> str:
    return "inf" if math.isinf(alpha) else f"{alpha:g}"


def _sem(values: pd.Series) -> float:
    return float(values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def _with_interval(name: str, values: pd.Series) -> dict[str, float]:
    """The mean of `values` with its standard error and 95 % t interval, as table columns."""
    estimate = mean_ci(values.to_numpy())
    return {name: estimate.value, f"{name}_err": _sem(values), f"{name}_lo": estimate.lo, f"{name}_hi": estimate.hi}


def _p_text(row: pd.Series | None) -> str:
    """A convergence probability with its Wilson interval."""
    if row is None:
        return "none"
    return Estimate(row.p, row.p_lo, row.p_hi, int(row.replicas)).text(3, runs="realisations")


def _half_width(data: pd.DataFrame, column: str) -> float:
    """The largest half-width of the 95 % intervals of `column` over the rows (how precise every cell is)."""
    return float(((data[f"{column}_hi"] - data[f"{column}_lo"]) / 2).max())


#: Fig. 6's "same straight line": two Phi_theta curves are one where their paired difference's 95 % interval lies
#: within +- this (5 % of Phi_theta's range, a difference a reader of the paper's figure could not see)
ONE_CURVE = 0.05
#: the figures' error bars, said on each (the text's intervals are 95 % ones)
ERROR_BARS = "error bars: +-1 standard error over the realisations"


def _tau_runs(results: Results) -> dict[tuple[int, float, float, float], pd.Series]:
    """The tau of every realisation, by seed (NaN where it was not reached), by point (N, R, v0, alpha) of the
    Fig. 5 sweeps."""
    runs: dict[tuple[int, float, float, float], pd.Series] = {}
    for sweep in (TAU_SPEED, TAU_DENSITY, TAU_RADIUS):
        if sweep not in results.sweeps:
            continue
        frame = results.sweeps[sweep]
        keys = ["params.n", "params.radius", "params.speed", "params.alpha"]
        for (n, radius, v0, alpha), group in frame.groupby(keys):
            runs[(int(n), float(radius), float(v0), float(alpha))] = group.set_index("seed")["final_tau"]
    return runs


def _paired_by_seed(first: pd.DataFrame, second: pd.DataFrame, column: str) -> Estimate:
    """Mean of `column` in `second` less in `first` over the seeds (the same initial state) that have a value in
    both, with its t interval."""
    both = pd.concat([frame.set_index("seed")[column] for frame in (first, second)], axis=1,
                     keys=["a", "b"]).dropna()
    return paired_difference_ci(both["a"], both["b"])


def _tau_pairs(results: Results, alpha: float, v0: tuple[float, float]) -> Estimate:
    """Mean tau at the second speed less that at the first (N = 300, R = 2, Fig. 5a), over the realisations that
    reached it at both, paired by seed (the same initial state)."""
    frame = results.sweeps[TAU_SPEED]
    frame = frame[(frame["params.alpha"].astype(float) == alpha) & (frame["params.n"] == N)]
    return _paired_by_seed(frame[frame["params.speed"] == v0[0]], frame[frame["params.speed"] == v0[1]], "final_tau")


class LiWang(Experiment):
    name = "liwang"
    title = "Li-Wang adaptive velocity: convergence probability, largest cluster, transient time, noise"
    source = "Li & Wang, PRE 75 021917 (2007), papers/002_d777ea4dd61f2aeb.txt, Figs. 3-6 and eq. (10)"

    # ------------------------------------------------------------------ sizes
    @staticmethod
    def _base(steps: int, metrics_every: int) -> dict[str, Any]:
        return {"steps": steps, "params.dim": 2, "params.box": BOX, "params.boundary": "open",
                "log.metrics_every": metrics_every}

    def sweeps(self, quick: bool) -> dict[str, dict[str, Any]]:
        if quick:
            speeds, alphas, reps, steps = [0.2, 0.6, 1.0], [0.0, 4.0, "inf"], 8, 100
            tau_alphas, tau_reps, tau_steps, radius_steps = [1.0, 8.0, 64.0, 1024.0], 8, 50, 50
            tau_speeds, tau_ns, tau_radii = [1.0], [], [6.0]
            etas, noise_alphas, noise_reps = [0.0, 1.25, 2.5], [0.0, 4.0], 8
        else:
            speeds = [round(0.1 * k, 1) for k in range(1, 11)]
            alphas, reps, steps = [0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 64.0, "inf"], 400, 1000
            # tau <= 60 at R >= 2 but up to ~90 at R = 1, alpha = 1024: a realisation that never reaches 0.98 v0
            # in the run is reported (``tau_unreached``) and left out of the mean
            tau_alphas, tau_reps, tau_steps, radius_steps = [float(2**k) for k in range(11)], 400, 150, 500
            tau_speeds, tau_ns, tau_radii = [0.2, 0.5, 1.0], [150, 600], [1.0, 3.0, 4.0, 6.0]
            etas, noise_alphas, noise_reps = [round(0.25 * k, 2) for k in range(11)], [0.0, 1.0, 4.0, 16.0], 200
        # tau is tracked every step; metrics only at both ends
        tau_set = {**self._base(tau_steps, tau_steps), "params.noise": 0.0}
        radius_set = {**self._base(radius_steps, radius_steps), "params.noise": 0.0}
        sweeps = {
            CONVERGENCE: {  # Figs. 3 and 4
                "model": "adaptive", "replicas": reps, "seed": 0,
                "set": {**self._base(steps, steps), "params.noise": 0.0},
                "grid": {"params.n": [N], "params.radius": [RADIUS], "params.speed": speeds, "params.alpha": alphas},
            },
            TAU_SPEED: {  # Fig. 5a
                "model": "adaptive", "replicas": tau_reps, "seed": 0, "set": tau_set,
                "grid": {"params.n": [N], "params.radius": [RADIUS], "params.speed": tau_speeds,
                         "params.alpha": tau_alphas},
            },
            TAU_DENSITY: {  # Fig. 5b: the density N / L^2 through N at L = 5
                "model": "adaptive", "replicas": tau_reps, "seed": 0, "set": tau_set,
                "grid": {"params.n": tau_ns, "params.radius": [RADIUS], "params.speed": [1.0],
                         "params.alpha": tau_alphas},
            },
            TAU_RADIUS: {  # Figs. 5c-d, v0 = 1
                "model": "adaptive", "replicas": tau_reps, "seed": 0, "set": radius_set,
                "grid": {"params.n": [N], "params.radius": tau_radii, "params.speed": [1.0],
                         "params.alpha": tau_alphas},
            },
            NOISE: {  # Fig. 6
                "model": "adaptive", "replicas": noise_reps, "seed": 0,
                "set": self._base(steps, steps // 20),  # time means over the second half of the run
                "grid": {"params.n": [N], "params.radius": [RADIUS], "params.speed": [FIG6_SPEED],
                         "params.alpha": noise_alphas, "params.noise": etas},
            },
        }
        return {name: spec for name, spec in sweeps.items() if all(spec["grid"].values())}

    # ------------------------------------------------------------------ report
    def report(self, results: Results, quick: bool) -> Report:
        table = self._summary(results)
        fits = self._tau_fits(table, results)
        figures = {"fig3-convergence": self._figure_vs_v0_alpha(table, "p", "convergence probability p"),
                   "fig4-largest-cluster": self._figure_vs_v0_alpha(table, "S", "largest cluster S"),
                   "fig5-transient": self._figure_tau(table, fits),
                   "fig6-noise": self._figure_noise(table)}
        return Report(figures, table, self._comparison(table, fits, results))

    @staticmethod
    def _summary(results: Results) -> pd.DataFrame:
        """One row per point, with standard errors over the replicas: p and the final S (Figs. 3-4); the mean tau
        and the fraction of realisations that never reached it (Fig. 5); Phi_theta, C_alpha and S as means over
        the second half of each run (Fig. 6)."""
        figure_of = {CONVERGENCE: "3-4", TAU_SPEED: "5a", TAU_DENSITY: "5b", TAU_RADIUS: "5c-d", NOISE: "6"}
        rows = []
        for sweep, frame in results.sweeps.items():
            frame = frame.assign(alpha=frame["params.alpha"].astype(float))  # a mixed column is text: "inf", "4.0"
            keys = ["params.n", "params.radius", "params.speed", "alpha"]
            keys += ["params.noise"] if "params.noise" in frame.columns else []
            for values, group in frame.groupby(keys):
                point = dict(zip(keys, values, strict=True))
                row = {"figure": figure_of[sweep], "n": int(point["params.n"]), "radius": point["params.radius"],
                       "v0": point["params.speed"], "alpha": point["alpha"], "noise": point.get("params.noise", 0.0),
                       "replicas": len(group)}
                if sweep == CONVERGENCE:
                    converged = group["final_converged"]
                    p = proportion_ci(int(converged.sum()), len(group))
                    row.update(p=converged.mean(), p_err=math.sqrt(max(converged.mean() * (1 - converged.mean()), 0)
                                                                   / len(group)), p_lo=p.lo, p_hi=p.hi,
                               **_with_interval("S", group["final_largest_cluster"]))
                elif sweep == NOISE:
                    row.update(**_with_interval("phi_theta", group["mean_phi_theta"]),
                               **_with_interval("c_alpha", group["mean_c_alpha"]),
                               **_with_interval("S", group["mean_largest_cluster"]))
                else:
                    tau = group["final_tau"]
                    row.update(**_with_interval("tau", tau.dropna()), tau_unreached=tau.isna().mean())
                rows.append(row)
        return pd.DataFrame(rows).sort_values(["figure", "n", "radius", "v0", "alpha", "noise"], ignore_index=True)

    # ------------------------------------------------------------------ figures
    @staticmethod
    def _figure_vs_v0_alpha(table: pd.DataFrame, column: str, label: str) -> Any:
        """Panel (a): `column` against v0, one curve per alpha; panel (b): against alpha (evenly spaced, inf
        last), one curve per v0 (at most five, spread over the range)."""
        import matplotlib.pyplot as plt

        data = table[table.figure == "3-4"]
        alphas = sorted(data.alpha.unique())
        figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
        for alpha, group in data.groupby("alpha"):
            left.errorbar(group.v0, group[column], yerr=group[f"{column}_err"], marker="o", ms=3, capsize=2,
                          label=f"alpha = {_alpha_label(alpha)}")
        speeds = sorted(data.v0.unique())
        shown = [speeds[k] for k in sorted({round(i * (len(speeds) - 1) / 4) for i in range(5)})]
        for v0 in shown:
            group = data[data.v0 == v0].sort_values("alpha")
            right.errorbar([alphas.index(a) for a in group.alpha], group[column], yerr=group[f"{column}_err"],
                           marker="o", ms=3, capsize=2, label=f"v0 = {v0:g}")
        right.set_xticks(range(len(alphas)), [_alpha_label(a) for a in alphas])
        left.set_xlabel("maximum speed v0")
        right.set_xlabel("exponent alpha")
        for ax, tag in ((left, "a"), (right, "b")):
            ax.set_ylabel(label)
            ax.set_ylim(0, 1.03)
            ax.set_title(f"({tag}) N = {N}, L = {BOX:g}, R = {RADIUS:g}")
            ax.legend(fontsize=7)
        figure.suptitle(ERROR_BARS, fontsize=9)
        figure.tight_layout()
        return figure

    def _figure_tau(self, table: pd.DataFrame, fits: pd.DataFrame) -> Any:
        """tau against log2 alpha for v0 (a), density (b) and R (c), with eq. (10)'s line; beta and gamma of our
        fits against R (d)."""
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(2, 2, figsize=(10, 8))
        panels = [("5a", "v0", "v0 = {:g}", "(a) by v0, R = 2"),
                  ("5b", "n", "N = {:d}", "(b) by density N / 25, v0 = 1"),
                  ("5c-d", "radius", "R = {:g}", "(c) by R, v0 = 1")]
        for ax, (tag, key, fmt, title) in zip(axes.flat, panels, strict=False):
            data = self._tau_groups(table, tag, key)
            for value, group in data:
                ax.errorbar(np.log2(group.alpha), group.tau, yerr=group.tau_err, marker="o", ms=3, capsize=2,
                            label=fmt.format(value))
            logs = np.log2(sorted(table[table.tau.notna()].alpha.unique())) if "tau" in table else np.zeros(0)
            ax.plot(logs, BETA + GAMMA * logs, "k--", lw=1, label="paper: 4.0 + 1.4 log2 alpha")
            ax.set_xlabel("log2 alpha")
            ax.set_ylabel("transient time tau (steps)")
            ax.set_title(title)
            ax.legend(fontsize=7)
        radius = fits[fits.figure == "5c-d"].sort_values("radius")
        fitting, poor = radius[radius.residual <= 1.0], radius[radius.residual > 1.0]
        ax = axes[1, 1]
        ax.plot(fitting.radius, fitting.beta, "o-", color="C0", label="beta (ours)")
        ax.plot(fitting.radius, fitting.gamma, "s-", color="C1", label="gamma (ours)")
        if len(poor):
            ax.plot(poor.radius, poor.beta, "o", mfc="none", color="C0", label="beta, gamma where tau is not")
            ax.plot(poor.radius, poor.gamma, "s", mfc="none", color="C1", label="  log-linear (residual > 1 step)")
        ax.axhline(BETA, color="C0", ls=":", label="paper beta at R = 2")
        ax.axhline(GAMMA, color="C1", ls=":", label="paper gamma at R = 2")
        ax.axhline(1.0, color="grey", ls="--", lw=1, label="paper: beta -> 1 as R -> 6")
        ax.set_xlabel("sensing radius R")
        ax.set_ylabel("fit coefficient")
        ax.set_title("(d) eq. (10) fits against R, v0 = 1")
        ax.legend(fontsize=7)
        figure.suptitle(ERROR_BARS, fontsize=9)
        figure.tight_layout()
        return figure

    @staticmethod
    def _tau_groups(table: pd.DataFrame, tag: str, key: str) -> list[tuple[Any, pd.DataFrame]]:
        """Fig. 5 panel `tag`'s curves by `key`; the reference point (N = 300, R = 2, v0 = 1) joins panels b and c
        from the v0 sweep, where it is not rerun; no curves where the panel's sweep did not run."""
        data = table[table.figure == tag]
        if data.empty:
            return []
        reference = table[(table.figure == "5a") & (table.v0 == 1.0)]
        if tag != "5a" and len(reference) and not (data[key] == reference[key].iloc[0]).any():
            data = pd.concat([data, reference])
        return [(value, group.sort_values("alpha")) for value, group in data.groupby(key)]

    def _tau_fits(self, table: pd.DataFrame, results: Results) -> pd.DataFrame:
        """Least-squares beta, gamma of eq. (10) on the mean tau of each curve of Fig. 5 (alpha >= 1), with 95 %
        bootstrap intervals (the realisations resampled whole: a realisation's seed is the same at every alpha, so
        its tau along a curve are correlated), and the largest distance of a point from
        its line (``residual``: how well a log law describes the curve)."""
        runs = _tau_runs(results)
        rows = []
        for tag, key in (("5a", "v0"), ("5b", "n"), ("5c-d", "radius")):
            for _, group in self._tau_groups(table, tag, key) if "tau" in table else []:
                group = group[(group.alpha >= 1) & group.tau.notna()]
                if len(group) < 2:
                    continue
                logs = np.log2(group.alpha.to_numpy())
                gamma, beta = np.polyfit(logs, group.tau, 1)
                residual = float(np.max(abs(beta + gamma * logs - group.tau)))
                top = group[group.alpha == group.alpha.max()].iloc[0]
                samples = pd.concat([runs[(int(r.n), r.radius, r.v0, r.alpha)] for r in group.itertuples()],
                                    axis=1).to_numpy()  # a row per seed, a column per alpha

                def fit(resampled: np.ndarray, which: int, logs: np.ndarray = logs) -> float:
                    return float(np.polyfit(logs, np.nanmean(resampled, axis=0), 1)[which])

                b = bootstrap_ci(samples, lambda x: fit(x, 1), beta)
                g = bootstrap_ci(samples, lambda x: fit(x, 0), gamma)
                rows.append({"figure": tag, "v0": group.v0.iloc[0], "n": int(group.n.iloc[0]),
                             "radius": group.radius.iloc[0], "beta": beta, "beta_lo": b.lo, "beta_hi": b.hi,
                             "gamma": gamma, "gamma_lo": g.lo, "gamma_hi": g.hi, "residual": residual,
                             "alpha_max": top.alpha, "tau_at_max": top.tau, "tau_at_max_lo": top.tau_lo,
                             "tau_at_max_hi": top.tau_hi, "replicas": int(group.replicas.min()),
                             "unreached": group.tau_unreached.max()})
        return pd.DataFrame(rows, columns=["figure", "v0", "n", "radius", "beta", "beta_lo", "beta_hi", "gamma",
                                           "gamma_lo", "gamma_hi", "residual", "alpha_max", "tau_at_max",
                                           "tau_at_max_lo", "tau_at_max_hi", "replicas", "unreached"])

    @staticmethod
    def _figure_noise(table: pd.DataFrame) -> Any:
        """Phi_theta (a) and C_alpha (b) against eta, one curve per alpha, and the largest cluster S (c) that
        tells a dispersed swarm from one held together; (a) also shows sin(eta) / eta."""
        import matplotlib.pyplot as plt

        data = table[table.figure == "6"]
        figure, axes = plt.subplots(1, 3, figsize=(14, 4))
        for ax, column, label in ((axes[0], "phi_theta", "global order Phi_theta"),
                                  (axes[1], "c_alpha", "mean speed coefficient C_alpha"),
                                  (axes[2], "S", "largest cluster S")):
            for alpha, group in data.groupby("alpha"):
                ax.errorbar(group.noise, group[column], yerr=group[f"{column}_err"], marker="o", ms=3, capsize=2,
                            label=f"alpha = {_alpha_label(alpha)}")
            ax.set_xlabel("noise amplitude eta (rad)")
            ax.set_ylabel(label)
            ax.set_ylim(0, 1.03)
        eta = np.linspace(1e-3, max(data.noise.max(), 1e-3), 100)
        axes[0].plot(eta, np.sin(eta) / eta, "k--", lw=1, label="sin(eta) / eta")
        for ax in axes:
            ax.legend(fontsize=7)
        axes[0].set_title(f"(a) v0 = {FIG6_SPEED:g}, mean over the second half of each run")
        axes[1].set_title("(b)")
        axes[2].set_title("(c) not in the paper")
        figure.suptitle(ERROR_BARS, fontsize=9)
        figure.tight_layout()
        return figure

    # ------------------------------------------------------------------ comparison
    @staticmethod
    def _monotone(values: np.ndarray, errors: np.ndarray, replicas: int, increasing: bool) -> bool:
        """Whether `values` move one way within noise: no step against the trend larger than two combined
        standard errors plus one realisation's worth (1 / replicas)."""
        steps = np.diff(values) * (1 if increasing else -1)
        allowance = 2 * np.hypot(errors[1:], errors[:-1]) + 1 / replicas
        return bool(np.all(steps >= -allowance))

    def _comparison(self, table: pd.DataFrame, fits: pd.DataFrame, results: Results) -> str:
        sections = [self._compare_convergence(table), self._compare_tau(table, fits, results),
                    self._compare_noise(table, results)]
        return "\n\n".join(section for section in sections if section)

    def _compare_convergence(self, table: pd.DataFrame) -> str:
        data = table[table.figure == "3-4"]
        if data.empty:
            return ""
        reps = int(data.replicas.min())
        speeds, alphas = sorted(data.v0.unique()), sorted(data.alpha.unique())
        lines = ["| alpha | " + " | ".join(f"v0 = {v:g}" for v in speeds) + " | p falls with v0 | S falls with v0 |",
                 "|---|" + "---|" * (len(speeds) + 2)]
        falls = []
        for alpha, group in data.groupby("alpha"):
            group = group.sort_values("v0")
            p_falls = self._monotone(group.p.to_numpy(), group.p_err.to_numpy(), reps, increasing=False)
            s_falls = self._monotone(group.S.to_numpy(), group.S_err.to_numpy(), reps, increasing=False)
            falls.append(p_falls and s_falls)
            cells = " | ".join(f"{p:.2f} / {s:.3f}" for p, s in zip(group.p, group.S, strict=True))
            lines.append(f"| {_alpha_label(alpha)} | {cells} | {'yes' if p_falls else 'no'} | "
                         f"{'yes' if s_falls else 'no'} |")
        rises = []
        for _, group in data.groupby("v0"):
            group = group.sort_values("alpha")
            rises.append(self._monotone(group.p.to_numpy(), group.p_err.to_numpy(), reps, increasing=True)
                         and self._monotone(group.S.to_numpy(), group.S_err.to_numpy(), reps, increasing=True))
        ends = {alpha: g.sort_values("v0").iloc[[0, -1]] for alpha, g in data.groupby("alpha")}  # slowest, fastest
        drops = {alpha: tuple(e[c].iloc[0] - e[c].iloc[1] for c in ("p", "S")) for alpha, e in ends.items()}
        drop_errors = {alpha: tuple(math.hypot(*e[f"{c}_err"]) for c in ("p", "S")) for alpha, e in ends.items()}
        # slower for larger alpha: no drop above the next smaller alpha's by more than 1.96 standard errors
        slower = all(drops[b][c] - drops[a][c] <= 1.96 * math.hypot(drop_errors[a][c], drop_errors[b][c])
                     for a, b in zip(alphas, alphas[1:], strict=False) for c in (0, 1))
        inf = data[np.isinf(data.alpha)]
        zero_fast = data[(data.alpha == alphas[0]) & (data.v0 == speeds[-1])]
        inf_fast = inf[inf.v0 == speeds[-1]]
        lowest = inf.sort_values("p").iloc[0] if len(inf) else None
        first, last = drops[alphas[0]], drops[alphas[-1]]
        checks = {
            "p and S fall with v0 at every alpha (Figs. 3a, 4a)": all(falls),
            f"... more slowly for larger alpha (our bar: the drop from v0 = {speeds[0]:g} to {speeds[-1]:g} smaller "
            f"at the largest alpha than at the smallest, and at no alpha above the next smaller alpha's by more than "
            f"1.96 standard errors of their difference): p drops by "
            + ", ".join(f"{drops[a][0]:.2f}" for a in alphas) + ", S by "
            + ", ".join(f"{drops[a][1]:.3f}" for a in alphas)
            + f" at alpha = {', '.join(_alpha_label(a) for a in alphas)}":
                last[0] < first[0] and last[1] < first[1] and slower,
            "p and S rise with alpha at every v0 (Figs. 3b, 4b)": all(rises),
            f"p at alpha = inf close to 1 (our bar: the 95 % interval of the lowest one reaches 0.95; lowest: "
            f"{_p_text(lowest)} at v0 = {lowest.v0 if lowest is not None else math.nan:g}; lowest S "
            f"{inf.S.min() if len(inf) else math.nan:.4f})":
                lowest is not None and lowest.p_hi >= 0.95,
            f"at the fastest v0 = {speeds[-1]:g}, alpha = inf converges far more often than alpha = "
            f"{_alpha_label(alphas[0])} (p = {_p_text(inf_fast.iloc[0] if len(inf_fast) else None)} vs "
            f"{_p_text(zero_fast.iloc[0])}; our bar: the intervals more than 0.5 apart)":
                len(inf_fast) > 0 and float(inf_fast.p_lo.iloc[0]) - float(zero_fast.p_hi.iloc[0]) > 0.5,
        }
        return "\n".join([
            "## Figs. 3-4: convergence probability p and largest cluster S",
            "",
            "The paper (section IV, no numbers beyond these): p and S decrease with v0 for every alpha, and more "
            "slowly for larger alpha; they increase with alpha for every v0; at large v0 convergence is 'practically "
            "impossible' for the Vicsek case alpha = 0 but likely for large alpha; 'the convergence probability is "
            "very close to 1 in the case of alpha = inf'. Ours (converged: final S = 1 and Phi_theta >= 0.999, "
            "which leaves out the paper's 'with the same maximum speed v0': with a large alpha an aligned flock can "
            "still hold slow agents, so at large alpha our p may read higher than the paper's definition would; "
            f"{reps} realisations per point; cells p / S; the 95 % intervals are at most +-{_half_width(data, 'p'):.3f}"
            f" wide for p (Wilson) and +-{_half_width(data, 'S'):.3f} for S (t); a trend 'falls' or 'rises' where "
            "no step goes against it by more than two combined standard errors plus one realisation's worth):",
            "",
            *lines,
            "",
            *self._checks(checks),
        ])

    def _compare_tau(self, table: pd.DataFrame, fits: pd.DataFrame, results: Results) -> str:
        if fits.empty:
            return ""

        def interval(fit: Any, name: str) -> Estimate:
            return Estimate(getattr(fit, name), getattr(fit, f"{name}_lo"), getattr(fit, f"{name}_hi"), fit.replicas)

        lines = ["| panel | v0 | N | R | beta [95 % CI] | gamma [95 % CI] | largest residual | tau at alpha_max "
                 "[95 % CI] | unreached | realisations a point |", "|---|---|---|---|---|---|---|---|---|---|"]
        for fit in fits.itertuples():
            top = Estimate(fit.tau_at_max, fit.tau_at_max_lo, fit.tau_at_max_hi, fit.replicas)
            lines.append(f"| {fit.figure} | {fit.v0:g} | {fit.n} | {fit.radius:g} | {interval(fit, 'beta').short()} | "
                         f"{interval(fit, 'gamma').short()} | {fit.residual:.2f} | {top.short(1)} (alpha = "
                         f"{fit.alpha_max:g}) | {fit.unreached:.1%} | {fit.replicas} |")
        reference = fits[(fits.radius == RADIUS) & (fits.figure != "5c-d")].drop_duplicates(["v0", "n"])
        checks: dict[str, bool] = {}
        for fit in reference.sort_values(["n", "v0"]).itertuples():
            curve = f"v0 = {fit.v0:g}, N = {fit.n}, R = {fit.radius:g}"
            for name, paper in (("beta", BETA), ("gamma", GAMMA)):
                ours = interval(fit, name)
                checks[f"{name} = {paper:.1f} at {curve}: ours {ours.text(2, runs='realisations a point')}"] = \
                    ours.holds(paper)
            if fit.alpha_max == 1024:
                top = Estimate(fit.tau_at_max, fit.tau_at_max_lo, fit.tau_at_max_hi, fit.replicas)
                checks[f"'about 18 steps' at alpha = 1024, {curve}: ours "
                       f"{top.text(1, 'steps', 'realisations')}"] = top.holds(18.0)
        notes: list[str] = []
        at_one = []  # eq. (10) at alpha = 1 reads tau = beta: the measured tau there, where the fitted beta misses
        for fit in reference.sort_values(["n", "v0"]).itertuples():
            row = table[table.figure.isin(["5a", "5b"]) & (table.v0 == fit.v0) & (table.n == fit.n)
                        & (table.radius == fit.radius) & (table.alpha == 1.0) & table.tau.notna()]
            if len(row) and not interval(fit, "beta").holds(BETA):
                tau = Estimate(row.tau.iloc[0], row.tau_lo.iloc[0], row.tau_hi.iloc[0], int(row.replicas.iloc[0]))
                at_one.append(f"v0 = {fit.v0:g}, N = {fit.n}: {tau.short(2)}"
                              + (" (holds 4.0)" if tau.holds(BETA) else ""))
        if at_one:
            notes.append(
                "Where the fitted beta misses the paper's 4.0: eq. (10) at alpha = 1 reads tau = beta, and our mean "
                f"tau at alpha = 1 (95 % t interval) is {'; '.join(at_one)}. The fitted intercept differs from it "
                "where the curve bends in log2 alpha (the largest residual in the table); the paper's beta may be "
                "read off its figure at alpha = 1 or fitted, it does not say.")
        speeds = sorted(table[(table.figure == "5a") & table.tau.notna()].v0.unique())
        if len(speeds) > 1 and TAU_SPEED in results.sweeps:
            alphas = sorted(table[table.figure == "5a"].alpha.unique())
            gaps = {alpha: _tau_pairs(results, alpha, (speeds[-1], speeds[0])) for alpha in alphas}
            moved = [alpha for alpha, gap in gaps.items() if gap.excludes(0.0)]
            for alpha in (alphas[0], alphas[-1]):
                checks[f"tau does not distinctly depend on v0 (Fig. 5a), alpha = {alpha:g}: tau at v0 = {speeds[0]:g} "
                       f"less tau at v0 = {speeds[-1]:g}, paired by initial state: "
                       f"{gaps[alpha].text(2, 'steps', 'pairs')}"] = gaps[alpha].holds(0.0)
            notes.append(
                f"Over alpha = {alphas[0]:g} to {alphas[-1]:g}, the paired difference between v0 = {speeds[0]:g} "
                f"and v0 = {speeds[-1]:g} excludes zero at alpha = {', '.join(f'{a:g}' for a in moved) or 'none'}, "
                f"largest {max(gaps.values(), key=lambda g: abs(g.value)).text(2, 'steps', 'pairs')}; at alpha = "
                f"{alphas[-1]:g} it is {gaps[alphas[-1]].text(2, 'steps', 'pairs')}: tau depends on v0 by about a "
                "step, whose sign may change with alpha, where the paper says tau 'does not distinctly depend on the "
                "maximum speed v0' (Figs. 5a-b).")
        densities = table[(table.figure == "5b") & table.tau.notna()]
        if len(densities):
            runs = _tau_runs(results)
            for n in sorted(densities.n.unique()):
                worst = max((difference_ci(runs[(N, RADIUS, 1.0, a)].dropna(), runs[(int(n), RADIUS, 1.0, a)].dropna())
                             for a in sorted(densities.alpha.unique()) if (N, RADIUS, 1.0, a) in runs),
                            key=lambda d: abs(d.value))
                checks[f"tau does not distinctly depend on the density (Fig. 5b): N = {n} against N = {N} at v0 = 1, "
                       f"the largest difference over alpha {worst.text(2, 'steps', 'realisations')}"] = \
                    worst.holds(0.0)
        radius = fits[fits.figure == "5c-d"].sort_values("radius")
        logarithmic = radius[radius.residual <= 1.0]  # where eq. (10) describes the curve, to a step
        if len(fits):
            poor = fits[fits.residual > 1.0]
            checks[f"tau grows logarithmically with alpha, 'generically' (eq. 10; our bar: every curve of Fig. 5 "
                   f"within a step of its fitted line: {len(fits) - len(poor)} of {len(fits)} curves"
                   + "".join(f"; not at {r.figure} N = {r.n}, R = {r.radius:g}, v0 = {r.v0:g} (largest residual "
                             f"{r.residual:.2f} steps)" for r in poor.itertuples()) + ")"] = poor.empty
        if len(logarithmic) > 1:
            excluded = radius[radius.residual > 1.0]
            rows = list(logarithmic.itertuples())

            def falls(name: str) -> bool:  # lower at the largest R, and no step up beyond the intervals
                steps = zip(rows, rows[1:], strict=False)
                return getattr(rows[-1], name) < getattr(rows[0], name) and not any(
                    getattr(later, f"{name}_lo") > getattr(earlier, f"{name}_hi") for earlier, later in steps)

            checks[f"beta and gamma fall as R grows (no rise beyond the intervals), over the R where eq. (10) fits "
                   f"within a step (R = {', '.join(f'{r:g}' for r in logarithmic.radius)}: beta "
                   f"{', '.join(interval(f, 'beta').short() for f in logarithmic.itertuples())}; gamma "
                   f"{', '.join(interval(f, 'gamma').short() for f in logarithmic.itertuples())}"
                   + "".join(f"; left out: R = {r.radius:g}, largest residual {r.residual:.2f} steps, beta "
                             f"{r.beta:.2f}, gamma {r.gamma:.2f}" for r in excluded.itertuples()) + ")"] = (
                falls("beta") and falls("gamma"))
            notes += [f"At R = {r.radius:g} eq. (10) does not describe tau (largest residual {r.residual:.2f} steps). "
                      f"Our reading, not tested: {r.unreached:.1%} of that curve's realisations (at its worst alpha) "
                      "never reach 0.98 v0 in the run and are left out of the mean, so the mean is taken over the "
                      "realisations that did, which bends the curve; the paper's 'generically' leaves such radii "
                      "open." for r in excluded.itertuples()]
        if len(radius) > 1:
            largest = radius.iloc[-1]
            beta = Estimate(largest.beta, largest.beta_lo, largest.beta_hi, int(largest.replicas))
            checks[f"beta approaches 1 as R approaches 6: at R = {largest.radius:g} ours "
                   f"{beta.text(2, runs='realisations a point')}"] = largest.radius >= 5.5 and beta.holds(1.0)
        return "\n".join([
            "## Fig. 5: transient time tau against alpha",
            "",
            "The paper, eq. (10): tau ~ beta + gamma log2 alpha for alpha >= 1 (beta an offset in steps, gamma the "
            "steps added by each doubling of alpha), 'beta ~ 4.0 and gamma ~ 1.4' for "
            "N = 300, L = 5, R = 2: 'tau does not distinctly depend on the maximum speed v0 and the density N/L^2' "
            "(Figs. 5a-b), so 'even for a very high value of alpha = 1024, most agents will move with nearly the "
            "maximum speed in just about 18 steps'; beta and gamma decrease as R increases, and beta approaches 1 "
            "as R approaches 6 (Figs. 5c-d). tau is the first step where the mean speed reaches 0.98 v0. Our "
            "least-squares fits of the mean tau on log2 alpha (alpha = 1, 2, 4, ...), with 95 % bootstrap "
            f"intervals ({BOOTSTRAP_RESAMPLES} resamples of the realisations, each drawn whole across a curve's "
            "points: a realisation has one seed, so one initial state, at every alpha); 'largest residual': "
            "the farthest mean tau from the fitted line, in steps; 'unreached': the largest fraction of "
            "realisations of a curve whose mean speed never reached 0.98 v0 in the run, left out of the mean; the "
            "N = 300, R = 2, v0 = 1 curve is shared by the three panels. The v0 of 5a and the N of 5b (at L = 5) "
            "are ours: the paper's text gives neither, and its caption of Fig. 5b reads 'for different values of R, "
            "v0 = 1.0' where its prose says Figs. 5a-b vary v0 and the density N/L^2. A number agrees where the "
            "paper's printed number lies within our interval, however near it is (1.4 against [1.41, 1.47] would "
            "not agree):",
            "",
            *lines,
            "",
            *self._checks(checks),
            *(line for note in notes for line in ("", note)),  # a paragraph each
        ])

    def _compare_noise(self, table: pd.DataFrame, results: Results) -> str:
        data = table[table.figure == "6"]
        if data.empty:
            return ""
        reps = int(data.replicas.min())
        run_steps = ", ".join(f"{int(k)}" for k in sorted(results.sweeps[NOISE]["steps"].unique()))
        etas = sorted(data.noise.unique())
        lines = ["| alpha | " + " | ".join(f"eta = {e:g}" for e in etas) + " |", "|---|" + "---|" * len(etas)]
        for alpha, group in data.groupby("alpha"):
            group = group.sort_values("noise")
            cells = " | ".join(f"{p:.3f} / {c:.3f} / {s:.2f}"
                               for p, c, s in zip(group.phi_theta, group.c_alpha, group.S, strict=True))
            lines.append(f"| {_alpha_label(alpha)} | {cells} |")
        lines.append("| sin(eta) / eta | " + " | ".join(f"{math.sin(e) / e if e else 1.0:.3f}" for e in etas) + " |")
        zero = data[data.alpha == 0]
        positive = data[data.alpha > 0]
        falls = all(self._monotone(g.sort_values("noise").c_alpha.to_numpy(), g.sort_values("noise").c_alpha_err
                                   .to_numpy(), reps, increasing=False) for _, g in positive.groupby("alpha"))
        at_max = positive[positive.noise == etas[-1]].sort_values("alpha")
        ordered = all(bool((lo[j:] <= hi[j - 1]).all())  # every larger alpha against every smaller one
                      for _, g in positive[positive.noise > 0].sort_values("alpha").groupby("noise")
                      for lo, hi in [(g.c_alpha_lo.to_numpy(), g.c_alpha_hi.to_numpy())] for j in range(1, len(g)))
        at_max_cells = [f"{_alpha_label(r.alpha)}: {r.c_alpha:.3f} [{r.c_alpha_lo:.3f}, {r.c_alpha_hi:.3f}]"
                        for r in at_max.itertuples()]
        checks = {
            f"C_alpha = 1 at alpha = 0 for every eta (ours {zero.c_alpha.min():.4f} to {zero.c_alpha.max():.4f})":
                len(zero) > 0 and bool((abs(zero.c_alpha - 1) < 1e-3).all()),
            "C_alpha falls with eta for every alpha > 0": falls,
            f"C_alpha decreases to zero faster for larger alpha (at every eta > 0, no larger alpha's C_alpha "
            f"above a smaller one's beyond their intervals; at eta = {etas[-1]:g} below 0.05 at the largest alpha: "
            f"{', '.join(at_max_cells)})":
                len(at_max) > 0 and at_max.c_alpha.iloc[-1] < 0.05 and ordered,
        }
        large = sorted(positive.alpha.unique())[-2:]
        if len(large) == 2 and len(etas) > 2:
            checks.update(self._one_line(data, results, large, etas))
        notes = [
            "Our reading: with large alpha and noise the speeds phi^alpha vanish, the swarm freezes as one cluster "
            "(S ~ 1: the third number of each cell, and panel c) whose members all see nearly the whole group, so "
            "each direction is the common mean "
            "turned by xi ~ U[-eta, eta] and Phi_theta = |E exp(i xi)| = sin(eta) / eta, which is close to a "
            "straight line for eta >= 1.25 (table row above). With small alpha (or small eta) the agents keep "
            "moving, and in the open plane, with no cohesion, the noisy swarm evaporates into lone agents (S -> 0): "
            "their phi is 1 (their own direction), so their C_alpha climbs back toward 1 and Phi_theta falls to the "
            "1 / sqrt(N) level of random directions as the run goes on. Our numbers therefore depend on the run "
            "length (the paper gives none); C_alpha and Phi_theta of the moving curves keep drifting after the "
            "transient, while the frozen curves do not.",
        ]
        return "\n".join([
            "## Fig. 6: order and speed against noise",
            "",
            "The paper (v0 = 0.6, eta in [0, 2.5], 200 realisations, no numbers in the text): 'for large noise "
            "amplitude eta and large exponent alpha, the global order parameter Phi_theta decreases along the same "
            "straight line'; C_alpha 'always equals one for alpha = 0' and 'decreases to zero with a faster speed as "
            "the noise amplitude eta increases for larger value of alpha > 0'. The paper gives no run length and no "
            "alpha values for Fig. 6; ours are alpha = "
            f"{', '.join(_alpha_label(a) for a in sorted(data.alpha.unique()))} and {run_steps} steps a run. Ours "
            f"(time mean over the second half of each run, {reps} realisations per point; cells Phi_theta / C_alpha / "
            "S, whose 95 % t intervals are "
            f"at most +-{_half_width(data, 'phi_theta'):.3f}, +-{_half_width(data, 'c_alpha'):.3f} and "
            f"+-{_half_width(data, 'S'):.3f} wide):",
            "",
            *lines,
            "",
            *self._checks(checks),
            "",
            *notes,
        ])

    @staticmethod
    def _one_line(data: pd.DataFrame, results: Results, large: list[float], etas: list[float]) -> dict[str, bool]:
        """The claim that for large eta the two largest alphas' Phi_theta fall along one straight line. The paper
        reads it off a figure and gives no number, so "one curve" is a test of equivalence: at each eta, the 95 %
        interval of the paired difference of the realisations' Phi_theta (the same seed, so the same initial state,
        at both alphas) lies wholly within +-ONE_CURVE (a difference a reader of the figure could not see); the
        curve is "straight" where the least-squares line through the larger alpha's means over the largest etas at
        which the curves are one lies within each of those means' 95 % intervals. Needs three such etas (two points
        are always on a line). The text also says where the paired intervals exclude 0 (differences the
        realisations resolve although the figure could not show them)."""
        frame = results.sweeps[NOISE].assign(alpha=results.sweeps[NOISE]["params.alpha"].astype(float))
        differences = []  # the larger alpha's less the smaller's, at each eta
        for eta in etas:
            at = frame[frame["params.noise"] == eta]
            differences.append(_paired_by_seed(at[at.alpha == large[0]], at[at.alpha == large[1]], "mean_phi_theta"))
        one = [-ONE_CURVE <= d.lo and d.hi <= ONE_CURVE for d in differences]
        shared = len(one) if all(one) else one[::-1].index(False)  # the largest etas where the curves are one
        tail = np.array(etas[len(etas) - shared:])
        curve = data[data.alpha == large[1]].sort_values("noise").tail(shared)
        names = ", ".join(_alpha_label(a) for a in large)
        resolved = sum(not d.holds(0.0) for d in differences[len(etas) - shared:])
        text = (f"for large eta the two largest alphas ({names}) fall along one straight line: the 95 % interval of "
                f"the paired difference in Phi_theta (alpha = {_alpha_label(large[1])} less alpha = "
                f"{_alpha_label(large[0])}) lies within +-{ONE_CURVE:g} at the {shared} largest eta"
                + (f" (from {tail[0]:g}: "
                   + ", ".join(d.short(4) for d in differences[len(etas) - shared:])
                   + f"; {resolved} of them exclude 0)" if shared else ""))
        if shared < len(etas):
            text += f", not at eta = {etas[len(etas) - shared - 1]:g} ({differences[len(etas) - shared - 1].short(3)})"
        straight = False
        if shared >= 3:
            slope, intercept = np.polyfit(tail, curve.phi_theta.to_numpy(), 1)
            miss = np.abs(np.polyval([slope, intercept], tail) - curve.phi_theta.to_numpy())
            half = ((curve.phi_theta_hi - curve.phi_theta_lo) / 2).to_numpy()
            straight = bool((miss <= half).all())
            frozen = float(np.max(np.abs(curve.phi_theta.to_numpy() - np.sin(tail) / tail)))
            text += (f"; the line Phi_theta = {intercept:.2f} {slope:+.2f} eta through the larger alpha's means "
                     f"misses them by at most {miss.max():.4f}, against half-intervals of {half.min():.4f} to "
                     f"{half.max():.4f}; the means are within {frozen:.3f} of sin(eta) / eta there")
        elif shared:
            text += " (too few for a straight line to be tested)"
        return {text: shared >= 3 and straight}

    @staticmethod
    def _checks(checks: dict[str, bool]) -> list[str]:
        verdict = "agrees" if all(checks.values()) else "does NOT fully agree"
        return [f"Verdict: {verdict} ({sum(checks.values())} of {len(checks)} checks).", "",
                *(f"- [{'x' if ok else ' '}] {text}" for text, ok in checks.items())]
