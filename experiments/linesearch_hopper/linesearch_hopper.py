"""The exact line search (envs/linesearch.py) against MJX's iterative one, both against MuJoCo C:

1. one physics step from the same states (visited by MuJoCo C with random actions, hopper's own MJCF
   and solver, float64): |qvel after the step| of MJX with each line search minus MuJoCo C's, and the
   Newton iterations each needed;
2. trajectories: |qpos| between the two line searches after 1, 10, 100 env steps from the same starts
   under the same random actions (hopper, and allegro_cylinder, whose MJCF allows the exact search too);
3. returns: the hopper controllers of a sweep trained with MJX's iterative line search
   (`fig1_idp_hopper`, flat PPO and K=6, 8 seeds) run deterministically with each line search, and the
   mixtures also in MuJoCo C.

    .venv/bin/python experiments/linesearch_hopper/linesearch_hopper.py runs/sweeps/fig1_idp_hopper \
        --out experiments/linesearch_hopper/results
"""

import argparse
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "solver_hopper"))  # rescoring.py

def one_step(states=4096, seed=0):
    """MJX (each line search) vs MuJoCo C over one physics step from states MuJoCo C visits."""
    import jax
    import jax.numpy as jnp
    import mujoco
    from mujoco import mjx
    from mujoco.mjx._src import forward

    import envs
    from envs.physics import Physics, applied

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
        with applied(Physics(linesearch=mode), mj):
            qvel[mode] = np.asarray(jax.jit(jax.vmap(lambda d: forward.step(m, d).qvel))(batch), np.float64)
        err = np.abs(qvel[mode] - rows["qvel_c"]).max(1)
        out[f"mjx_{mode}_vs_c_max_abs_qvel_err"] = {"median": float(np.median(err)), "p99": float(np.quantile(err, 0.99)),
                                                   "max": float(err.max()), "mean": float(err.mean())}
    diff = np.abs(qvel["exact"] - qvel["iterative"]).max(1)
    out["exact_vs_iterative_max_abs_qvel_diff"] = {"median": float(np.median(diff)), "p99": float(np.quantile(diff, 0.99)),
                                                   "max": float(diff.max())}
    out["qvel_c_scale_median_max_abs"] = float(np.median(np.abs(rows["qvel_c"]).max(1)))
    return out


def drift(env_name="hopper"):
    """|qpos| between the two line searches (rescoring.qpos_drift; the task's own solver settings,
    given explicitly for the iterative one)."""
    import envs
    from envs.physics import Physics
    from rescoring import qpos_drift

    exact, iterative = envs.make_base(env_name), envs.make_base(env_name, Physics(linesearch="iterative"))
    assert [envs.solver_settings(e)["linesearch_in_force"] for e in (exact, iterative)] == ["exact", "iterative"]
    return qpos_drift(exact, iterative, hopper=env_name == "hopper")


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("sweep", help="sweep trained with MJX's iterative line search (fig1_idp_hopper)")
    p.add_argument("--clusters", type=int, default=6)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/linesearch_hopper/results")
    args = p.parse_args(argv)

    from envs.physics import Physics
    from gsa_jax import run_metadata
    from rescoring import mean_ci, score_sweep, write_rows

    os.makedirs(args.out, exist_ok=True)
    step = one_step()
    print(json.dumps(step, indent=1), flush=True)
    solvers = {"mjx_exact": Physics(), "mjx_iterative": Physics(linesearch="iterative")}
    with tempfile.TemporaryDirectory() as tmp:
        rows = score_sweep(args.sweep, "hopper", args.clusters, args.episodes, solvers, tmp)
    write_rows(os.path.join(args.out, "returns.csv"), rows)
    summary = {}
    for policy in ("mlp", "mixture"):
        sel = [r for r in rows if r["policy"] == policy]
        summary[policy] = mean_ci(sel, list(solvers) + (["mujoco_c"] if policy == "mixture" else []))
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
