"""Brax's own PPO trainer on Brax's MJX hopper, configured as gsa_jax's flat PPO (32 envs x 64 steps = 2,048
samples per update, 10 epochs of 32 minibatches, 64x64 networks (Brax's default swish; ours tanh), lr 3e-4, GAE 0.95,
clipping 0.2, observation normalization, gradient-norm clip 0.5): its training env-steps/s on this machine,
one run, compile excluded. Writes OUT/brax_ppo.json with versions and settings.

    .venv/bin/python experiments/bench_brax_ppo/brax_ppo.py --steps 300000 --out experiments/bench_brax_ppo/results
"""

import argparse
import functools
import json
import os
import time

import jax
from brax import envs
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo

from gsa_jax import run_metadata


def replicate(tree, devices):
    """What jax.device_put_replicated did (removed in jax 0.10; brax 0.14.2's PPO trainer still calls it): every
    leaf with a leading axis of len(devices) copies, for its pmap to split over the devices."""
    return jax.tree.map(lambda a: jax.numpy.broadcast_to(a, (len(devices),) + jax.numpy.shape(a)), tree)


SETTINGS = dict(num_envs=32, unroll_length=64, batch_size=1, num_minibatches=32, num_updates_per_batch=10,
                learning_rate=3e-4, entropy_cost=0.0, discounting=0.99, gae_lambda=0.95, clipping_epsilon=0.2,
                normalize_observations=True, reward_scaling=1.0, max_grad_norm=0.5, episode_length=1000,
                num_evals=3, num_eval_envs=16)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--env", default="hopper")
    p.add_argument("--steps", type=int, default=300_000)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    if not hasattr(jax, "device_put_replicated"):  # an attribute the trainer reads; no effect on our own code
        jax.device_put_replicated = replicate
    env = envs.get_environment(args.env, backend="mjx")
    factory = functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(64, 64),
                                value_hidden_layer_sizes=(64, 64))
    progress = []
    t0 = time.perf_counter()

    def on_progress(step, metrics):
        progress.append({"step": int(step), "wall_s": time.perf_counter() - t0,
                         **{k: float(v) for k, v in metrics.items() if k in ("training/sps", "training/walltime", "eval/episode_reward",
                                                                              "eval/walltime")}})
        print(progress[-1], flush=True)

    ppo.train(environment=env, num_timesteps=args.steps, network_factory=factory, progress_fn=on_progress, seed=0, **SETTINGS)
    # the last training epoch's rate: compiled before it started (Brax's training/sps of that epoch)
    result = {"env": args.env, "backend": "mjx", "steps": args.steps, "settings": SETTINGS, "progress": progress,
              "env_steps_per_s": progress[-1].get("training/sps"), "devices": [str(d) for d in jax.devices()],
              **run_metadata()}
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "brax_ppo.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(f"Brax PPO, {args.env} (MJX): {result['env_steps_per_s']:,.0f} env-steps/s in its last training epoch")


if __name__ == "__main__":
    main()
