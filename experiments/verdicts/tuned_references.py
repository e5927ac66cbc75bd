"""The project's own tuned flat PPO as references: `.venv/bin/python experiments/verdicts/tuned_references.py`.

Reads the controller scores of experiments/tuning's tuned flat PPO (each task's chosen configuration trained on seeds
0-9 for 1M steps; controller_scores.csv from `gsa_jax.score experiments/tuning/results/<task>/flat_ppo/evaluation`)
and writes one 'deterministic' entry per task into gsa_jax/analysis/verdicts/ppo_references.csv (replacing an earlier one of
the same source): the mean and std (ddof 0) over seeds of the controller score, the score every verdict uses.
"""

import csv
import json
import os

import numpy as np

from gsa_jax import read_csv
from gsa_jax.analysis.verdicts import baseline

HERE = os.path.dirname(os.path.abspath(__file__))
TUNING = os.path.join(HERE, "..", "tuning", "results")
TASKS = {"halfcheetah_v5": "HalfCheetah-v5", "hopper_v5": "Hopper-v5", "walker2d_v5": "Walker2d-v5"}


def tuned_row(folder: str, task: str) -> dict:
    scores = os.path.join("experiments", "tuning", "results", folder, "flat_ppo", "evaluation", "controller_scores.csv")
    x = np.array([float(r["controller_score"]) for r in read_csv(os.path.join(HERE, "..", "..", scores))])
    chosen = next(r for r in read_csv(os.path.join(TUNING, folder, "tuning.csv")) if r["class"] == "flat_ppo")
    knobs = ", ".join(f"{k} {v}" for k, v in json.loads(chosen["chosen"]).items())
    return {"task": task, "published_task": task, "score": round(float(x.mean()), 2), "std": round(float(x.std()), 2),
            "seeds": len(x), "steps": 1_000_000, "metric": "deterministic",
            "algorithm": f"gsa_jax flat PPO tuned for this task (experiments/tuning, configuration {chosen['chosen_set']}: {knobs})",
            "source": scores, "note": "the verdicts' own controller score (10 episodes in MuJoCo C from seed 10,000); mean and "
            "std (ddof 0) over seeds 0-9; hyperparameters chosen on this task (2 tuning seeds, 300k steps)"}


def main():
    rows = [r for r in read_csv(baseline.REFERENCES) if not r["source"].startswith("experiments/tuning/")]
    rows += [tuned_row(folder, task) for folder, task in TASKS.items()]
    with open(baseline.REFERENCES, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(baseline.COLUMNS))
        w.writeheader()
        w.writerows(rows)
    baseline.load_references()  # still a valid table
    print(f"wrote {len(rows)} entries to {baseline.REFERENCES}")


if __name__ == "__main__":
    main()
