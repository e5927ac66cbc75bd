"""The benchmark's worker processes, `python -m gsa_jax.benchmark.workers {sweep,raw} ...` (what
gsa_jax.benchmark.measure starts; not a command): compile, then time chunks together with the other workers and report
the medians as one JSON line."""

import argparse
import dataclasses
import json
import os
import resource
import statistics
import sys
import time

import jax

import envs
from envs.physics import C, Physics
from gsa_jax.benchmark.measure import RAW_UNROLL
from gsa_jax.errors import run_command
from gsa_jax.running import xla_cache
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.programs import GroupRuns, GroupShape, compile_group, pad_runs
from gsa_jax.running.spec import RUN_BATCH, single_group


def _beat(args, payload=None):
    """Heartbeat for the parent's hang detection (XLA:CPU has been seen to hang with no CPU use)."""
    write_atomic(os.path.join(args.barrier, f"beat-{args.worker_id}"), json.dumps(payload or {}))


def _wait_barrier(args):
    open(os.path.join(args.barrier, f"ready-{args.worker_id}"), "w").close()
    while len([n for n in os.listdir(args.barrier) if n.startswith("ready-")]) < args.num_workers:
        time.sleep(0.01)


def _time_chunks(args, fn, state, clock=None):
    """(wall seconds of args.repeats calls of fn, each call's change of clock()'s counts ({} without a clock))."""
    times, changes = [], []
    for _ in range(args.repeats):
        c0 = clock() if clock else {}
        t = time.perf_counter()
        state = fn(state)
        times.append(time.perf_counter() - t)
        c1 = clock() if clock else {}
        changes.append({k: c1[k] - c0[k] for k in c1})
        _beat(args, {"chunk_s": times[-1]})
    return times, changes


def _share(args):
    """The workers of one measurement share one compile (gsa_jax.running.xla_cache) unless --compile-each:
    enables the cache and returns compile_with's share, or None when each worker compiles alone."""
    if args.num_workers < 2 or args.compile_each:
        return None
    cache = os.path.join(args.barrier, "xla_cache")
    xla_cache.enable(cache)
    return cache, args.worker_id == 0


def worker(args: argparse.Namespace) -> None:
    """One process: compile the group program for args.runs runs, wait at the barrier, time chunks of
    one PPO iteration."""

    group, cfg = single_group(args.env, args.policy, args.clusters, list(range(args.seed0, args.seed0 + args.runs)),
                              args.physics)
    if args.epochs:
        cfg = dataclasses.replace(cfg, num_epochs=args.epochs)
    physics = dataclasses.replace(cfg.physics, solver_iterations=args.solver_iterations,
                                  ls_iterations=args.ls_iterations, backend=args.physics, threads=args.physics_threads)
    cfg = dataclasses.replace(cfg, physics=physics, value_target=args.value_target, randomize=args.randomize or "")
    devices = jax.local_devices()[:1]
    t0 = time.perf_counter()
    runs = pad_runs(group.runs, len(devices))
    shape = GroupShape(cfg, 1, tuple(devices), args.run_batch)
    states, run, hps, _, how = compile_group(shape, GroupRuns(runs, [], 1000), _share(args))
    compile_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    states, _ = run(states, hps)  # first execution (allocations, page faults) is not timed
    jax.block_until_ready(states)
    _beat(args, {"chunk_s": time.perf_counter() - t1})
    _wait_barrier(args)
    clock = None
    if args.physics == C:  # where the chunks' time goes: MuJoCo C, the rest of the host calls, the program
        from envs.c_hosts import host_seconds as clock
    times, host = _time_chunks(args, lambda st: jax.block_until_ready(run(st, hps)[0]), states, clock)
    steps = len(runs) * cfg.batch_size
    print(json.dumps({
        "compile_s": compile_s, "compile": how, "chunk_s": times, "env_steps_per_chunk": steps,
        **({"host_chunks": host} if clock else {}),
        "env_steps_per_s": steps / statistics.median(times),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }), flush=True)


def raw_worker(args: argparse.Namespace) -> None:
    """One process: the task alone (no policy, no learning) -- args.batch envs stepped by a vmapped
    env.step with uniform random actions, with the training loop's time limit and auto-reset,
    in scans of RAW_UNROLL steps."""
    env = envs.make(args.env, physics=Physics(args.solver_iterations, args.ls_iterations, backend=args.physics,
                                              threads=args.physics_threads))
    b = args.batch
    t0 = time.perf_counter()
    share = _share(args)

    def chunk(carry):
        state, key = carry
        key, k = jax.random.split(key)

        def body(st, kk):
            a = jax.random.uniform(kk, (b, env.action_size), minval=-1.0, maxval=1.0)
            st = jax.vmap(env.step)(st, a)
            return st, None

        state, _ = jax.lax.scan(body, state, jax.random.split(k, RAW_UNROLL))
        return state, key

    keys = jax.random.split(jax.random.PRNGKey(args.seed0), b)
    reset, _ = xla_cache.compile_with(jax.jit(jax.vmap(env.reset)).lower(keys), share)
    state = reset(keys)
    carry = (state, jax.random.PRNGKey(args.seed0 + 1))
    step, how = xla_cache.compile_with(jax.jit(chunk, donate_argnums=0).lower(carry), share)
    compile_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    carry = jax.block_until_ready(step(carry))
    _beat(args, {"chunk_s": time.perf_counter() - t1})
    _wait_barrier(args)
    holder = [carry]

    def timed(_):
        holder[0] = jax.block_until_ready(step(holder[0]))
        return None

    times, _ = _time_chunks(args, timed, None)
    print(json.dumps({"compile_s": compile_s, "compile": how, "chunk_s": times, "env_steps_per_chunk": b * RAW_UNROLL,
                      "env_steps_per_s": b * RAW_UNROLL / statistics.median(times),
                      "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}), flush=True)


def worker_parser() -> argparse.ArgumentParser:
    """The workers' command line: the kind (sweep: PPO iterations of a group program; raw: the task alone), the cell
    and the barrier measure.run_workers gives every worker."""
    p = argparse.ArgumentParser(prog="python -m gsa_jax.benchmark.workers", description=__doc__)
    p.add_argument("kind", choices=("sweep", "raw"))
    p.add_argument("--env", required=True)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--run-batch", type=int, default=RUN_BATCH)
    p.add_argument("--value-target", default="gae")
    p.add_argument("--physics", default="mjx")
    p.add_argument("--physics-threads", type=int, default=0)
    p.add_argument("--randomize", default="")
    p.add_argument("--compile-each", action="store_true")
    for a in ("--policy", "--barrier"):
        p.add_argument(a, default=None)
    for a in ("--clusters", "--runs", "--seed0", "--worker-id", "--num-workers", "--batch", "--epochs",
              "--solver-iterations", "--ls-iterations"):
        p.add_argument(a, type=int, default=None)
    return p


def main(argv: "list | None" = None) -> int:
    """One worker process: its measurement as one JSON line on stdout (exit status 0; a user error is one line and
    its status, as gsa bench's own)."""
    args = worker_parser().parse_args(argv)
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):  # a cache the user set: loaded from quietly, as the commands do
        xla_cache.quiet_cache_loads()
    return run_command("bench", lambda: (worker if args.kind == "sweep" else raw_worker)(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
