"""What the cheaper MJX solver costs: hopper controllers trained with the task's own solver
(`fig1_idp_hopper`, 4 Newton / 50 line-search iterations) and with 1 / 4 (`solver_hopper`), same seeds,
same 1M steps, each evaluated deterministically in both simulators, and the mixtures also in MuJoCo C
(the MJCF's own settings, float64), plus how far one env step and a rollout drift between the solvers.

    .venv/bin/python experiments/solver_hopper/solver_hopper.py runs/sweeps/fig1_idp_hopper runs/sweeps/solver_hopper \
        --out experiments/solver_hopper/results
"""

import argparse
import json
import os
import sys
import tempfile


def drift():
    """The task's own solver vs solver 1/4 (qpos_drift)."""
    import envs
    from envs.physics import Physics
    from rescoring import qpos_drift

    return qpos_drift(envs.make_base("hopper"), envs.make_base("hopper", Physics(1, 4)), hopper=True)


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("task_sweep", help="sweep trained with the task's own solver (fig1_idp_hopper)")
    p.add_argument("fast_sweep", help="sweep trained with solver 1/4 (solver_hopper)")
    p.add_argument("--clusters", type=int, default=6)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/solver_hopper/results")
    args = p.parse_args(argv)

    from envs.physics import Physics
    from gsa_jax import run_metadata
    from rescoring import mean_ci, score_sweep, write_rows

    os.makedirs(args.out, exist_ok=True)
    solvers = {"mjx_task_solver": Physics(), "mjx_fast_solver": Physics(1, 4)}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for trained, sweep in (("task", args.task_sweep), ("fast", args.fast_sweep)):
            rows += score_sweep(sweep, "hopper", args.clusters, args.episodes, solvers, tmp, trained_with=trained)
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
