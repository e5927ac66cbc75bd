"""Flat PPO against published PPO scores, computed the way the published table computes them
(`gsa published REFERENCE.csv PER_RUN.csv [PER_RUN.csv ...] --out OUT.csv`).

REFERENCE.csv: one published score per task (columns env, mean, std, source; e.g. CleanRL's PPO table,
whose entries are the mean ± std (ddof 0) over seeds of each run's mean return over its last 100 training
episodes: openrlbenchmark's rlops). PER_RUN.csv: gsa_jax.plot's per_run_scores.csv. Every flat PPO task
whose name matches a reference task up to its version and case (Hopper-v5, or Brax's hopper, and Hopper-v4)
gets one row: our mean ± std (ddof 0) over seeds of training_return_last_100_episodes and of the
deterministic final score, next to the published entry.
"""

import numpy as np

from gsa_jax.algorithm.kinds import MLP
from gsa_jax.analysis.sweeps import columns as C


def task_name(env: str) -> str:
    """A task's name without its version, lower case: Hopper-v5 -> hopper (and Brax's variant, hopper)."""
    return env.rsplit("-v", 1)[0].lower()


def spread(xs: np.ndarray) -> tuple:
    """(mean, std with ddof 0) of the finite values, rounded to 3 decimals."""
    xs = np.asarray([x for x in xs if np.isfinite(x)], float)
    return round(float(xs.mean()), 3), round(float(xs.std()), 3)


def compare(reference: list, runs: list) -> list:
    """Rows of the comparison: per reference task with flat PPO runs of the same name, ours and theirs."""
    out = []
    for ref in reference:
        for env in dict.fromkeys(r["env"] for r in runs if r["policy"] == MLP):
            if task_name(env) != task_name(ref["env"]):
                continue
            mine = [r for r in runs if r["env"] == env and r["policy"] == MLP]
            num = lambda r, c: float(r[c]) if r[c] != "" else np.nan  # noqa: E731
            last_mean, last_std = spread([num(r, C.LAST_EPISODES_RETURN) for r in mine])
            det_mean, det_std = spread([num(r, C.FINAL_SCORE) for r in mine])
            out.append({"env": env, "seeds": len(mine), "last_100_episodes_mean": last_mean,
                        "last_100_episodes_std": last_std, "deterministic_mean": det_mean, "deterministic_std": det_std,
                        "published_env": ref["env"], "published_mean": ref["mean"], "published_std": ref["std"],
                        "published_source": ref["source"]})
    return out
