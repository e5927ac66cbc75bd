"""Nominal against randomized training, read from two gsa_jax.robustness result folders of one task:

    .venv/bin/python experiments/randomized/compare.py NOMINAL_DIR RANDOMIZED_DIR --out DIR

Both folders hold robustness.csv (per controller and shift: the score over the same deterministic MuJoCo C
episodes from seeds 10,000 on, 20 by default: robustness.json says how many) and, where the task can fall,
paired_pushes.csv. Writes to DIR:
- by_training.csv: per configuration (flat PPO, each K) and shift, the IQM score of the nominal-trained and the
  randomized-trained controllers with 95% stratified-bootstrap intervals, and P(a randomized-trained run scores
  higher than a nominal-trained one) with its interval (rliable). The 'nominal' shift answers "does randomized
  training cost nominal score?".
- mixture_vs_flat.csv: per training, K and shift, P(a mixture run scores higher than a flat PPO run) with its
  interval: does randomized training change the mixtures' standing against flat PPO under each shift?
- paired_pushes.csv: the two trainings' paired-push rows side by side (fall probability per push where the same
  unpushed episode survives; P(a mixture falls less than flat PPO)).
- comparison.png: the IQM score per shift, nominal- against randomized-trained, one panel per configuration.
"""

import argparse
import csv
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))
from gsa_jax import improvement_probability, iqm_ci, write_csv  # noqa: E402

TRAININGS = ("nominal", "randomized")


def read_scores(folder):
    """{(policy, K, shift): {seed: score}} of a robustness.csv (K '' for flat PPO)."""
    out = {}
    with open(os.path.join(folder, "robustness.csv")) as f:
        for row in csv.DictReader(f):
            shift = row["shift"] if row["shift"] in ("nominal", "simulator") else f"{row['shift']} {float(row['level']):g}"
            key = (row["policy"], row["K"] if row["policy"] == "mixture" else "", shift)
            out.setdefault(key, {})[int(row["seed"])] = float(row["score"])
    return out


def column(scores, key):
    """[runs, 1] of a cell's scores in seed order."""
    return np.array([scores[key][s] for s in sorted(scores[key])])[:, None]


def by_training(nominal, randomized, reps):
    """Rows of by_training.csv for the cells both trainings have."""
    rows = []
    for key in sorted(set(nominal) & set(randomized), key=lambda k: (k[2], k[0] != "mlp", int(k[1] or 0))):
        a, b = column(nominal, key), column(randomized, key)
        iqm = iqm_ci({"nominal": a, "randomized": b}, reps=reps)
        p = improvement_probability({"p": (b, a)}, reps=reps)["p"]
        rows.append({"policy": key[0], "K": key[1], "shift": key[2], "runs_nominal": len(a), "runs_randomized": len(b),
                     **{f"{t}_iqm": round(iqm[t][0], 1) for t in TRAININGS},
                     **{f"{t}_ci_low": round(iqm[t][1], 1) for t in TRAININGS},
                     **{f"{t}_ci_high": round(iqm[t][2], 1) for t in TRAININGS},
                     "p_randomized_higher": round(p[0], 3), "p_ci_low": round(p[1], 3), "p_ci_high": round(p[2], 3),
                     "says": says(p, "randomized-trained higher", "nominal-trained higher")})
    return rows


def says(p, above, below):
    """The reading of a probability interval against 0.5."""
    return above if p[1] > 0.5 else below if p[2] < 0.5 else "no difference shown"


def mixture_vs_flat(trainings, reps):
    """Rows of mixture_vs_flat.csv: per training, K and shift, P(mixture run > flat PPO run)."""
    rows = []
    for name, scores in trainings.items():
        for key in sorted(k for k in scores if k[0] == "mixture"):
            flat = ("mlp", "", key[2])
            if flat not in scores:
                continue
            p = improvement_probability({"p": (column(scores, key), column(scores, flat))}, reps=reps)["p"]
            rows.append({"training": name, "K": key[1], "shift": key[2], "p_mixture_higher": round(p[0], 3),
                         "p_ci_low": round(p[1], 3), "p_ci_high": round(p[2], 3),
                         "says": says(p, "mixture higher", "flat PPO higher")})
    return rows


def paired_pushes(folders):
    """The two trainings' paired_pushes.csv rows, with a training column."""
    rows = []
    for name, folder in folders.items():
        path = os.path.join(folder, "paired_pushes.csv")
        if os.path.exists(path):
            with open(path) as f:
                rows += [{"training": name, **r} for r in csv.DictReader(f)]
    return rows


def write(path, rows):
    if not rows:
        return
    write_csv(path, rows)  # every row's columns: one training's file may have columns the other's lacks


def episodes(folders):
    """The episodes per controller and shift the robustness folders recorded (robustness.json), e.g. '20'."""
    import json

    found = set()
    for folder in folders:
        with open(os.path.join(folder, "robustness.json")) as f:
            found.add(json.load(f)["episodes"])
    return "/".join(str(e) for e in sorted(found))


def plot(rows, path, n_episodes="20"):
    """IQM score per shift, nominal- vs randomized-trained, one panel per configuration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = sorted({(r["policy"], r["K"]) for r in rows}, key=lambda c: (c[0] != "mlp", int(c[1] or 0)))
    shifts = sorted(dict.fromkeys(r["shift"] for r in rows), key=lambda s: (s != "nominal", s))
    fig, axes = plt.subplots(1, len(configs), figsize=(3.2 * len(configs), 4), sharey=True, squeeze=False)
    for ax, (policy, k) in zip(axes[0], configs):
        cell = {r["shift"]: r for r in rows if (r["policy"], r["K"]) == (policy, k)}
        y = np.arange(len(shifts))
        for dy, t, color in ((-0.18, "nominal", "tab:gray"), (0.18, "randomized", "tab:blue")):
            mid = np.array([cell[s][f"{t}_iqm"] if s in cell else np.nan for s in shifts])
            lo = np.array([cell[s][f"{t}_ci_low"] if s in cell else np.nan for s in shifts])
            hi = np.array([cell[s][f"{t}_ci_high"] if s in cell else np.nan for s in shifts])
            ax.errorbar(mid, y + dy, xerr=[mid - lo, hi - mid], fmt="o", color=color, ms=4, label=f"trained {t}")
        ax.set_title("flat PPO" if policy == "mlp" else f"K = {k}")
        ax.set_yticks(y, shifts)
        ax.invert_yaxis()  # nominal on top
        ax.set_xlabel(f"IQM score ({n_episodes} episodes)")
    axes[0][0].legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("nominal")
    p.add_argument("randomized")
    p.add_argument("--out", required=True)
    p.add_argument("--reps", type=int, default=2000, help="bootstrap resamples")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    scores = {"nominal": read_scores(args.nominal), "randomized": read_scores(args.randomized)}
    rows = by_training(scores["nominal"], scores["randomized"], args.reps)
    write(os.path.join(args.out, "by_training.csv"), rows)
    write(os.path.join(args.out, "mixture_vs_flat.csv"), mixture_vs_flat(scores, args.reps))
    pushes = paired_pushes({"nominal": args.nominal, "randomized": args.randomized})  # none where the task cannot fall
    write(os.path.join(args.out, "paired_pushes.csv"), pushes)
    plot(rows, os.path.join(args.out, "comparison.png"), episodes([args.nominal, args.randomized]))
    print(f"wrote {args.out}: by_training.csv, mixture_vs_flat.csv, {'paired_pushes.csv, ' if pushes else ''}comparison.png")


if __name__ == "__main__":
    main()
