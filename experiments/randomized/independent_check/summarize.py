"""summary.csv of results10.jsonl (evaluate.py's episode returns): per group of controllers, the mean and IQM over
controllers of each controller's mean return, and P(a randomized-trained K = 6 controller scores above a
randomized-trained flat PPO one) over all pairs (and the same for the nominal-trained)."""

import csv
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def group(path):
    return ("randomized" if "/randomized/" in path else "nominal") + ("_K6" if "mixture" in path else "_flat")


def iqm(x):
    x = np.sort(x)
    k = int(np.floor(0.25 * len(x)))
    return float(x[k:len(x) - k].mean())


def main():
    groups = {}
    with open(os.path.join(HERE, "results10.jsonl")) as f:
        for line in f:
            r = json.loads(line)
            groups.setdefault(group(r["path"]), []).append(float(np.mean(r["returns"])))
    rows = [{"group": g, "controllers": len(v), "mean": round(float(np.mean(v)), 1), "iqm": round(iqm(v), 1)}
            for g, v in sorted(groups.items())]
    for training in ("nominal", "randomized"):
        a, b = np.array(groups[f"{training}_K6"]), np.array(groups[f"{training}_flat"])
        p = float(np.mean(a[:, None] > b[None, :]) + 0.5 * np.mean(a[:, None] == b[None, :]))
        rows.append({"group": f"p_{training}_K6_above_flat", "controllers": len(a) + len(b), "mean": round(p, 3),
                     "iqm": ""})
    with open(os.path.join(HERE, "summary.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(open(os.path.join(HERE, "summary.csv")).read())


if __name__ == "__main__":
    main()
