"""How far each PPO update moves the policy, per task and class: `.venv/bin/python experiments/atlas_dmc/diagnostics.py`.

A mixture that scores low may be one whose updates run off-policy (clipped almost everywhere) or whose partition
collapses onto a few clusters, not one too small for the task. From every committed metrics-*.csv.gz of results/,
over the second half of training (iterations above half the last one, every run of a cell pooled), writes
results/update_diagnostics.csv: per task, policy and K the median approx_kl (PPO's k3 estimate of KL(old || new) per
update), the median clip fraction, the mean number of clusters the partition uses, and flat PPO's approx_kl beside
each row for scale.
"""

import csv
import glob
import gzip
import os
import statistics

from gsa_jax.analysis.results import write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")


def read_cells(task_dir):
    """{(env, policy, K): [metric rows of the second half of training]} from one task's metrics files."""
    rows = []
    for path in sorted(glob.glob(os.path.join(task_dir, "*", "metrics-*.csv.gz"))):
        with gzip.open(path, "rt") as f:
            rows += list(csv.DictReader(f))
    last = max((int(r["iteration"]) for r in rows), default=0)
    cells = {}
    for r in rows:
        if int(r["iteration"]) > last // 2:
            cells.setdefault((r["env"], r["policy"], r["K"]), []).append(r)
    return cells


def median_of(rows, col):
    """Median of a column over rows where it is set ('' when never set)."""
    values = [float(r[col]) for r in rows if r.get(col, "") not in ("", "nan")]
    return f"{statistics.median(values):.4g}" if values else ""


def summarize(cells):
    """One output row per cell, flat PPO's approx_kl beside each."""
    flat_kl = {env: median_of(rows, "approx_kl") for (env, policy, _), rows in cells.items() if policy == "mlp"}
    out = []
    for (env, policy, k), rows in sorted(cells.items(), key=lambda c: (c[0][0], c[0][1], int(c[0][2] or 0))):
        used = [float(r["clusters_used"]) for r in rows if r.get("clusters_used", "") not in ("", "nan")]
        out.append({"task": env, "policy": policy, "K": k if policy == "mixture" else "", "approx_kl_median": median_of(rows, "approx_kl"),
                    "clip_fraction_median": median_of(rows, "clip_fraction"),
                    "clusters_used_mean": f"{statistics.fmean(used):.3g}" if used and policy == "mixture" else "",
                    "flat_ppo_approx_kl_median": flat_kl.get(env, ""), "rows": len(rows)})
    return out


def main():
    table = []
    for task_dir in sorted(glob.glob(os.path.join(RESULTS, "*", ""))):
        table += summarize(read_cells(task_dir))
    write_csv(os.path.join(RESULTS, "update_diagnostics.csv"), table)
    print(open(os.path.join(RESULTS, "update_diagnostics.csv")).read())


if __name__ == "__main__":
    main()
