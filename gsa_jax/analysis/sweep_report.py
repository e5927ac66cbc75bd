"""A sweep's report: every figure and table of merged sweeps written to disk (`plot_sweep`, which
`gsa plot` runs): the statistics (sweeps/), the verdicts of the grid (verdicts/) and the figures. It sits
above analysis/'s folders, which import none of it."""

import os
from typing import Callable, Sequence

import numpy as np

from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import controller_scores, stats
from gsa_jax.analysis.sweeps.figures import plot_curves, plot_profiles, plot_return_vs_k
from gsa_jax.analysis.sweeps.results import (
    action_dims_of, drop_failed, load_failed, load_sweeps, random_returns_of, setting_columns, spec_multipliers, spec_steps,
    task_records, unscored_lines, write_csv,
)
from gsa_jax.analysis.sweeps.tables import aggregate_table, final_table, normalized_scores, run_table
from gsa_jax.analysis.verdicts.grid import write_verdicts


def random_policies_of(env_names: Sequence[str], random_returns: dict, out_dir: str, log: Callable = print) -> dict:
    """{env: random policy record}: measured in MuJoCo C (controller_scores.random_policy, kept in out_dir) where the
    task has a MuJoCo C version, else the sweeps' scalar return taken as exact (its uncertainty unknown)."""
    out = {}
    for env_name, task in task_records(env_names).items():
        if task.has_c:
            out[env_name] = controller_scores.random_policy(out_dir, task, log=log)
        elif env_name in random_returns:
            out[env_name] = {"returns": float(random_returns[env_name]), "episodes": 0, "start_seed": ""}
    return out


def plot_sweep(sweep_dirs: Sequence[str], out_dir: str | None = None, action_dims: dict | None = None,
               random_returns: dict | None = None, log: Callable = print, reps: int = stats.REPS,
               curve_reps: int = stats.CURVE_REPS) -> tuple:
    """Every figure and table of the merged sweeps into out_dir (default: the first directory); reps /
    curve_reps: bootstrap resamples of the tables' intervals / of each learning-curve point's band; random_returns:
    {env: return} taken as exact (default: the random policy measured over 128 episodes in MuJoCo C, kept in
    out_dir/random_policy.json, where the task has a MuJoCo C version).
    Returns (figure.png path, final_returns.csv path, final_returns rows)."""
    dirs = [sweep_dirs] if isinstance(sweep_dirs, str) else list(sweep_dirs)
    out_dir = out_dir or dirs[0]
    os.makedirs(out_dir, exist_ok=True)
    failed_runs = [f for d in dirs for f in load_failed(d)]
    data, failed = drop_failed(load_sweeps(dirs), failed_runs)
    controller_scores.attach(data, dirs)
    if action_dims is None:
        action_dims = action_dims_of(dirs, sorted({c.env for c in data}))
    evaluated = any(np.isfinite(s["eval_return"]).any() for seeds in data.values() for s in seeds.values())
    png = os.path.join(out_dir, "figure.png")
    plot_curves(data, action_dims, failed, "eval_return" if evaluated else "episode_return", png,
                "Flat PPO vs mixtures of K linear controllers: " + ("deterministic controllers" if evaluated else "training return")
                + "\n(IQM over seeds, 95% bootstrap band)", curve_reps)
    plot_curves(data, action_dims, failed, "episode_return", os.path.join(out_dir, "figure_training.png"),
                "Training return (stochastic policy)\n(IQM over seeds, 95% bootstrap band)", curve_reps)
    rows = final_table(data, action_dims, failed, reps)
    for line in unscored_lines(rows):
        log(line)
    table = os.path.join(out_dir, "final_returns.csv")
    write_csv(table, rows)
    write_csv(os.path.join(out_dir, "per_run_scores.csv"), run_table(data))
    env_names = sorted({c.env for c in data})
    given = random_returns is not None
    if not given:
        random_returns = random_returns_of(dirs, env_names, out_dir, log)
    policies = (random_policies_of(env_names, random_returns, out_dir, log) if not given else
                {e: {"returns": float(v), "episodes": 0, "start_seed": ""} for e, v in random_returns.items()})
    random_returns = {**random_returns, **{e: float(np.mean(p["returns"])) for e, p in policies.items()}}
    verdicts, sufficient = write_verdicts(data, policies, spec_steps(dirs), setting_columns(data), out_dir, log)
    scored = [r for r in rows if r[C.SEEDS]]
    plot_return_vs_k(scored, os.path.join(out_dir, "return_vs_k.png"), setting_columns(data), sufficient, verdicts)
    normalized = normalized_scores(data, action_dims, random_returns, spec_multipliers(dirs))
    if normalized:
        write_csv(os.path.join(out_dir, "aggregate.csv"), aggregate_table(normalized, reps))
        plot_profiles(normalized, os.path.join(out_dir, "performance_profile.png"), reps)
    return png, table, rows
