"""The linear partition judged against the MLP partition at equal K and step size with the project's verdict
(gsa_jax.analysis.verdicts.verdict.judge: IQM gap on the scale of the reference's gain over the random policy, Yuen's
trimmed-mean test, margin 0.1), from a task's committed results (gsa plot's per_run_scores.csv: every run's
controller score in MuJoCo C, and random_policy.json); beside it, each partition's verdict against flat PPO as gsa
plot gave it (its verdicts.csv: the project's answer, flat PPO's adequacy included).

The MLP partition is a reference only where it learned the task by the project's rule for flat PPO
(baseline.learned: its IQM not shown below a tenth of the way from the random policy's return to the task's
maximum), else 'no answer'; 'sufficient' also needs the linear partition's failing seeds shown no more frequent than
the MLP partition's (verdict.judge's failure-share condition against seeds). One error rate for the linear-vs-MLP rows: every such row of every task is one test of the family, at the
one-sided level ALPHA / (rows of the family) (Bonferroni), so the chance of any wrong 'sufficient' or 'insufficient'
among them is at most ALPHA.

    .venv/bin/python experiments/partition/compare.py experiments/partition/results/<task> [...]
writes experiments/partition/results/verdicts.csv and verdicts.md over the tasks given.
"""

import csv
import json
import os
import sys
from collections import defaultdict

import envs
from gsa_jax.analysis.verdicts import trimmed
from gsa_jax.analysis.verdicts.baseline import learned
from gsa_jax.analysis.verdicts.verdict import ALPHA, DEFAULT_MARGIN, NO_SCALE, judge, summarize_random

COLUMNS = ("env", "K", "lr_scale_partition", "linear_iqm", "mlp_iqm", "random_mean", "gap", "gap_low", "gap_high",
           "p_failure_share", "level", "linear_vs_mlp", "linear_vs_flat_ppo", "mlp_vs_flat_ppo", "seeds")


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


def flat_verdicts(task_dir: str) -> dict:
    """{(K, partition, lr_scale_partition): verdict against flat PPO at margin 0.1} from gsa plot's verdicts.csv."""
    with open(os.path.join(task_dir, "verdicts.csv")) as f:
        return {(r["K"], r["partition"], r["lr_scale_partition"]): r["verdict"] for r in csv.DictReader(f)
                if r["role"] == "answer" and float(r["margin"]) == DEFAULT_MARGIN}


def pairs(cells: dict) -> list:
    """[(K, lr_scale_partition)] where both partitions have a cell, in K then step-size order."""
    found = {(k[1], k[3]) for k in cells if k[0] == "mixture" and k[2] == "linear"}
    return sorted((p for p in found if ("mixture", p[0], "mlp", p[1]) in cells), key=lambda p: (int(p[0]), p[1]))


def judge_pair(linear: list, mlp: list, random_returns: list, max_return: "float | None", level: float) -> tuple:
    """(Gap or None, verdict) of the linear partition's scores against the MLP partition's."""
    ok, why = learned(mlp, summarize_random(random_returns), max_return)
    if not ok:
        return None, "no answer: " + why.replace("flat PPO", "the MLP partition")
    gap = judge(linear, mlp, random_returns, DEFAULT_MARGIN, level)
    if gap.verdict == NO_SCALE:
        return None, "no answer: the MLP partition's gain over the random policy is not shown (its seeds spread)"
    return gap, gap.verdict


def judge_rows(task_dirs: list) -> list:
    """Every (task, K, step size): linear vs MLP partition at the family's Bonferroni level, beside gsa plot's
    verdicts of both against flat PPO."""
    tasks = [(d, *read_scores(d)) for d in task_dirs]
    level = ALPHA / sum(len(pairs(cells)) for _, cells, _, _ in tasks)
    rows = []
    for d, cells, random_returns, env in tasks:
        flat, top = flat_verdicts(d), envs.resolve(env).max_return()
        for k, lr in pairs(cells):
            lin, mlp = cells[("mixture", k, "linear", lr)], cells[("mixture", k, "mlp", lr)]
            gap, verdict = judge_pair(lin, mlp, random_returns, top, level)
            rows.append({"env": env, "K": k, "lr_scale_partition": lr, "linear_iqm": round(trimmed.trimmed(lin).mean, 1),
                         "mlp_iqm": round(trimmed.trimmed(mlp).mean, 1),
                         "random_mean": round(sum(random_returns) / len(random_returns), 2),
                         **{c: "" if gap is None else round(getattr(gap, a), 3)
                            for c, a in (("gap", "point"), ("gap_low", "low"), ("gap_high", "high"))},
                         "p_failure_share": "" if gap is None else f"{gap.p_share:.3g}",
                         "level": f"{level:.5f}", "linear_vs_mlp": verdict,
                         "linear_vs_flat_ppo": flat.get((k, "linear", lr), ""),
                         "mlp_vs_flat_ppo": flat.get((k, "mlp", lr), ""), "seeds": f"{len(lin)} / {len(mlp)}"})
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
        print(f"{r['env']} K={r['K']} lr_scale_partition={r['lr_scale_partition']}: linear partition "
              f"{r['linear_iqm']} vs MLP partition {r['mlp_iqm']}: gap {r['gap']} [{r['gap_low']}, {r['gap_high']}] "
              f"-> {r['linear_vs_mlp']} (vs flat PPO: linear {r['linear_vs_flat_ppo']}, MLP {r['mlp_vs_flat_ppo']})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
