"""What the cheaper MJX solver costs: hopper controllers trained with the task's own solver
(`fig1_idp_hopper`, 4 Newton / 50 line-search iterations) and with 1 / 4 (`solver_hopper`), same seeds,
same 1M steps, each evaluated deterministically in both simulators, and the mixtures also in MuJoCo C
(the MJCF's own settings, float64), plus how far one env step and a rollout drift between the solvers.

    .venv/bin/python experiments/solver_hopper.py runs/sweeps/fig1_idp_hopper runs/sweeps/solver_hopper \
        --out experiments/results/solver_hopper
"""

import argparse
import csv
import json
import os
import sys
import tempfile

import numpy as np


def load_cell(sweep_dir, policy, k, tmp):
    """Per seed (sorted): (trainer, params, obs_stats, hp, iteration, run_dir) of one sweep cell."""
    from gsa_jax.extract import extract, finished_runs, select
    from gsa_jax.inspect import last_iteration, load_run

    runs = finished_runs(sweep_dir)
    seeds = sorted({int(r["seed"]) for _, _, r in runs if r["env"] == "hopper" and r["policy"] == policy
                    and (policy == "mlp" or int(r["K"]) == k)})
    out = []
    for seed in seeds:
        run_dir = os.path.join(tmp, f"{os.path.basename(sweep_dir.rstrip('/'))}-{policy}-s{seed}")
        extract(sweep_dir, *select(runs, "hopper", policy, k if policy == "mixture" else 1, seed), run_dir)
        trainer, params, obs_stats, hp, meta = load_run(run_dir, require_mixture=False)
        out.append((seed, trainer, params, obs_stats, hp, last_iteration(meta), run_dir))
    return out


def make_eval(cfg, policy_obj, episodes, solver):
    """jit(vmap over runs) of the returns [runs, episodes] of deterministic episodes in hopper with
    `solver` (None or (it, ls)); params are arguments, so one compile serves a whole cell."""
    import jax
    import jax.numpy as jnp

    import envs
    from gsa_jax.normalize import normalize
    from gsa_jax.ppo import schedule

    env = envs.make("hopper", cfg.episode_length, auto_reset=False, solver_iterations=solver and solver[0],
                    ls_iterations=solver and solver[1])

    def one(params, obs_stats, hp, iteration, key):
        sched = schedule(hp, iteration)

        def step(carry, _):
            s, alive, ret = carry
            z = normalize(obs_stats, s.obs) if cfg.normalize_obs else s.obs
            a, _ = jax.vmap(policy_obj.mode, in_axes=(None, 0, None))(params["policy"], z, sched)
            nxt = jax.vmap(env.step)(s, jnp.clip(a, -1.0, 1.0))
            return (nxt, alive * (1.0 - nxt.done), ret + nxt.reward * alive), None

        s0 = jax.vmap(env.reset)(jax.random.split(key, episodes))
        (_, _, ret), _ = jax.lax.scan(step, (s0, jnp.ones((episodes,)), jnp.zeros((episodes,))), None,
                                      length=cfg.episode_length)
        return ret

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, None)))


def evaluate_cell(cell, episodes, solvers):
    import jax
    import jax.numpy as jnp

    stack = lambda xs: jax.tree.map(lambda *a: jnp.stack(a), *xs)
    params, obs_stats, hps = stack([c[2] for c in cell]), stack([c[3] for c in cell]), stack([c[4] for c in cell])
    its = jnp.asarray([c[5] for c in cell], jnp.int32)
    cfg, policy = cell[0][1].cfg, cell[0][1].policy
    return {name: np.asarray(make_eval(cfg, policy, episodes, solver)(params, obs_stats, hps, its, jax.random.PRNGKey(123)))
            for name, solver in solvers.items()}


def qpos_drift(env_a, env_b, episodes=64, steps=(1, 10, 100), hopper=False):
    """Max/mean |qpos difference| between two versions of one task from the same starts under the same
    random actions, after 1, 10, 100 env steps (no time limit, no reset); with hopper=True also of the torso
    height (qpos[1])."""
    import jax

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


def drift():
    """The task's own solver vs solver 1/4 (qpos_drift)."""
    import envs

    return qpos_drift(envs.make_base("hopper"), envs.make_base("hopper", 1, 4), hopper=True)


def score_sweep(sweep, clusters, episodes, solvers, tmp, **tags):
    """Rows (tags, policy, K, seed, one mean return per MJX solver in `solvers`, and mujoco_c for the
    exported mixtures) for the flat PPO and K=`clusters` hopper controllers of a sweep."""
    from gsa_jax.checkpoint import save_npz_atomic
    from gsa_jax.deploy import load_controller, run_mujoco_c
    from gsa_jax.export import controller_arrays

    rows = []
    for policy in ("mlp", "mixture"):
        cell = load_cell(sweep, policy, clusters, tmp)
        res = evaluate_cell(cell, episodes, solvers)
        for i, c in enumerate(cell):
            row = {**tags, "policy": policy, "K": clusters if policy == "mixture" else "", "seed": c[0]}
            for name in solvers:
                row[name] = round(float(res[name][i].mean()), 1)
            if policy == "mixture":
                ctrl = os.path.join(c[6], "controller.npz")
                save_npz_atomic(ctrl, **controller_arrays(c[6]))
                row["mujoco_c"] = round(run_mujoco_c(*load_controller(ctrl), episodes)["return_mean"], 1)
            else:
                row["mujoco_c"] = ""
            rows.append(row)
            print(row, flush=True)
    return rows


def write_rows(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def mean_ci(rows, cols):
    """{col: {mean, ci95}} over rows (seeds)."""
    return {col: {"mean": float(np.mean([r[col] for r in rows])),
                  "ci95": float(1.96 * np.std([r[col] for r in rows], ddof=1) / np.sqrt(len(rows)))} for col in cols}


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("task_sweep", help="sweep trained with the task's own solver (fig1_idp_hopper)")
    p.add_argument("fast_sweep", help="sweep trained with solver 1/4 (solver_hopper)")
    p.add_argument("--clusters", type=int, default=6)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/results/solver_hopper")
    args = p.parse_args(argv)

    from gsa_jax.runinfo import run_metadata

    os.makedirs(args.out, exist_ok=True)
    solvers = {"mjx_task_solver": None, "mjx_fast_solver": (1, 4)}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for trained, sweep in (("task", args.task_sweep), ("fast", args.fast_sweep)):
            rows += score_sweep(sweep, args.clusters, args.episodes, solvers, tmp, trained_with=trained)
    write_rows(os.path.join(args.out, "returns.csv"), rows)
    summary = {}
    for trained in ("task", "fast"):
        for policy in ("mlp", "mixture"):
            sel = [r for r in rows if r["trained_with"] == trained and r["policy"] == policy]
            summary[f"{policy}_trained_{trained}"] = mean_ci(sel, list(solvers) + (["mujoco_c"] if policy == "mixture" else []))
    result = {"summary": summary, "trajectory_drift": drift(), "episodes_per_seed": args.episodes,
              "sweeps": {"task": os.path.abspath(args.task_sweep), "fast": os.path.abspath(args.fast_sweep)},
              **run_metadata()}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("summary", "trajectory_drift")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
