"""Do trained hopper controllers work outside MJX? Every seed of a sweep's hopper mixture cell:
extract the run, export its controller, and roll the deterministic controller out for N episodes in
MuJoCo C (plain `mujoco`, float64) and in MJX (float32, the training simulator), same MJCF.

    .venv/bin/python experiments/deploy_hopper/deploy_hopper.py runs/sweeps/fig1_idp_hopper --clusters 6 --episodes 20 \
        --out experiments/deploy_hopper/results
"""

import argparse
import csv
import json
import os
import sys

import numpy as np


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("sweep_dir")
    p.add_argument("--env", default="hopper")
    p.add_argument("--clusters", type=int, default=6)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/deploy_hopper/results")
    args = p.parse_args(argv)

    from gsa_jax.deployment.evaluation import load_controller, run_mjx, run_mujoco_c
    from gsa_jax import export_controller, run_metadata, select_run, sweep_runs

    os.makedirs(args.out, exist_ok=True)
    seeds = sorted({int(r["seed"]) for _, _, _, r in sweep_runs(args.sweep_dir) if r["env"] == args.env
                    and r["policy"] == "mixture" and int(r["K"]) == args.clusters})
    rows = []
    for seed in seeds:
        address = select_run(args.sweep_dir, args.env, "mixture", args.clusters, seed)
        ctrl = os.path.join(args.out, "runs", f"{args.env}-K{args.clusters}-s{seed}", "controller.npz")
        os.makedirs(os.path.dirname(ctrl), exist_ok=True)
        export_controller(address, ctrl)
        c = run_mujoco_c(*load_controller(ctrl), args.episodes)
        _, j = run_mjx(address, args.episodes)
        rows.append({"seed": seed, "mujoco_c_return": round(c["return_mean"], 1), "mujoco_c_ci95": round(c["return_ci95"], 1),
                     "mujoco_c_length": round(c["length_mean"], 1), "mjx_return": round(j["return_mean"], 1),
                     "mjx_ci95": round(j["return_ci95"], 1), "mjx_length": round(j["length_mean"], 1)})
        print(rows[-1], flush=True)
    with open(os.path.join(args.out, "deploy.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    c_all, j_all = np.array([r["mujoco_c_return"] for r in rows]), np.array([r["mjx_return"] for r in rows])
    summary = {"env": args.env, "K": args.clusters, "episodes_per_seed": args.episodes, "seeds": seeds,
               "mujoco_c_mean_over_seeds": float(c_all.mean()), "mjx_mean_over_seeds": float(j_all.mean()),
               "ratio_c_over_mjx": float(c_all.mean() / j_all.mean()), "sweep": os.path.abspath(args.sweep_dir),
               **run_metadata()}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("versions",)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
