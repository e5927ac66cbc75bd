"""Do the paired-push verdicts hold for another draw of push events? The robustness experiment's P(a mixture falls
less than flat PPO) resamples controllers under one fixed draw of push times and directions (draw 0). This re-runs
the paired pushes of one task x configuration against flat PPO under independent draws and writes each draw's
verdict:

    python experiments/push_draws/push_draws.py [--env Ant-v5] [--K 8] [--size 0.5] [--window 50] [--draws 0,1,2,3,4]

Controllers: the committed Figure-1 controllers of the task (experiments/fig1_v5/results/fig1_v5_<env>*/controllers),
the K given and flat PPO, 10 seeds each; start states as the robustness experiment's (seeds 10,000-10,019), 10 push
events per start, pushes of --size m/s, its windows (20, 50, 100 steps: the push times are drawn below the episode
length minus the longest), falls counted over --window steps (gsa_jax.deployment.pushes.evaluate_pushes with
draw=d; draw 0 is the robustness experiment's own). Per draw: the fall-probability IQM of both configurations
and P(the mixture falls less) with its 95% CI (gsa_jax.analysis.robustness.paired.aggregate_pushes). Writes draws.csv and
meta.json beside this file's results/ after every draw.
"""

import argparse
import glob
import json
import os
import subprocess

import numpy as np

from gsa_jax.analysis.robustness.paired import aggregate_pushes
from gsa_jax.analysis.robustness.retention_eval import START_SEED, load_controllers
from gsa_jax import write_csv
from gsa_jax.deployment.pushes import PER_EPISODE, WINDOWS, PushPlan, evaluate_pushes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STARTS = 20  # the robustness experiment's start states
COLUMNS = ("env", "K", "size", "window", "draw", "mixture_fall_iqm", "flat_fall_iqm", "p_falls_less_than_flat_ppo",
           "p_fall_ci_low", "p_fall_ci_high")


def controllers(env, k):
    """The committed controllers of `env`: flat PPO and K = k, [(path, meta, controller)]."""
    dirs = sorted(glob.glob(os.path.join(ROOT, "experiments", "fig1_v5", "results", f"fig1_v5_{env}*", "controllers")))
    return [c for c in load_controllers(dirs) if c[1]["policy"] == "mlp" or str(c[1]["K"]) == str(k)]


def verdict(ctrls, env, size, window, draw):
    """One draw's row: every controller's paired pushes under push-event draw `draw`, aggregated."""
    events = []
    for _, meta, ctrl in ctrls:
        plan = PushPlan((size,), WINDOWS, PER_EPISODE, draw=draw)  # every window: push times drawn below length - the longest
        rows, _ = evaluate_pushes(ctrl, env, np.arange(START_SEED, START_SEED + STARTS), plan)
        events += [{**meta, **r} for r in rows]
    agg = [r for r in aggregate_pushes(events, WINDOWS) if r["window"] == window]
    mix = next(r for r in agg if r["policy"] == "mixture")
    flat = next(r for r in agg if r["policy"] == "mlp")
    return {"env": env, "K": mix["K"], "size": size, "window": window, "draw": draw, "mixture_fall_iqm": mix["fall_iqm"],
            "flat_fall_iqm": flat["fall_iqm"], "p_falls_less_than_flat_ppo": mix["p_falls_less_than_flat_ppo"],
            "p_fall_ci_low": mix["p_fall_ci_low"], "p_fall_ci_high": mix["p_fall_ci_high"]}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="Ant-v5")
    p.add_argument("--K", type=int, default=8)
    p.add_argument("--size", type=float, default=0.5)
    p.add_argument("--window", type=int, default=50)
    p.add_argument("--draws", default="0,1,2,3,4")
    p.add_argument("--out", default=os.path.join(ROOT, "experiments", "push_draws", "results"))
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    ctrls = controllers(args.env, args.K)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    with open(os.path.join(args.out, "meta.json"), "w") as f:
        json.dump({"args": vars(args) | {"out": os.path.relpath(args.out, ROOT)}, "controllers": len(ctrls),
                   "start_seeds": [START_SEED, START_SEED + STARTS], "per_episode": PER_EPISODE, "git_commit": commit}, f,
                  indent=1)
    rows = []
    for draw in (int(d) for d in args.draws.split(",")):
        rows.append(verdict(ctrls, args.env, args.size, args.window, draw))
        print(rows[-1], flush=True)
        write_csv(os.path.join(args.out, "draws.csv"), rows, COLUMNS)


if __name__ == "__main__":
    main()
