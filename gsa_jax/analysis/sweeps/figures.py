"""A sweep's figures: learning curves, return vs K (with the verdicts' margin and smallest sufficient K), performance
profiles (gsa_jax.analysis.sweep_report.plot_sweep draws them all)."""

import math
from typing import Any, Sequence

import numpy as np

from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.kinds import MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.tables import cell_curves, cell_label, cell_order, k_curves


def plot_curves(data: dict, action_dims: dict, failed: dict, column: str, path: str, title: str,
                reps: int = stats.CURVE_REPS) -> None:
    """Per task, the IQM learning curve of every cell with its 95% bootstrap band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    window = max(1, min(len(s["episode_return"]) for seeds in data.values() for s in seeds.values()) // 50)
    curves = cell_curves(data, column, window, reps)
    env_names = list(dict.fromkeys(c.env for c in sorted(data)))
    ncols = min(3, len(env_names))
    fig, axes = plt.subplots(math.ceil(len(env_names) / ncols), ncols, figsize=(max(7.0, 5.2 * ncols), 3.9 * math.ceil(len(env_names) / ncols) + 0.3), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        cells = sorted((c for c in data if c.env == env_name), key=cell_order)
        for i, cell in enumerate(c for c in cells if c in curves):
            xs, iqm, lo, hi = curves[cell]
            style = dict(color="black", lw=2.0) if cell.policy == MLP else dict(color=plt.cm.viridis(i / max(1, len(cells) - 1) * 0.9), lw=1.6)
            n_failed = f", {len(failed[cell])} failed (NaN/inf), not shown" if cell in failed else ""
            ax.plot(xs, iqm, marker="o" if column == "eval_return" else None, ms=3,
                    label=f"{cell_label(cell, action_dims)} (n={len(data[cell])}{n_failed})", **style)
            ax.fill_between(xs, lo, hi, alpha=0.18, color=style["color"], lw=0)
        ax.set(title=env_name, xlabel="environment steps", ylabel="episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(env_names):]:
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def mark_sufficient_k(ax: Any, table: list, env_name: str) -> None:
    """A dotted vertical line at the task's smallest sufficient K at the default margin (sufficient_k_table)."""
    for r in table:
        if r["env"] == env_name and r["default_margin"] and r["smallest_sufficient_K"] != "":
            ax.axvline(r["smallest_sufficient_K"], color="tab:green", ls=":", lw=1.5,
                       label=f"smallest sufficient K (margin {r['margin']:g}): {r['smallest_sufficient_K']}")


def draw_margin(ax: Any, verdict_rows: list, env_name: str) -> None:
    """A dashed line at flat PPO's IQM less the default margin of its gain over a random policy (or at the target
    less the margin): the level a mixture's IQM must be shown above to be called sufficient."""
    for r in verdict_rows:
        if r["env"] == env_name and r["default_margin"] and r["reference_iqm"] != "" and r["random_return"] != "":
            ref, rnd = float(r["reference_iqm"]), float(r["random_return"])
            ax.axhline(ref - r["margin"] * (ref - rnd), color="tab:red", ls="--", lw=1.2,
                       label=f"{r['versus']} - {r['margin']:g} x (its gain over a random policy)")
            return


def plot_return_vs_k(rows: list, path: str, settings: Sequence[str] = (), sufficient: Sequence = (),
                     verdict_rows: Sequence = ()) -> None:
    """Final score IQM (95% bootstrap CI over seeds) against K per task; flat PPO as a horizontal band, the default
    margin below it (dashed) and the smallest sufficient K (dotted). One curve per value of the `settings` columns
    (the cells' sub-policy class, critic, swept hyperparameters)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in rows))
    point, low, high = C.IQM_CI
    fig, axes = plt.subplots(1, len(env_names), figsize=(max(6.5, 4.6 * len(env_names)), 4.0), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        mark_sufficient_k(ax, sufficient, env_name)
        draw_margin(ax, verdict_rows, env_name)
        curves = k_curves(rows, env_name, settings)
        all_ks = sorted({r["K"] for pts in curves.values() for r in pts})
        for extra, pts in curves.items():
            iqm = np.array([r[point] for r in pts], float)
            err = np.array([[r[point] - r[low], r[high] - r[point]] for r in pts], float).T
            sub = dict(extra).get("subpolicy") or subpolicies.DEFAULT
            rest = "".join(f", {c}={v}" for c, v in extra if c != "subpolicy")
            ax.errorbar([r["K"] for r in pts], iqm, yerr=err, fmt="o-", capsize=3, label=f"mixture of K {sub} controllers{rest}")
        if all_ks:
            ax.set_xscale("log", base=2)
            ax.set_xticks(all_ks, [f"{int(k)}" for k in all_ks])
        for r in rows:
            if r["env"] == env_name and r["policy"] == MLP and r[C.SEEDS]:
                ax.axhspan(r[low], r[high], color="k", alpha=0.15, lw=0)
                ax.axhline(r[point], color="k", lw=1.5, label="flat PPO (MLP 64x64)")
        ax.set(title=env_name, xlabel="K (number of clusters / sub-policies)", ylabel=f"final score ({rows[0].get('score', '')})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("How many (and how complex) controllers does the task need?\n(final score: IQM, 95% bootstrap CI)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


PROFILE_XLABEL = "normalized score tau (0 = random policy, 1 = flat PPO's final IQM)"


def plot_profiles(normalized: dict, path: str, reps: int = stats.REPS, xlabel: str = PROFILE_XLABEL) -> None:
    """Performance profiles: the fraction of runs (averaged over tasks) whose normalized score exceeds tau.
    normalized: {(configuration, (column, value)...): (tasks, scores [runs, tasks])}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = max(1.5, max(float(np.max(m)) for _, m in normalized.values()))
    taus = np.linspace(0.0, top, 60)
    prof = stats.performance_profiles({str(k): m for k, (_, m) in normalized.items()}, taus, reps)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, (k, (tasks, _)) in enumerate(normalized.items()):
        frac, lo, hi = prof[str(k)]
        color = "black" if k[0] == "flat PPO" else plt.cm.viridis(i / max(1, len(normalized) - 1) * 0.9)
        ax.plot(taus, frac, color=color, label=" ".join([k[0]] + [f"{c}={v}" for c, v in k[1:] if v != ""]) + f" ({len(tasks)} tasks)")
        ax.fill_between(taus, lo, hi, color=color, alpha=0.15, lw=0)
    ax.set(xlabel=xlabel, ylabel="fraction of runs with score > tau")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
