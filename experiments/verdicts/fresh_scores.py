"""The chosen controllers re-scored on starts they were not picked on: `.venv/bin/python experiments/verdicts/fresh_scores.py`.

An answer exports the chosen K's best seed, picked by its controller score (10 episodes from seed 10,000). That pick
carries a winner's curse: the same episodes choose it and score it. Here every task's chosen controller (the smallest
sufficient K at margin 0.1 in the regenerated tables, its best seed) and every committed answer's
controller/controller.npz is re-scored on 50 fresh start states from seed 20,000 (controller_scores.FRESH_*), as
gsa_jax.answer now does for its own. Writes results/fresh_scores.csv: selection score, fresh score and their difference.
"""

import glob
import os

from gsa_jax.analysis.sweeps import controller_scores as C
from gsa_jax import read_csv, write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
TABLES = [os.path.join(ROOT, "fig1_v5", "results", "merged")] + sorted(
    glob.glob(os.path.join(ROOT, "atlas_dmc", "results", "*", "")))


def chosen_controllers():
    """(source, env, K, seed, selection score, controller path) of every table's chosen controller."""
    for d in TABLES:
        for r in read_csv(os.path.join(d, "sufficient_k.csv")):
            if r["default_margin"] != "1" or r["smallest_sufficient_K"] == "":
                continue
            k = int(r["smallest_sufficient_K"])
            runs = [x for x in read_csv(os.path.join(d, "per_run_scores.csv"))
                    if x["env"] == r["env"] and x["policy"] == "mixture" and x["K"] == str(k)]
            best = max(runs, key=lambda x: float(x["controller_score"]))
            label = f"{r['env'].replace(':', '.')}-mixture-K{k}-s{best['seed']}.npz"
            hits = glob.glob(os.path.join(ROOT, "**", "controllers", label), recursive=True)
            yield "table", r["env"], k, int(best["seed"]), float(best["controller_score"]), hits[0]


def answer_controllers():
    paths = glob.glob(os.path.join(HERE, "answers", "*", "controller", "controller.npz"))
    paths += glob.glob(os.path.join(HERE, "longer_budget", "answer", "controller", "controller.npz"))
    for path in sorted(paths):
        row = C.score_controller(path)  # the selection score: the standard 10 starts
        yield "answer", row["env"], row["K"], row["seed"], float(row["controller_score"]), path


def main():
    rows = []
    for source, env, k, seed, selection, path in list(chosen_controllers()) + list(answer_controllers()):
        fresh = C.score_controller(path, C.FRESH_EPISODES, C.FRESH_START_SEED)
        rows.append({"source": source, "env": env, "K": k, "seed": seed, "selection_score": round(selection, 2),
                     "selection_episodes": C.EPISODES, "fresh_score": fresh["controller_score"],
                     "fresh_episode_std": fresh["episode_std"], "fresh_episodes": C.FRESH_EPISODES,
                     "fresh_start_seed": C.FRESH_START_SEED, "fresh_minus_selection": round(fresh["controller_score"] - selection, 2),
                     "controller": os.path.relpath(path, os.path.join(ROOT, ".."))})
        print(rows[-1], flush=True)
    write_csv(os.path.join(HERE, "results", "fresh_scores.csv"), rows)


if __name__ == "__main__":
    main()
