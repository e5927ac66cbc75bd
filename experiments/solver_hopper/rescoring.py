"""Trained controllers re-scored outside training: a sweep's cells evaluated deterministically under chosen physics
options (MJX) and in MuJoCo C, and how far two physics variants of a task drift apart. Used by the experiments that
compare simulators: solver_hopper.py beside it, and experiments/linesearch_hopper/ (which puts this folder on its
path).
"""

import csv
import os
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.physics import Physics
from gsa_jax import export_controller
from gsa_jax.algorithm.episodes import step_episodes
from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.ppo import schedule
from gsa_jax.analysis.sweeps.extraction import select, sweep_runs
from gsa_jax.deployment.evaluation import load_controller, run_mujoco_c
from gsa_jax.deployment.inspection import last_iteration, load_run


def load_cell(sweep_dir: str, env_name: str, policy: str, k: int) -> list:
    """Per seed (sorted): (trainer, params, obs_stats, hp, iteration, address) of one sweep cell."""

    seeds = sorted({int(r["seed"]) for _, _, _, r in sweep_runs(sweep_dir) if r["env"] == env_name
                    and r["policy"] == policy and (policy == MLP or int(r["K"]) == k)})
    out = []
    for seed in seeds:
        address = select(sweep_dir, env_name, policy, k if policy == MIXTURE else 1, seed)
        trainer, params, obs_stats, hp, meta = load_run(address, require_mixture=False)
        out.append((seed, trainer, params, obs_stats, hp, last_iteration(meta), address))
    return out


def make_eval(cfg: Any, policy_obj: Any, episodes: int, physics: Physics | None) -> Callable:
    """jit(vmap over runs) of the returns [runs, episodes] of deterministic episodes in cfg's task with
    `physics` (envs.physics.Physics; None: the defaults); params are arguments, so one compile serves a
    whole cell."""
    env = envs.make(cfg.env, cfg.episode_length, auto_reset=False, physics=physics)

    def one(params, obs_stats, hp, iteration, key):
        sched = schedule(hp, iteration)

        def step(carry, _):
            s, alive, ret = carry
            z = normalize(obs_stats, s.obs) if cfg.normalize_obs else s.obs
            a, _ = jax.vmap(policy_obj.mode, in_axes=(None, 0, None))(params["policy"], z, sched)
            nxt, reward, alive, _ = step_episodes(env, s, jnp.clip(a, -1.0, 1.0), alive)
            return (nxt, alive, ret + reward), None

        s0 = jax.vmap(env.reset)(jax.random.split(key, episodes))
        (_, _, ret), _ = jax.lax.scan(step, (s0, jnp.ones((episodes,)), jnp.zeros((episodes,))), None,
                                      length=cfg.episode_length)
        return ret

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, None)))


def evaluate_cell(cell: list, episodes: int, variants: dict) -> dict:
    """{variant name: returns [seeds, episodes]} of a cell's deterministic controllers under each physics variant."""

    stack = lambda xs: jax.tree.map(lambda *a: jnp.stack(a), *xs)
    params, obs_stats, hps = stack([c[2] for c in cell]), stack([c[3] for c in cell]), stack([c[4] for c in cell])
    its = jnp.asarray([c[5] for c in cell], jnp.int32)
    cfg, policy = cell[0][1].cfg, cell[0][1].policy
    return {name: np.asarray(make_eval(cfg, policy, episodes, physics)(params, obs_stats, hps, its, jax.random.PRNGKey(123)))
            for name, physics in variants.items()}


def qpos_drift(env_a: Any, env_b: Any, episodes: int = 64, steps: tuple = (1, 10, 100), hopper: bool = False) -> dict:
    """Max/mean |qpos difference| between two versions of one task from the same starts under the same
    random actions, after 1, 10, 100 env steps (no time limit, no reset); with hopper=True also of the torso
    height (qpos[1])."""
    s0 = jax.vmap(env_a.reset)(jax.random.split(jax.random.PRNGKey(7), episodes))
    acts = jax.random.uniform(jax.random.PRNGKey(8), (max(steps), episodes, env_a.action_size), minval=-1, maxval=1)
    q = []
    for env in (env_a, env_b):
        roll = jax.jit(lambda s: jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a),) * 2, s, acts)[1].pipeline_state.qpos)
        q.append(np.asarray(roll(s0)))
    res = {}
    for n in steps:
        d = np.abs(q[0][n - 1] - q[1][n - 1])
        res[f"after_{n}_steps"] = {"max_abs_qpos_diff": float(d.max()), "mean_abs_qpos_diff": float(d.mean())}
        if hopper:
            res[f"after_{n}_steps"]["torso_height_mean_abs_diff_m"] = float(d[:, 1].mean())
    return res


def score_sweep(sweep: str, env_name: str, clusters: int, episodes: int, variants: dict, tmp: str, **tags: Any) -> list:
    """Rows (tags, policy, K, seed, one mean return per physics variant {name: Physics or None}, and
    mujoco_c for the exported mixtures) for the flat PPO and K=`clusters` controllers of a sweep's task.
    tmp: a directory for the exported controllers."""

    rows = []
    for policy in (MLP, MIXTURE):
        cell = load_cell(sweep, env_name, policy, clusters)
        res = evaluate_cell(cell, episodes, variants)
        for i, c in enumerate(cell):
            row = {**tags, "policy": policy, "K": clusters if policy == MIXTURE else "", "seed": c[0]}
            for name in variants:
                row[name] = round(float(res[name][i].mean()), 1)
            if policy == MIXTURE:
                ctrl = os.path.join(tmp, os.path.basename(c[6]) + ".npz")
                export_controller(c[6], ctrl)
                row["mujoco_c"] = round(run_mujoco_c(*load_controller(ctrl), episodes)["return_mean"], 1)
            else:
                row["mujoco_c"] = ""
            rows.append(row)
            print(row, flush=True)
    return rows


def write_rows(path: str, rows: list) -> None:
    """rows (dicts with the same keys) as a CSV file."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def mean_ci(rows: list, cols: Sequence[str]) -> dict:
    """{col: {mean, ci95}} over rows (seeds)."""
    return {col: {"mean": float(np.mean([r[col] for r in rows])),
                  "ci95": float(1.96 * np.std([r[col] for r in rows], ddof=1) / np.sqrt(len(rows)))} for col in cols}
