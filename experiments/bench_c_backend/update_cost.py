"""What the PPO update costs, and how close to the CPU's matrix-product rate it runs: ppo_update.sgd_update alone (10 epochs
x 32 minibatches of 64 on 2,048 samples per run) for R vmapped mixture runs with a task's shapes, one core, in one
process, variants alternating (machine drift hits each alike):

- `paper`: the update as the trainer runs it;
- `no_shuffle`: the minibatches in sample order (ppo_update.shuffle replaced by arange): what the shuffle costs;
- `plain_sgd`: a plain gradient step instead of global-norm clipping + Adam: what the optimizer costs;
the update's rate (XLA's FLOP count of the loss gradient over its time); then float32 matrix products alone at the update's shapes ([R, 64, 64] x [R, 64, 64], a tanh between products, as in the
update's hidden layers) and at a large shape (1024^3), for the rate this core reaches.

    taskset -c 0 .venv/bin/python experiments/bench_c_backend/update_cost.py --env ant [--runs 8] [--repeats 9] [--out F]

The ablations change the arithmetic (they are not training variants): they say where the time goes."""

import argparse
import contextlib
import json
import statistics
import time
from unittest import mock

import jax
import jax.numpy as jnp

import envs
from envs.physics import Physics
from gsa_jax.algorithm import ppo, ppo_update
from gsa_jax.algorithm.config import Config, for_task, make_hparams
from gsa_jax.algorithm.nn import init_mlp
from gsa_jax.algorithm.optim import init_adam
from gsa_jax import run_metadata


def update_inputs(p, hp, runs, key):
    """Params, Adam state and a batch of random samples with the task's shapes, for `runs` runs [runs, ...]."""
    obs_size, act_size, k_max, batch = p.obs_size, p.env.action_size, p.cfg.k_max, p.cfg.batch_size

    def one(k):
        k_pol, k_val, k_obs, k_act, k_c, k_lp, k_adv, k_t = jax.random.split(k, 8)
        params = {"policy": p.policy.init(k_pol, hp),
                  "value": init_mlp(k_val, (obs_size, *p.cfg.hidden, 1), out_scale=1.0)}
        samples = {"obs": jax.random.normal(k_obs, (batch, obs_size)),
                   "action": jax.random.normal(k_act, (batch, act_size)),
                   "cluster": jax.random.randint(k_c, (batch,), 0, k_max),
                   "logp": jax.random.normal(k_lp, (batch,)) - 10.0, "adv": jax.random.normal(k_adv, (batch,)),
                   "target": jax.random.normal(k_t, (batch,))}
        return params, init_adam(params), samples

    return jax.jit(jax.vmap(one))(jax.random.split(key, runs))


def sequential_order(key, n):
    return jnp.arange(n, dtype=jnp.int32)


def plain_sgd(params, grads, opt, lr):
    return jax.tree.map(lambda w, g: w - lr * g, params, grads), opt


def compile_update(p, hp, inputs, keys, variant):
    """sgd_update for every run (vmapped), compiled with the variant's parts in place -> compiled function."""
    sched = ppo.schedule(hp, jnp.zeros((), jnp.int32))
    fn = jax.jit(jax.vmap(lambda prm, opt, batch, k: ppo_update.sgd_update(p, prm, opt, batch, hp, sched, 3e-4, k)))
    patches = {"paper": {}, "no_shuffle": {"shuffle": sequential_order},
               "plain_sgd": {"adam_step": plain_sgd, "clip_by_global_norm": lambda g, m: (g, jnp.zeros(()))}}[variant]
    with mock.patch.multiple(ppo_update, **patches) if patches else contextlib.nullcontext():
        return fn.lower(*inputs, keys).compile()


def minibatch_flops(p, hp, inputs):
    """XLA's FLOP count (cost analysis) of one minibatch's loss gradient for every run: the products and the
    elementwise work of the gradient, not the optimizer."""
    sched = ppo.schedule(hp, jnp.zeros((), jnp.int32))
    params, _, samples = inputs
    mb = jax.tree.map(lambda x: x[:, :p.cfg.minibatch_size], samples)
    grad = jax.vmap(jax.grad(lambda prm, b: ppo_update.ppo_loss(p, prm, b, hp, sched)[0]))
    cost = jax.jit(grad).lower(params, mb).compile().cost_analysis()
    return float((cost[0] if isinstance(cost, list) else cost)["flops"])


def time_alternating(fns, args, repeats):
    """Median seconds of each fn(*args) over `repeats` rounds, the fns taking turns in each round."""
    times = {name: [] for name in fns}
    for name, f in fns.items():
        jax.block_until_ready(f(*args[name]))
    for _ in range(repeats):
        for name, f in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(f(*args[name]))
            times[name].append(time.perf_counter() - t)
    return {name: statistics.median(ts) for name, ts in times.items()}


def product_chain(b, n, steps):
    """steps products [b, n, n] x [b, n, n] with a tanh between them: (compiled fn, its arguments, its FLOPs)."""
    def run(x, w):
        return jax.lax.fori_loop(0, steps, lambda i, y: jnp.tanh(jnp.einsum("bmk,bkn->bmn", y, w)), x)

    x = jnp.full((b, n, n), 0.01)
    return jax.jit(run), (x, x), 2.0 * b * n * n * n * steps


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", default="ant")
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    task = envs.resolve(args.env)
    cfg = for_task(Config(env=args.env, k_max=6, physics=Physics(backend="c", threads=1)), task)
    p = ppo.make_parts(cfg, ppo.make_env(cfg, task), ppo.make_env(cfg, task, auto_reset=False))
    hp = make_hparams(K=6)
    inputs = update_inputs(p, hp, args.runs, jax.random.PRNGKey(0))
    keys = jax.random.split(jax.random.PRNGKey(1), args.runs)
    variants = ("paper", "no_shuffle", "plain_sgd")
    fns = {v: compile_update(p, hp, inputs, keys, v) for v in variants}
    chains = {"products_R_64": product_chain(args.runs, 64, 2000), "products_1_1024": product_chain(1, 1024, 2)}
    seconds = time_alternating({**fns, **{k: f for k, (f, _, _) in chains.items()}},
                               {**{v: (*inputs, keys) for v in variants}, **{k: a for k, (_, a, _) in chains.items()}},
                               args.repeats)
    env_steps = args.runs * cfg.batch_size
    update_flops = minibatch_flops(p, hp, inputs) * cfg.num_epochs * cfg.num_minibatches
    result = {"env": args.env, "runs": args.runs, "repeats": args.repeats, "obs_size": p.obs_size,
              "action_size": p.env.action_size, "k_max": cfg.k_max, "hidden": list(cfg.hidden),
              "num_epochs": cfg.num_epochs, "num_minibatches": cfg.num_minibatches, "batch_size": cfg.batch_size,
              "update_s": {v: seconds[v] for v in variants},
              "update_us_per_env_step": {v: 1e6 * seconds[v] / env_steps for v in variants},
              "share_of_update": {v: 1.0 - seconds[v] / seconds["paper"] for v in variants[1:]},
              "update_gflop_per_env_step": update_flops / env_steps / 1e9,
              "update_gflop_s": update_flops / seconds["paper"] / 1e9,
              "products_gflop_s": {k: flops / seconds[k] / 1e9 for k, (_, _, flops) in chains.items()},
              **run_metadata()}
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
