"""What one host call costs inside a compiled program: jax.pure_callback against envs.host_call, each
calling a function that does nothing and returns backend 'c''s SimState shapes for a batch of 256 envs,
64 calls per scan, one after the other in one process.

    .venv/bin/python experiments/bench_c_backend/host_call_overhead.py [--batch 256] [--repeats 7]

Prints microseconds per call (median of the repeats) for each, as JSON."""

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from envs.host_call import host_call

CALLS = 64


def program(call, batch):
    """A jitted scan of CALLS host calls on [batch, ...] arrays (rows uint32 [batch, 200], two float32
    [batch, 30], one float32 [batch, 3]: about the hand's SimState)."""
    outs = (np.zeros((batch, 200), np.uint32), np.zeros((batch, 30), np.float32), np.zeros((batch, 30), np.float32),
            np.zeros((batch, 3), np.float32))
    shapes = tuple(jax.ShapeDtypeStruct(o.shape[1:], o.dtype) for o in outs)

    def nothing(rows, action):
        return outs

    def chunk(rows, key):
        def body(r, k):
            a = jax.random.uniform(k, (batch, 16))
            return jax.vmap(lambda x, y: call(nothing, shapes, x, y))(r, a)[0] + 1, None

        return jax.lax.scan(body, rows, jax.random.split(key, CALLS))[0]

    return jax.jit(chunk)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    calls = {"pure_callback": lambda fn, shapes, *xs: jax.pure_callback(fn, shapes, *xs, vmap_method="broadcast_all"),
             "host_call": host_call}
    rows, key = jnp.zeros((args.batch, 200), jnp.uint32), jax.random.PRNGKey(0)
    fns = {name: program(call, args.batch) for name, call in calls.items()}
    times = {name: [] for name in fns}
    for name, f in fns.items():
        jax.block_until_ready(f(rows, key))
    for _ in range(args.repeats):
        for name, f in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(rows, key))
            times[name].append((time.perf_counter() - t0) / CALLS * 1e6)
    print(json.dumps({"batch": args.batch, "calls": CALLS, "us_per_call": {n: round(statistics.median(t), 1) for n, t in times.items()},
                      "jax": jax.__version__}))


if __name__ == "__main__":
    main()
