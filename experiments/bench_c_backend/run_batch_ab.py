"""Runs per sub-batch with backend 'c', compared in one process: the group program of R mixture runs compiled
once per sub-batch size, then one PPO iteration of each in turn, --repeats rounds (alternating, so machine
drift hits every size alike). Start two at once to measure them as a 2-core sweep's two workers run. One MuJoCo C thread, as in each worker of a 2-core sweep; run it with
XLA_FLAGS=--xla_cpu_multi_thread_eigen=false as the sweep's workers run.

    XLA_FLAGS=--xla_cpu_multi_thread_eigen=false .venv/bin/python experiments/bench_c_backend/run_batch_ab.py \\
        --env ant --runs 128 --sizes 8,128 [--repeats 4] [--out results/x.json]

Prints one JSON line per size (median env-steps/s, its ratio to the first size, every timing)."""

import argparse
import dataclasses
import json
import statistics
import time

import jax
import jax.numpy as jnp

from envs.physics import Physics
from gsa_jax.running.programs import make_group_program, stack_hparams
from gsa_jax import run_metadata
from gsa_jax.running.spec import build_grid, check_spec, group_config


def compile_size(cfg, runs, size):
    """(compiled run, states after one untimed iteration, hps, compile seconds) for sub-batches of `size` runs."""
    _, init, run, place = make_group_program(cfg, 1, jax.local_devices()[:1], size)
    hps = place(stack_hparams(runs, [], 1000))
    keys = place(jnp.stack([jax.random.PRNGKey(r["seed"]) for r in runs]))
    t = time.perf_counter()
    states = init(keys, hps)
    compiled = run.lower(states, hps).compile()
    compile_s = time.perf_counter() - t
    states, _ = compiled(states, hps)
    return compiled, jax.block_until_ready(states), hps, compile_s


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--env", default="ant")
    p.add_argument("--runs", type=int, default=128)
    p.add_argument("--sizes", default="8,128")
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--out", default=None)
    args = p.parse_args()
    spec = check_spec({"envs": [args.env], "policies": ["mixture"], "clusters": [6], "seeds": list(range(args.runs)),
                       "steps": 10**9})
    group = build_grid(spec)[0]
    runs = group.runs
    cfg = dataclasses.replace(group_config(spec, group), physics=Physics(backend="c", threads=1))
    sizes = [int(s) for s in args.sizes.split(",")]
    progs = {s: list(compile_size(cfg, runs, s)) + [[]] for s in sizes}
    for _ in range(args.repeats):
        for s in sizes:
            compiled, states, hps, _, times = progs[s]
            t = time.perf_counter()
            progs[s][1] = jax.block_until_ready(compiled(states, hps)[0])
            times.append(time.perf_counter() - t)
    steps = args.runs * cfg.batch_size
    first = statistics.median(progs[sizes[0]][4])
    rows = [{"env": args.env, "runs": args.runs, "run_batch": s, "compile_s": progs[s][3],
             "env_steps_per_s": steps / statistics.median(progs[s][4]),
             "speedup_vs_first": first / statistics.median(progs[s][4]), "iteration_s": progs[s][4]} for s in sizes]
    for r in rows:
        print(json.dumps(r), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"results": rows, "repeats": args.repeats, **run_metadata()}, f, indent=1)


if __name__ == "__main__":
    main()
