"""One configuration per policy class for every task: each class's 24 configurations (the same draws on every task)
ranked by their mean rank over the tuned tasks' selections (results/<task>/<class>/selection.csv).

    .venv/bin/python experiments/tuning/cross_task.py      # writes experiments/tuning/results/cross_task.csv

Columns: class, hparam_set, the rank on each task, mean_rank, best (1 for the class's best mean rank), and the
configuration's knobs.
"""

import glob
import os

from gsa_jax import read_csv, write_csv

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def cross_task_rows(root=HERE):
    """Rows of cross_task.csv from every results/<task>/<class>/selection.csv under root."""
    tasks = sorted(os.path.basename(os.path.dirname(p)) for p in glob.glob(os.path.join(root, "*", "tuning.csv")))
    classes = sorted({os.path.basename(os.path.dirname(p)) for p in glob.glob(os.path.join(root, "*", "*", "selection.csv"))})
    rows = []
    for cls in classes:
        table = {}
        for task in tasks:
            for r in read_csv(os.path.join(root, task, cls, "selection.csv")):
                entry = table.setdefault(int(r["hparam_set"]), {"knobs": r, "ranks": {}})
                entry["ranks"][task] = int(r["rank"])
        scored = sorted(table.items(), key=lambda kv: (sum(kv[1]["ranks"].values()), kv[0]))
        for i, (index, e) in enumerate(scored):
            knobs = {k: v for k, v in e["knobs"].items() if k not in ("hparam_set", "tuning_runs", "tuning_iqm",
                                                                      "tuning_scores", "rank")}
            rows.append({"class": cls, "hparam_set": index, **{f"rank_{t}": e["ranks"].get(t, "") for t in tasks},
                         "mean_rank": round(sum(e["ranks"].values()) / len(e["ranks"]), 2), "best": int(i == 0),
                         "knobs": " ".join(f"{k}={v}" for k, v in knobs.items())})
    return rows


if __name__ == "__main__":
    path = os.path.join(HERE, "cross_task.csv")
    write_csv(path, cross_task_rows())
    print(f"wrote {path}")
