"""The exact line search (envs/linesearch.py) against MJX's iterative one, both against MuJoCo C:

1. one physics step from the same states (visited by MuJoCo C with random actions, hopper's own MJCF
   and solver, float64): |qvel after the step| of MJX with each line search minus MuJoCo C's, and the
   Newton iterations each needed;
2. trajectories: |qpos| between the two line searches after 1, 10, 100 env steps from the same starts
   under the same random actions (hopper, and allegro_cylinder, whose MJCF allows the exact search too);
3. returns: the hopper controllers of a sweep trained with MJX's iterative line search
   (`fig1_idp_hopper`, flat PPO and K=6, 8 seeds) run deterministically with each line search, and the
   mixtures also in MuJoCo C.

    .venv/bin/python experiments/linesearch_hopper.py runs/sweeps/fig1_idp_hopper \
        --out experiments/results/linesearch_hopper
"""

import argparse
import csv
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

ITERATIVE = (4, 50)  # hopper's MJCF settings, given explicitly: envs.make_base then uses MJX's search


def one_step(states=4096, seed=0):
    """MJX (each line search) vs MuJoCo C over one physics step from states MuJoCo C visits."""
    import jax
    import jax.numpy as jnp
    import mujoco
    from mujoco import mjx
    from mujoco.mjx._src import forward

    import envs
    from envs import linesearch

    env = envs.make_base("hopper")
    mj = envs.mj_model(env)
    data = mujoco.MjData(mj)
    rng = np.random.default_rng(seed)
    rows = {k: [] for k in ("qpos", "qvel", "ctrl", "warm", "qvel_c", "ncon")}
    while len(rows["qpos"]) < states:  # episodes of 250 physics steps from hopper's reset noise
        mujoco.mj_resetData(mj, data)
        data.qpos[:] = mj.qpos0 + rng.uniform(-5e-3, 5e-3, mj.nq)
        data.qvel[:] = rng.uniform(-5e-3, 5e-3, mj.nv)
        for _ in range(250):
            data.ctrl[:] = rng.uniform(-1, 1, mj.nu)
            for k, v in (("qpos", data.qpos), ("qvel", data.qvel), ("ctrl", data.ctrl), ("warm", data.qacc_warmstart)):
                rows[k].append(v.copy())
            mujoco.mj_step(mj, data)
            rows["qvel_c"].append(data.qvel.copy())
            rows["ncon"].append(data.ncon)
    rows = {k: np.asarray(v[:states]) for k, v in rows.items()}
    m = env.sys
    d0 = mjx.put_data(mj, mujoco.MjData(mj))
    batch = jax.vmap(lambda q, v, u, w: d0.replace(qpos=q, qvel=v, ctrl=u, qacc_warmstart=w))(
        *(jnp.asarray(rows[k], jnp.float32) for k in ("qpos", "qvel", "ctrl", "warm")))
    out = {"states": states, "states_with_contact": int((rows["ncon"] > 0).sum())}
    qvel = {}
    for mode in ("exact", "iterative"):
        with linesearch.using(mode):
            qvel[mode] = np.asarray(jax.jit(jax.vmap(lambda d: forward.step(m, d).qvel))(batch), np.float64)
        err = np.abs(qvel[mode] - rows["qvel_c"]).max(1)
        out[f"mjx_{mode}_vs_c_max_abs_qvel_err"] = {"median": float(np.median(err)), "p99": float(np.quantile(err, 0.99)),
                                                   "max": float(err.max()), "mean": float(err.mean())}
    diff = np.abs(qvel["exact"] - qvel["iterative"]).max(1)
    out["exact_vs_iterative_max_abs_qvel_diff"] = {"median": float(np.median(diff)), "p99": float(np.quantile(diff, 0.99)),
                                                   "max": float(diff.max())}
    out["qvel_c_scale_median_max_abs"] = float(np.median(np.abs(rows["qvel_c"]).max(1)))
    return out


