"""The field's reference tools on the same gymnasium ids, on this machine, for gsa_jax.bench --env <id>:
Stable-Baselines3 PPO (torch, CPU) trained to N env steps, and EnvPool's raw stepping.

    python experiments/bench_v5/baselines.py Hopper-v5 --sb3-steps 1000000 --out experiments/bench_v5/results/hopper_v5_baselines.json

Needs the optional packages (not the project's dependencies):
    pip install torch==2.13.0 stable-baselines3 envpool
A tool that does not install or import is skipped with the reason in the JSON.

SB3: PPO("MlpPolicy") with SB3's defaults (2,048 steps per update from 1 env, 10 epochs of minibatches
of 64, 64x64 tanh networks: the PPO paper's MuJoCo setting, as ours), on as many torch threads as cores;
machine-wide env-steps/s = steps / wall time. EnvPool: num_envs = batch = 256 on as many threads as
cores, uniform random actions, the median of 3 timed rounds of 200 steps after a warm-up.
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import time

import numpy as np


def sb3_ppo(env_id, steps, seed=0):
    try:
        import gymnasium as gym
        import stable_baselines3
        import torch
        from stable_baselines3 import PPO
    except ImportError as e:
        return {"skipped": f"stable-baselines3 / torch not importable: {e}"}
    torch.set_num_threads(os.cpu_count() or 1)
    model = PPO("MlpPolicy", gym.make(env_id), seed=seed, device="cpu", verbose=0)
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps)
    wall = time.perf_counter() - t0
    return {"steps": steps, "wall_s": round(wall, 1), "env_steps_per_s": round(steps / wall, 1),
            "torch_threads": torch.get_num_threads(),
            "versions": {"stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__}}


def envpool_raw(env_id, batch=256, steps=200, repeats=3):
    try:
        import envpool
    except ImportError as e:
        return {"skipped": f"envpool not importable: {e}"}
    threads = os.cpu_count() or 1
    env = envpool.make(env_id, env_type="gymnasium", num_envs=batch, batch_size=batch, num_threads=threads, seed=0)
    lo, hi = env.action_space.low, env.action_space.high
    rng = np.random.default_rng(0)
    acts = rng.uniform(lo, hi, size=(steps, batch) + lo.shape)
    env.reset()
    for a in acts:  # warm-up
        env.step(a)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for a in acts:
            env.step(a)
        times.append(time.perf_counter() - t0)
    return {"batch": batch, "threads": threads, "env_steps_per_s": round(batch * steps / statistics.median(times), 1),
            "times_s": times, "versions": {"envpool": envpool.__version__}}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("env_id")
    p.add_argument("--sb3-steps", type=int, default=1_000_000)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    res = {"env_id": args.env_id, "git_commit": commit, "started_at": time.strftime("%Y-%m-%dT%H:%M:%S"),
           "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "processor": platform.processor()}}
    res["envpool"] = envpool_raw(args.env_id)
    print("envpool:", res["envpool"], flush=True)
    res["sb3_ppo"] = sb3_ppo(args.env_id, args.sb3_steps)
    print("sb3 ppo:", res["sb3_ppo"], flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
