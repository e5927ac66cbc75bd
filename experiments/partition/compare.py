"""The linear partition judged against the MLP partition at equal K and step size, and each against flat PPO, with the
project's verdict (gsa_jax.analysis.verdicts.verdict.judge: IQM gap on the scale of the reference's gain over the
random policy, Yuen's trimmed-mean test, margin 0.1), from a task's committed results (gsa plot's per_run_scores.csv:
every run's controller score in MuJoCo C, and random_policy.json).

One error rate for the whole table: every row of every task is one test of the family, at the one-sided level
ALPHA / (rows of the family) (Bonferroni), so the chance of any wrong 'sufficient' or 'insufficient' in the table is
at most ALPHA.

    .venv/bin/python experiments/partition/compare.py experiments/partition/results/<task> [...]
writes experiments/partition/results/verdicts.csv and verdicts.md over the tasks given.
"""

import csv
import json
import os
import sys
from collections import defaultdict

from gsa_jax.analysis.verdicts import trimmed
from gsa_jax.analysis.verdicts.verdict import ALPHA, DEFAULT_MARGIN, judge

COLUMNS = ("env", "K", "lr_scale_partition", "cell", "versus", "seeds", "cell_iqm", "reference_iqm", "random_mean",
           "gap", "gap_low", "gap_high", "level", "verdict")


def read_scores(task_dir: str) -> tuple:
    """({(policy, K, partition, lr_scale_partition): [controller scores in seed order]}, random returns, env)."""
    cells = defaultdict(list)
    with open(os.path.join(task_dir, "per_run_scores.csv")) as f:
        rows = sorted(csv.DictReader(f), key=lambda r: int(r["seed"]))
    if any(r["controller_score"] == "" for r in rows):
        raise SystemExit(f"{task_dir}: runs without a controller score: run gsa score {task_dir} and gsa plot first")
    for r in rows:
        key = (r["policy"], r["K"], r.get("partition", ""), r.get("lr_scale_partition", ""))
        cells[key].append(float(r["controller_score"]))
    env = rows[0]["env"]
    with open(os.path.join(task_dir, "random_policy.json")) as f:
        random_returns = json.load(f)[env]["returns"]
    return cells, random_returns, env


def comparisons(cells: dict) -> list:
    """[(K, lr, cell key, reference key, what the reference is)]: linear vs MLP partition at equal K and step size,
    and every mixture cell vs flat PPO."""
    flat = next(k for k in cells if k[0] == "mlp")
    mixtures = sorted((k for k in cells if k[0] == "mixture"), key=lambda k: (int(k[1]), k[3], k[2]))
    out = []
    for k in mixtures:
        if k[2] == "linear" and ("mixture", k[1], "mlp", k[3]) in cells:
            out.append((k, ("mixture", k[1], "mlp", k[3]), "MLP partition"))
    out += [(k, flat, "flat PPO") for k in mixtures]
    return out


def judge_rows(task_dirs: list) -> list:
    """Every comparison of every task, judged at the family's Bonferroni level."""
    planned = []
    for d in task_dirs:
        cells, random_returns, env = read_scores(d)
        planned += [(env, cells, random_returns, c) for c in comparisons(cells)]
    level = ALPHA / len(planned)
    rows = []
    for env, cells, random_returns, (key, ref, versus) in planned:
        gap = judge(cells[key], cells[ref], random_returns, DEFAULT_MARGIN, level)
        rows.append({"env": env, "K": key[1], "lr_scale_partition": key[3], "cell": f"{key[2]} partition",
                     "versus": versus, "seeds": f"{len(cells[key])} / {len(cells[ref])}",
                     "cell_iqm": round(trimmed.trimmed(cells[key]).mean, 1),
                     "reference_iqm": round(trimmed.trimmed(cells[ref]).mean, 1),
                     "random_mean": round(sum(random_returns) / len(random_returns), 2),
                     "gap": round(gap.point, 3), "gap_low": round(gap.low, 3), "gap_high": round(gap.high, 3),
                     "level": f"{level:.5f}", "verdict": gap.verdict})
    return rows


def write_tables(rows: list, out: str) -> None:
    """verdicts.csv and verdicts.md in out."""
    with open(os.path.join(out, "verdicts.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(str(r[c]) for c in COLUMNS) + " |" for r in rows]
    with open(os.path.join(out, "verdicts.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main(argv: list) -> int:
    if not argv:
        print(__doc__)
        return 2
    rows = judge_rows(argv)
    out = os.path.dirname(os.path.normpath(argv[0]))
    write_tables(rows, out)
    for r in rows:
        print(f"{r['env']} K={r['K']} lr_scale_partition={r['lr_scale_partition']}: {r['cell']} "
              f"{r['cell_iqm']} vs {r['versus']} {r['reference_iqm']}: gap {r['gap']} "
              f"[{r['gap_low']}, {r['gap_high']}] -> {r['verdict']}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