def drift(env_name="hopper", episodes=64, steps=(1, 10, 100)):
    """|qpos| between the two line searches from the same starts under the same random actions (the
    task's own solver settings, given explicitly for the iterative one)."""
    import jax

    import envs

    own = envs.mj_model(envs.make_base(env_name)).opt
    envs_by = {"exact": envs.make_base(env_name),
               "iterative": envs.make_base(env_name, int(own.iterations), int(own.ls_iterations))}
    assert envs.solver_settings(envs_by["exact"])["linesearch"] == "exact"
    assert envs.solver_settings(envs_by["iterative"])["linesearch"] == "iterative"
    s0 = jax.vmap(envs_by["exact"].reset)(jax.random.split(jax.random.PRNGKey(7), episodes))
    acts = jax.random.uniform(jax.random.PRNGKey(8), (max(steps), episodes, envs_by["exact"].action_size),
                              minval=-1, maxval=1)
    q = {}
    for name, env in envs_by.items():
        roll = jax.jit(lambda s: jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a),) * 2, s, acts)[1].pipeline_state.qpos)
        q[name] = np.asarray(roll(s0))
    res = {}
    for n in steps:
        d = np.abs(q["exact"][n - 1] - q["iterative"][n - 1])
        res[f"after_{n}_steps"] = {"max_abs_qpos_diff": float(d.max()), "mean_abs_qpos_diff": float(d.mean())}
        if env_name == "hopper":
            res[f"after_{n}_steps"]["torso_height_mean_abs_diff_m"] = float(d[:, 1].mean())
    return res


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("sweep", help="sweep trained with MJX's iterative line search (fig1_idp_hopper)")
    p.add_argument("--clusters", type=int, default=6)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/results/linesearch_hopper")
    args = p.parse_args(argv)

    from solver_hopper import evaluate_cell, load_cell

    from gsa_jax.checkpoint import save_npz_atomic
    from gsa_jax.deploy import run_mujoco_c
    from gsa_jax.export import controller_arrays
    from gsa_jax.runinfo import run_metadata

    os.makedirs(args.out, exist_ok=True)
    step = one_step()
    print(json.dumps(step, indent=1), flush=True)
    solvers = {"mjx_exact": None, "mjx_iterative": ITERATIVE}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for policy in ("mlp", "mixture"):
            cell = load_cell(args.sweep, policy, args.clusters, tmp)
            res = evaluate_cell(cell, args.episodes, solvers)
            for i, c in enumerate(cell):
                row = {"policy": policy, "K": args.clusters if policy == "mixture" else "", "seed": c[0]}
                for name in solvers:
                    row[name] = round(float(res[name][i].mean()), 1)
                if policy == "mixture":
                    ctrl = os.path.join(c[6], "controller.npz")
                    save_npz_atomic(ctrl, **controller_arrays(c[6]))
                    row["mujoco_c"] = round(run_mujoco_c(ctrl, args.episodes)[1]["return_mean"], 1)
                else:
                    row["mujoco_c"] = ""
                rows.append(row)
                print(row, flush=True)
    with open(os.path.join(args.out, "returns.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    summary = {}
    for policy in ("mlp", "mixture"):
        sel = [r for r in rows if r["policy"] == policy]
        cols = list(solvers) + (["mujoco_c"] if policy == "mixture" else [])
        summary[policy] = {col: {"mean": float(np.mean([r[col] for r in sel])),
                                 "ci95": float(1.96 * np.std([r[col] for r in sel], ddof=1) / np.sqrt(len(sel)))}
                           for col in cols}
        summary[policy]["mean_abs_seed_diff_exact_vs_iterative"] = float(
            np.mean([abs(r["mjx_exact"] - r["mjx_iterative"]) for r in sel]))
    result = {"one_step": step, "returns": summary, "trajectory_drift": drift(),
              "trajectory_drift_allegro_cylinder": drift("allegro_cylinder"), "episodes_per_seed": args.episodes,
              "sweep": os.path.abspath(args.sweep), **run_metadata()}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("returns", "trajectory_drift", "trajectory_drift_allegro_cylinder")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
