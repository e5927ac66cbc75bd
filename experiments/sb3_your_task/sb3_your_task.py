"""Stable-Baselines3's PPO on a user's task through envs.as_gymnasium, against gsa_jax's flat PPO on the same task, at
equal env steps: training wall time and the deterministic policy's score, both scored by one evaluator.

    python experiments/sb3_your_task/sb3_your_task.py [--steps 100000] [--seeds 0,1,2] [--out experiments/sb3_your_task/results]

Per seed: gsa_jax (`python -m gsa_jax.train --policy mlp --physics c`, its defaults; timings from its config.json)
and SB3 (`PPO("MlpPolicy")` with SB3's defaults, on envs.as_gymnasium(TASK), torch on one thread), each trained to
--steps env steps (train_wall_s: the whole training, compile included; env_steps_per_s: after the compile;
train_cpu_s: the CPU seconds the training used, compile included, which a machine shared with other work changes
less than wall time). Both
final policies are then scored the same way: the deterministic action (gsa_jax: the exported
controller, numpy_policy; SB3: predict(deterministic=True)) over EPISODES episodes of envs.as_gymnasium(TASK) from the
start seeds EVAL_SEED.. (gsa_jax.deployment.gymnasium_rollout.run_episodes). Writes runs.csv (one row per tool and seed)
and meta.json (versions, commit, command) under --out, after every run.
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TASK = "examples.reacher:Reacher"
EPISODES, EVAL_SEED = 20, 10_000
COLUMNS = ("tool", "seed", "env_steps", "train_wall_s", "compile_s", "env_steps_per_s", "train_cpu_s", "score",
           "score_std")


def score(policy):
    """(mean, std) of the deterministic policy's returns over EPISODES episodes of envs.as_gymnasium(TASK)."""
    import envs
    from gsa_jax.deployment.gymnasium_rollout import run_episodes

    returns, _ = run_episodes(envs.as_gymnasium(TASK), policy, EPISODES, seed=EVAL_SEED)
    return float(np.mean(returns)), float(np.std(returns))


def gsa_jax_run(steps, seed, workdir):
    """One gsa_jax flat PPO run in a new process: its row."""
    from gsa_jax.deployment import numpy_policy
    from gsa_jax.deployment.exporting import controller_arrays

    out = os.path.join(workdir, f"gsa_jax-s{seed}")
    cpu0 = children_cpu_s()
    subprocess.run([sys.executable, "-m", "gsa_jax.train", "--env", TASK, "--physics", "c", "--policy", "mlp",
                    "--steps", str(steps), "--seed", str(seed), "--out", out, "--quiet", "--no-tensorboard"],
                   check=True, cwd=ROOT)
    cpu = children_cpu_s() - cpu0
    with open(os.path.join(out, "config.json")) as f:
        config = json.load(f)
    timing = config["timing"]
    mean, std = score(numpy_policy.Controller(controller_arrays(out)))
    return {"tool": "gsa_jax", "seed": seed, "env_steps": config["env_steps"], "train_wall_s": timing["wall_s"],
            "compile_s": timing["compile_s"],
            "env_steps_per_s": round(config["env_steps"] / (timing["wall_s"] - timing["compile_s"]), 1),
            "train_cpu_s": round(cpu, 1), "score": round(mean, 3), "score_std": round(std, 3)}


def children_cpu_s():
    """CPU seconds (user + system) of this process's finished child processes."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


class Deterministic:
    """An SB3 model's deterministic action as act(obs) (what gymnasium_rollout.run_episodes calls)."""

    def __init__(self, model):
        self.model = model

    def act(self, obs):
        return self.model.predict(obs, deterministic=True)[0]


def sb3_run(steps, seed):
    """One SB3 PPO run in this process: its row."""
    import torch
    from stable_baselines3 import PPO

    import envs

    torch.set_num_threads(1)
    model = PPO("MlpPolicy", envs.as_gymnasium(TASK), seed=seed, device="cpu", verbose=0)
    t0, cpu0 = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=steps)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    mean, std = score(Deterministic(model))
    return {"tool": "sb3", "seed": seed, "env_steps": int(model.num_timesteps), "train_wall_s": round(wall, 1),
            "compile_s": 0.0, "env_steps_per_s": round(model.num_timesteps / wall, 1), "train_cpu_s": round(cpu, 1),
            "score": round(mean, 3),
            "score_std": round(std, 3)}


def versions():
    import gymnasium
    import jax
    import mujoco
    import stable_baselines3
    import torch

    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    return {"jax": jax.__version__, "mujoco": mujoco.__version__, "gymnasium": gymnasium.__version__,
            "stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__, "git_commit": commit,
            "cpu_count": os.cpu_count()}


def write(out, rows, meta):
    with open(os.path.join(out, "runs.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    with open(os.path.join(out, "meta.json"), "w") as f:
        json.dump(meta, f, indent=1)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--out", default=os.path.join(ROOT, "experiments", "sb3_your_task", "results"))
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    meta = {"task": TASK, "steps": args.steps, "episodes": EPISODES, "eval_seed": EVAL_SEED,
            "command": " ".join(["python", "experiments/sb3_your_task/sb3_your_task.py"] + (argv or sys.argv[1:])),
            "versions": versions()}
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for seed in (int(s) for s in args.seeds.split(",")):
            for run in (lambda: gsa_jax_run(args.steps, seed, workdir), lambda: sb3_run(args.steps, seed)):
                rows.append(run())
                print(rows[-1], flush=True)
                write(args.out, rows, meta)


if __name__ == "__main__":
    main()
