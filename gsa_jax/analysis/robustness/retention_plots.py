"""robustness.png: per task, the retained fraction (IQM, 95% CI) under each shift, flat PPO and each K."""

import numpy as np

from gsa_jax.algorithm.kinds import MLP
from gsa_jax.analysis.robustness.shift_rows import RETAINED_CI


def plot_robustness(agg: list, path: str) -> None:
    """Per task: retained fraction (IQM, 95% CI) under each shift, flat PPO and each K side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in agg))
    point, low, high = RETAINED_CI
    fig, axes = plt.subplots(len(env_names), 1, figsize=(11, 3.4 * len(env_names)), squeeze=False)
    for ax, env_name in zip(axes[:, 0], env_names):
        rows = [r for r in agg if r["env"] == env_name and r["shift"] != "nominal" and r[point] != ""]
        shifts = list(dict.fromkeys(r["shift"] for r in rows))
        configs = list(dict.fromkeys((r["policy"], r["K"]) for r in rows))
        width = 0.8 / max(1, len(configs))
        for j, (policy, k) in enumerate(configs):
            pts = {r["shift"]: r for r in rows if (r["policy"], r["K"]) == (policy, k)}
            x = np.array([i for i, sh in enumerate(shifts) if sh in pts]) + (j - (len(configs) - 1) / 2) * width
            y = np.array([pts[sh][point] for sh in shifts if sh in pts], float)
            err = np.array([[pts[sh][point] - pts[sh][low], pts[sh][high] - pts[sh][point]]
                            for sh in shifts if sh in pts], float).T
            ax.bar(x, y, width, yerr=err, capsize=2, color="k" if policy == MLP else None, alpha=0.8,
                   label="flat PPO (MLP 64x64)" if policy == MLP else f"K = {k}")
        ax.axhline(1.0, color="gray", lw=0.8, ls="--")
        ax.set_xticks(range(len(shifts)), shifts, fontsize=8)
        ax.set(title=env_name, ylabel="retained fraction (IQM)")
        ax.legend(fontsize=7, ncol=len(configs))
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Deterministic controllers under shifts: (score - random) / (nominal - random), 95% bootstrap CI", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
