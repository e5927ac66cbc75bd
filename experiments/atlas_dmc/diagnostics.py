"""How far each PPO update moves the policy, per task and class: `.venv/bin/python experiments/atlas_dmc/diagnostics.py`.

A mixture that scores low may be one whose updates run off-policy (clipped almost everywhere) or whose partition
collapses onto a few clusters, not one too small for the task. From every committed metrics-*.csv.gz of results/,
over the second half of training (iterations above half the last one, every run of a cell pooled), writes
results/update_diagnostics.csv: per task, policy and K the median approx_kl (PPO's k3 estimate of KL(old || new) per
update), the median clip fraction, the mean number of clusters the partition uses, and flat PPO's approx_kl beside
each row for scale.
"""

import glob
import os
import statistics

import numpy as np

from gsa_jax import load_sweep, write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
COLUMNS = ("iteration", "approx_kl", "clip_fraction", "clusters_used")


def read_cells(task_dir):
    """{(env, policy, K): {column: [values of the second half of training, every seed pooled]}} of one task
    (iteration: every row's; the metrics: the finite ones)."""
    data = load_sweep(task_dir, COLUMNS)
    last = max(int(np.max(run["iteration"])) for seeds in data.values() for run in seeds.values())
    cells = {}
    for (env, policy, k, *_), seeds in data.items():
        pooled = cells.setdefault((env, policy, k), {c: [] for c in COLUMNS})
        for run in seeds.values():
            late = run["iteration"] > last // 2
            pooled["iteration"] += list(run["iteration"][late])
            for c in COLUMNS[1:]:
                pooled[c] += [float(v) for v in run[c][late] if np.isfinite(v)]
    return cells


def median_of(values):
    """Median of a list ('' when empty)."""
    return f"{statistics.median(values):.4g}" if values else ""


def summarize(cells):
    """One output row per cell, flat PPO's approx_kl beside each."""
    flat_kl = {env: median_of(cols["approx_kl"]) for (env, policy, _), cols in cells.items() if policy == "mlp"}
    out = []
    for (env, policy, k), cols in sorted(cells.items()):
        used = cols["clusters_used"]
        out.append({"task": env, "policy": policy, "K": k if policy == "mixture" else "",
                    "approx_kl_median": median_of(cols["approx_kl"]),
                    "clip_fraction_median": median_of(cols["clip_fraction"]),
                    "clusters_used_mean": f"{statistics.fmean(used):.3g}" if used and policy == "mixture" else "",
                    "flat_ppo_approx_kl_median": flat_kl.get(env, ""), "rows": len(cols["iteration"])})
    return out


def main():
    table = []
    tables = glob.glob(os.path.join(RESULTS, "*", "*", "metrics-*.csv.gz"))
    for task_dir in sorted({os.path.dirname(os.path.dirname(p)) for p in tables}):
        table += summarize(read_cells(task_dir))
    write_csv(os.path.join(RESULTS, "update_diagnostics.csv"), table)
    print(f"wrote {os.path.join(RESULTS, 'update_diagnostics.csv')} ({len(table)} rows)")


if __name__ == "__main__":
    main()
