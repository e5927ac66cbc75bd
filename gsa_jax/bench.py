"""The vmapped seed benchmark: `python -m gsa_jax.bench [--quick] [--out DIR]` (make bench).

For a task (`--env`, default hopper; also allegro_cylinder) it measures, in one invocation:
- the raw step rate of MuJoCo C on the same MJCF (`mujoco.rollout`, one thread per core, batch 256,
  the task's substeps per env step) -- the physical reference;
- raw MJX stepping (vmapped env.step, random actions, auto-reset) at batch 256 and 4096, with 1 and
  with all-core worker processes;
- end-to-end training throughput (env steps per second, PPO updates included, compile excluded and
  reported separately) of sweeps of 1, 16, 64 and 256 runs of the mixture (K=6) with 1 and with
  <cores> worker processes, and of the flat mlp at 256 runs on all cores (`--policies mixture,mlp`
  for mlp at every size and process count); worker processes (each one XLA CPU device, as `gsa_jax.sweep` runs them,
  in its sub-batches of --run-batch runs), with compile time and peak resident memory;
- with --profile-runs N, a time profile of one PPO iteration (physics / rest of the rollout / update) on
  --profile-processes workers (default 1; <cores> measures the update as the sweep's workers run it), and
  the ceiling it puts on ours / MuJoCo C (ratio_ceiling);
- with --physics mjx,c, the raw stepping, sweeps and profile for each physics backend (envs/physics.py;
  'c': MuJoCo C stepped from inside the compiled program), in the same invocation; every 'c' sweep also
  splits its own timed chunks (MuJoCo C / the rest of the host calls / the rest of the program, from
  envs.c_backend.host_seconds) and puts its ceiling on them (in_run_ceiling): no separate profile;
- the same largest raw batch and largest mixture sweep on all cores again with a cheaper MJX solver
  (`--solver-variant ITER,LS`, default 1,4: 1 Newton iteration, 4 line-search iterations), and MuJoCo C
  with those settings too -- a changed simulator, offered as the explicit `--solver-iterations` /
  `--ls-iterations` option of training and sweeps (experiments/solver_hopper/).
The default run takes ~20 min on 2 cores (the estimate is printed first), --quick ~3 min.
Every figure is the median of repeated timed chunks; workers of a multi-process measurement start
their timed chunks together. A worker that hangs (no heartbeat) is killed and the measurement retried
once, then recorded as an error. Writes bench.json (`ratio_vs_mujoco_c` for each measurement) and
bench.png.
"""

import argparse
import copy
import dataclasses
import itertools
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import NamedTuple

import jax
import mujoco
import numpy as np
from mujoco import rollout

import envs
from envs.physics import Physics
from gsa_jax import xla_cache
from gsa_jax.checkpoint import write_atomic
from gsa_jax.ppo import Config
from gsa_jax.programs import RUN_BATCH, GroupRuns, GroupShape, compile_group, pad_runs
from gsa_jax.runinfo import run_metadata
from gsa_jax.spec import build_grid, check_spec, group_config
from gsa_jax.supervise import worker_env

SIZES = (1, 16, 64, 256)
QUICK_SIZES = (1, 16)
RAW_BATCHES = (256, 4096)
RAW_UNROLL = 20  # env steps per timed raw-stepping chunk
SOLVER_VARIANT = (1, 4)  # (solver iterations, line-search iterations) of the extra "cheaper solver" lines


# ----------------------------------------------------------------------------------------------- workers
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
    """The workers of one measurement share one compile (gsa_jax.xla_cache) unless --compile-each:
    enables the cache and returns compile_with's share, or None when each worker compiles alone."""
    if args.num_workers < 2 or args.compile_each:
        return None
    cache = os.path.join(args.barrier, "xla_cache")
    xla_cache.enable(cache)
    return cache, args.worker_id == 0


def worker(args):
    """One process: compile the group program for args.runs runs, wait at the barrier, time chunks of
    one PPO iteration."""

    spec = check_spec({"envs": [args.env], "policies": [args.policy], "clusters": [args.clusters],
                       "seeds": list(range(args.seed0, args.seed0 + args.runs)), "steps": 10**9,
                       "config": {"backend": args.physics}})
    group = build_grid(spec)[0]
    cfg = group_config(spec, group)
    if args.epochs:
        cfg = dataclasses.replace(cfg, num_epochs=args.epochs)
    cfg = dataclasses.replace(cfg, solver_iterations=args.solver_iterations, ls_iterations=args.ls_iterations,
                              value_target=args.value_target, backend=args.physics, physics_threads=args.physics_threads)
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
    if args.physics == "c":  # where the chunks' time goes: MuJoCo C, the rest of the host calls, the program
        from envs.c_backend import host_seconds as clock
    times, host = _time_chunks(args, lambda st: jax.block_until_ready(run(st, hps)[0]), states, clock)
    steps = len(runs) * cfg.batch_size
    print(json.dumps({
        "compile_s": compile_s, "compile": how, "chunk_s": times, "env_steps_per_chunk": steps,
        **({"host_chunks": host} if clock else {}),
        "env_steps_per_s": steps / statistics.median(times),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }), flush=True)


def raw_worker(args):
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


class BenchError(Exception):
    pass


def run_workers(cmds, compile_limit_s=900, retries=1, log=print, compile_each=False):
    """Start one worker per command (they meet at a barrier), collect their JSON lines (compile_each: every
    worker compiles its program itself instead of loading worker 0's). A worker that
    fails, or stops beating (no heartbeat for compile_limit_s before its first chunk, or 60 s + 10x its
    first chunk after it) gets the whole measurement killed and retried, at most `retries` times."""
    for attempt in range(retries + 1):
        barrier = tempfile.mkdtemp(prefix="gsa_bench_")
        full = [c + ["--barrier", barrier, "--worker-id", str(i), "--num-workers", str(len(cmds))]
                + (["--compile-each"] if compile_each else []) for i, c in enumerate(cmds)]
        env = worker_env(len(cmds))  # as the sweep's workers
        procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for c in full]
        start, problem = time.time(), None
        while any(p.poll() is None for p in procs):
            time.sleep(0.5)
            for i, p in enumerate(procs):
                if p.poll() is not None:
                    if p.returncode != 0:
                        problem = f"worker {i} exited with {p.returncode}: {p.stderr.read()[-2000:]}"
                    continue
                beat = os.path.join(barrier, f"beat-{i}")
                if os.path.exists(beat):
                    with open(beat) as f:
                        first = json.load(f).get("chunk_s", 60.0)
                    limit, since = 60 + 10 * first, os.path.getmtime(beat)
                else:
                    limit, since = compile_limit_s, start
                if time.time() - since > limit:
                    problem = f"worker {i} made no progress for {limit:.0f} s (hung)"
            if problem:
                break
        if problem is None:
            outs = [p.communicate()[0] for p in procs]
            shutil.rmtree(barrier, ignore_errors=True)  # with the workers' compilation cache
            return [dict(json.loads(o.strip().splitlines()[-1]), xla_flags=env.get("XLA_FLAGS", "")) for o in outs]
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        shutil.rmtree(barrier, ignore_errors=True)
        log(f"  ! {problem}; " + ("retrying" if attempt < retries else "giving up"))
    raise BenchError(problem)


def _split(n, processes):
    return [n // processes + (1 if i < n % processes else 0) for i in range(processes)]


def _solver_args(solver):
    return ["--solver-iterations", str(solver[0]), "--ls-iterations", str(solver[1])] if solver else []


def _solver_field(solver):
    return {"solver": {"iterations": solver[0], "ls_iterations": solver[1]}} if solver else {}


def _compile_fields(results):
    """Per-process compile times, how each process got its program (compiled / loaded from worker 0),
    and the workers' XLA_FLAGS."""
    return {"compile_s_per_process": [r["compile_s"] for r in results], "compile_per_process": [r["compile"] for r in results],
            "xla_flags": results[0]["xla_flags"]}


class SweepCell(NamedTuple):
    """One measured sweep configuration: `runs` runs of (env, policy) split over `processes` workers.
    clusters: K of a mixture; epochs: PPO epochs (None: Config's); solver: None (the task's own) or
    (iterations, ls_iterations); run_batch: see programs.make_group_program; value_target: the critic;
    backend, physics_threads: the physics backend and its threads per process."""

    env: str
    policy: str
    runs: int
    processes: int
    clusters: int = 6
    epochs: int | None = None
    solver: tuple | None = None
    run_batch: int = RUN_BATCH
    value_target: str = "gae"
    backend: str = "mjx"
    physics_threads: int = 0


def worker_command(cell, runs, seed0, repeats):
    """The command line of one bench worker training `runs` runs of the cell from seed seed0."""
    return ([sys.executable, "-m", "gsa_jax.bench", "--worker", "--env", cell.env, "--policy", cell.policy,
             "--clusters", str(cell.clusters), "--runs", str(runs), "--seed0", str(seed0), "--repeats", str(repeats)]
            + (["--epochs", str(cell.epochs)] if cell.epochs else []) + _solver_args(cell.solver)
            + ["--run-batch", str(cell.run_batch)]
            + ["--value-target", cell.value_target, "--physics", cell.backend, "--physics-threads", str(cell.physics_threads)])


def measure_sweep(cell, repeats, log=print, compile_each=False):
    """Throughput of a SweepCell, its workers measured together; compile_each: see run_workers."""
    cmds, seed0 = [], 0
    for n in _split(cell.runs, cell.processes):
        cmds.append(worker_command(cell, n, seed0, repeats))
        seed0 += n
    results = run_workers(cmds, log=log, compile_each=compile_each)
    return {
        "env": cell.env, "policy": cell.policy, "runs": cell.runs, "processes": cell.processes,
        **({"num_epochs": cell.epochs} if cell.epochs else {}), **_solver_field(cell.solver), "value_target": cell.value_target,
        "backend": cell.backend, "physics_threads": cell.physics_threads,
        "env_steps_per_s": sum(r["env_steps_per_s"] for r in results),
        "compile_s": max(r["compile_s"] for r in results), **_compile_fields(results),
        "peak_rss_mib": sum(r["peak_rss_mib"] for r in results),
        "peak_rss_mib_per_process": max(r["peak_rss_mib"] for r in results),
        "chunk_s": [r["chunk_s"] for r in results],
        "env_steps_per_iteration": sum(r["env_steps_per_chunk"] for r in results),
        **({"in_run": split} if (split := in_run_split(results)) else {}),
    }


def in_run_split(results):
    """Where the time of a backend-'c' sweep's chunks went, from its workers' host_chunks: per worker the
    medians over its chunks of the seconds inside MuJoCo C, in the rest of the host calls (state copies, the
    task's derived values) and in the rest of the program (policy, GAE, PPO update, the host calls'
    hand-over). -> {"per_process": [...], "fractions": {...}}, or None when a worker has no host_chunks (MJX)."""
    if not all("host_chunks" in r for r in results):
        return None
    per_process = []
    for r in results:
        parts = [(h["mujoco_c_s"], h["host_s"] - h["mujoco_c_s"], t - h["host_s"]) for t, h in zip(r["chunk_s"], r["host_chunks"])]
        m, h, p = (statistics.median(x) for x in zip(*parts))
        per_process.append({"mujoco_c_s": m, "host_other_s": h, "program_s": p, "env_steps": r["env_steps_per_chunk"],
                            "host_calls": statistics.median(c["calls"] for c in r["host_chunks"])})
    total = sum(w["mujoco_c_s"] + w["host_other_s"] + w["program_s"] for w in per_process)
    fractions = {k: sum(w[f"{k}_s"] for w in per_process) / total for k in ("mujoco_c", "host_other", "program")}
    return {"per_process": per_process, "fractions": fractions}


def in_run_ceiling(split, mujoco_c):
    """The ceiling of a sweep from its own split: each worker's chunk with its host calls (MuJoCo C and the
    copies around it) costing what MuJoCo C's rollout costs per env step on one thread (c = its env-steps/s /
    threads) and the rest of the program as it ran: sum_i steps_i / (steps_i / c + program_i), over MuJoCo
    C's env-steps/s. Measured in the same chunks as the sweep, unlike ratio_ceiling's separate profile; the
    rollout's rate is a separate measurement on other states (it moves by up to +-25% between invocations
    here), so the same ceiling with MuJoCo C's own seconds in the run is given too."""
    c = mujoco_c["env_steps_per_s"] / mujoco_c["threads"]
    ws = split["per_process"]
    rate = sum(w["env_steps"] / (w["env_steps"] / c + w["program_s"]) for w in ws)
    steps = sum(w["env_steps"] for w in ws)
    at_own = sum(w["env_steps"] / (w["mujoco_c_s"] + w["host_other_s"] + w["program_s"]) for w in ws) / sum(
        w["env_steps"] / (w["mujoco_c_s"] + w["program_s"]) for w in ws)
    return {"ratio_ceiling_in_run": rate / mujoco_c["env_steps_per_s"],
            # the same ceiling with MuJoCo C at its own seconds in this run (the sweep's states, the same moment):
            # what the host calls' copies cost the sweep
            "sweep_of_ceiling_at_own_mujoco_c": at_own,
            "mujoco_c_us_per_env_step": 1e6 * sum(w["mujoco_c_s"] for w in ws) / steps,
            "rollout_us_per_env_step": 1e6 / c}


def measure_raw(env, batch, processes, repeats, solver=None, log=print, backend="mjx", physics_threads=0):
    """Raw stepping throughput (physics backend `backend`) of `batch` envs split over `processes` workers."""
    cmds = [[sys.executable, "-m", "gsa_jax.bench", "--raw-worker", "--env", env, "--batch", str(b), "--seed0", str(i),
             "--repeats", str(repeats), "--physics", backend, "--physics-threads", str(physics_threads)] + _solver_args(solver)
            for i, b in enumerate(_split(batch, processes))]
    results = run_workers(cmds, log=log)
    return {"env": env, "batch": batch, "processes": processes, **_solver_field(solver), "backend": backend,
            "physics_threads": physics_threads,
            "env_steps_per_s": sum(r["env_steps_per_s"] for r in results),
            "compile_s": max(r["compile_s"] for r in results), **_compile_fields(results), "chunk_s": [r["chunk_s"] for r in results]}


def time_profile(env, policy, runs, repeats, run_batch=RUN_BATCH, log=print, backend="mjx", processes=1):
    """Where one PPO iteration's time goes (`runs` runs split over `processes` workers, each in sub-batches
    of `run_batch`, 0 = all at once): t(E epochs) = t_collect + E t_epoch, measured at E = 1 and the
    default E; physics = the same number of env steps stepped raw, each worker stepping the envs one
    sub-batch steps at a time. Returns wall seconds per iteration of all the runs (the workers together)
    for physics, the rest of the rollout (policy sampling, normalization, GAE, host), and the PPO update
    (all epochs)."""
    epochs = Config.num_epochs
    cell = SweepCell(env, policy, runs, processes, run_batch=run_batch, backend=backend)
    full = measure_sweep(cell, repeats, log=log)
    one = measure_sweep(cell._replace(epochs=1), repeats, log=log)
    steps = full["env_steps_per_iteration"]
    t_full, t_one = steps / full["env_steps_per_s"], steps / one["env_steps_per_s"]
    t_epoch = max(0.0, (t_full - t_one) / (epochs - 1))
    t_collect = max(0.0, t_one - t_epoch)
    per_worker = max(_split(runs, processes))
    raw_batch = (min(per_worker, run_batch) if run_batch else per_worker) * Config.num_envs * processes
    raw = measure_raw(env, raw_batch, processes, repeats, log=log, backend=backend)
    t_physics = min(t_collect, steps / raw["env_steps_per_s"])
    return {"env": env, "policy": policy, "runs": runs, "processes": processes, "run_batch": run_batch, "raw_batch": raw_batch,
            "backend": backend,
            "num_epochs": epochs, "iteration_s": t_full, "env_steps_per_iteration": steps,
            "physics_s": t_physics, "rollout_other_s": t_collect - t_physics, "update_s": epochs * t_epoch,
            "fractions": {"physics": t_physics / t_full, "rollout_other": (t_collect - t_physics) / t_full,
                          "update": epochs * t_epoch / t_full},
            "raw_env_steps_per_s": raw["env_steps_per_s"], "train_env_steps_per_s": full["env_steps_per_s"],
            "train_env_steps_per_s_1_epoch": one["env_steps_per_s"]}


def measure_mujoco_c(env_name, batch=256, steps=200, repeats=3, threads=None, solver=None):
    """Env-steps/s of MuJoCo C (`mujoco.rollout`) on the env's own MJCF: random controls, the env's
    substeps (n_frames) per env step, one MjData per thread. Models with a start keyframe (allegro)
    start there and random-walk their PD targets as the env's actions do (contacts stay active).
    solver: None (the MJCF's settings) or (iterations, ls_iterations) set on a copy of the model."""

    base = envs.make_base(env_name)
    model = envs.mj_model(base)
    if solver:
        model = copy.deepcopy(model)
        model.opt.iterations, model.opt.ls_iterations = solver
    n_frames = envs.substeps(base)
    threads = threads or os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(threads)]
    d0 = mujoco.MjData(model)
    mujoco.mj_resetData(model, d0)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, d0, 0)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.zeros((mujoco.mj_stateSize(model, spec),))
    mujoco.mj_getState(model, d0, state, spec)
    rng = np.random.default_rng(0)
    init = np.repeat(state[None], batch, axis=0)
    nq = model.nq
    init[:, 1:1 + nq] += rng.uniform(-0.005, 0.005, size=(batch, nq))  # state[0] is time
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    if model.nkey:  # targets = start targets + a random walk of 0.025 rad steps (envs/allegro.py's action scale)
        walk = np.cumsum(rng.uniform(-0.025, 0.025, size=(batch, steps, model.nu)), axis=1)
        ctrl = np.clip(model.key_ctrl[0] + walk, lo, hi)
    else:
        ctrl = rng.uniform(lo, hi, size=(batch, steps, model.nu))
    ctrl = np.repeat(ctrl, n_frames, axis=1)  # each action held for n_frames physics steps
    times = []
    with rollout.Rollout(nthread=threads) as r:
        r.rollout([model] * batch, datas, init, ctrl)  # warm-up
        for _ in range(repeats):
            t = time.perf_counter()
            r.rollout([model] * batch, datas, init, ctrl)
            times.append(time.perf_counter() - t)
    med = statistics.median(times)
    return {"env": env_name, "batch": batch, "threads": threads, "substeps_per_env_step": n_frames, **_solver_field(solver),
            "env_steps_per_s": batch * steps / med, "physics_steps_per_s": batch * steps * n_frames / med, "times_s": times}


# ----------------------------------------------------------------------------------------------- report
_BACKEND_NAMES = {"mjx": "MJX", "c": "MuJoCo C in the program"}


def _lines(rows, keys, x):
    """{key values: [(x, env_steps_per_s)] sorted by x} over measurement rows (backend 'mjx' where absent)."""
    lines = {}
    for r in rows:
        key = tuple(r.get(k, "mjx") for k in keys)
        lines.setdefault(key, []).append((r[x], r["env_steps_per_s"]))
    return {k: sorted(v) for k, v in sorted(lines.items())}


def plot(results, raw, mujoco_c, path, mujoco_c_variant=None):
    """Left: training throughput vs runs (a line per policy and process count); right: raw stepping vs
    batch. Measurements with a changed solver are separate markers (stars), with their MuJoCo C line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    ax = axes[0]
    ok = [r for r in results if "error" not in r and "solver" not in r]
    for (policy, procs, be), pts in _lines(ok, ("policy", "processes", "backend"), "runs").items():
        ax.plot(*zip(*pts), ("o" if policy == "mixture" else "s") + ("-" if be == "mjx" else "--"),
                label=f"{policy}, {procs} process(es), {_BACKEND_NAMES[be]}")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("runs trained together (vmapped)")
    ax.set_ylabel("env steps / s (training, end to end)")
    ax.set_title(f"{mujoco_c['env']}: sweep throughput vs MuJoCo C")
    ax2 = axes[1]
    okr = [r for r in raw if "error" not in r and "solver" not in r]
    for (procs, be), pts in _lines(okr, ("processes", "backend"), "batch").items():
        ax2.plot(*zip(*pts), "o-" if be == "mjx" else "o--", label=f"{_BACKEND_NAMES[be]} env.step, {procs} process(es)")
    ax2.set_xscale("log", base=2)
    ax2.set_xlabel("envs stepped together (batch)")
    ax2.set_ylabel("env steps / s (physics only, random actions)")
    ax2.set_title(f"{mujoco_c['env']}: raw stepping")
    for a, rows, x in ((ax, results, "runs"), (ax2, raw, "batch")):
        for r in rows:
            if "solver" in r and "error" not in r:
                sol = r["solver"]
                a.plot(r[x], r["env_steps_per_s"], "*", ms=13, color="C3",
                       label=f"solver {sol['iterations']}/{sol['ls_iterations']} (changed task), {r['processes']} process(es)"
                             + (f", {r['policy']}" if "policy" in r else ""))
    for a in axes:
        a.axhline(mujoco_c["env_steps_per_s"], color="k", ls=":", label=f"MuJoCo C rollout ({mujoco_c['threads']} threads)")
        if mujoco_c_variant:
            sol = mujoco_c_variant["solver"]
            a.axhline(mujoco_c_variant["env_steps_per_s"], color="C3", ls=":",
                      label=f"MuJoCo C, solver {sol['iterations']}/{sol['ls_iterations']}")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_solver_variant(text, quick):
    """--solver-variant: None -> SOLVER_VARIANT (none with --quick); 'none' -> None; 'I,L' -> (I, L)."""
    if text is None:
        return None if quick else SOLVER_VARIANT
    if text.strip().lower() == "none":
        return None
    try:
        it, ls = (int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--solver-variant must be ITER,LS (two integers) or none, got {text!r}") from None
    if it < 1 or ls < 1:
        raise ValueError(f"--solver-variant iterations must be >= 1, got {text!r}")
    return it, ls


def reps(repeats, runs, explicit=False):
    """Timed chunks for a sweep of `runs` runs: chunks of >= 64 runs take 10-40 s each here, 2 are enough."""
    return repeats if explicit or runs < 64 else min(repeats, 2)


def ratio_ceiling(prof, mujoco_c):
    """The best ours / MuJoCo C a trainer with this profile's policy and PPO cost could reach if its
    physics cost what MuJoCo C's does: per core and env step, 1/c (MuJoCo C: c = its env-steps/s per
    thread) plus what the profile measures outside physics, r (rollout rest + update; wall seconds per env
    step of the profile's P processes together, so P r per process): ratio <= (1 / (1/c + P r)) / c =
    1 / (1 + P r c). Each process counts as one core. A P = cores profile measures the update as the
    sweep's workers run it (one per core, sharing caches and memory); a 1-process profile measures it
    alone on the machine, which can differ either way (experiments/bench_c_backend/)."""
    c = mujoco_c["env_steps_per_s"] / mujoco_c["threads"]
    r = prof["processes"] * (prof["rollout_other_s"] + prof["update_s"]) / prof["env_steps_per_iteration"]
    return {"non_physics_s_per_env_step": r, "mujoco_c_env_steps_per_s_per_thread": c,
            "ratio_ceiling_with_mujoco_c_physics": 1.0 / (1.0 + r * c)}


def estimate_s(plan, raw_plan, profile_runs, repeats, profiles=1):
    """Rough wall time: ~50 s compile + start per measurement, timed chunks at ~10k steps/s per process;
    `profiles` time profiles of profile_runs runs."""
    t = 30 + sum(60 + (reps(repeats, n) + 1) * n * 2048 / (8000 + 4000 * k) / (2 if sol else 1) for _, n, k, sol, _ in plan)
    t += sum(40 + (repeats + 1) * b * RAW_UNROLL / (15000 * k) / (2 if sol else 1) for b, k, sol, _ in raw_plan)
    if profile_runs:
        t += profiles * (2 * (50 + (repeats + 1) * profile_runs * 2048 / 10000) + 40)
    return t


def positive_ints(flag, text, default):
    """Comma-separated positive integers of a flag (or the default); ValueError naming the flag."""
    if not text:
        return default
    try:
        values = [int(s) for s in text.split(",")]
    except ValueError:
        raise ValueError(f"{flag} takes comma-separated positive integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise ValueError(f"{flag} takes comma-separated positive integers, got {text!r}")
    return values


def build_parser():
    p = argparse.ArgumentParser(prog="python -m gsa_jax.bench", description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true",
                   help="1 run on 1 process and 16 runs on all cores, mixture only, raw batch 256 on all cores (~3 min)")
    p.add_argument("--out", default="runs/bench")
    p.add_argument("--env", default="hopper", help="hopper or allegro_cylinder (any env of envs.NAMES)")
    p.add_argument("--sizes", default=None, help="comma-separated run counts (default 1,16,64,256)")
    p.add_argument("--policies", default=None,
                   help="comma-separated (default: mixture at every size, mlp at the largest size)")
    p.add_argument("--processes", default=None, help="comma-separated worker counts (default 1,<cores>)")
    p.add_argument("--raw-batches", default=None, help="comma-separated env batches for raw stepping (default 256,4096)")
    p.add_argument("--profile-runs", type=int, default=0,
                   help="also profile one PPO iteration (physics / rest of rollout / update) at this many runs, e.g. 64")
    p.add_argument("--profile-processes", default="1",
                   help="comma-separated worker counts of the time profile (default 1; <cores>: as the sweep's workers "
                        "run, which gives the ceiling the sweep on all cores can reach)")
    p.add_argument("--repeats", type=int, default=None,
                   help="timed chunks per measurement (default 3; 2 for sweeps of >= 64 runs, whose chunks are long)")
    p.add_argument("--run-batch", type=int, default=RUN_BATCH,
                   help=f"runs per sequential sub-batch in each worker, as gsa_jax.sweep --run-batch (default {RUN_BATCH}, "
                        "the sweep's; 0: all at once)")
    p.add_argument("--solver-variant", default=None,
                   help="ITER,LS: also measure the largest raw batch and mixture sweep (all cores) and MuJoCo C with this "
                        "many solver / line-search iterations (default 1,4; 'none' to skip; skipped with --quick)")
    p.add_argument("--value-target", default="gae",
                   help="the critic of the measured sweeps: gae (default) or retrace (with its default buffer)")
    p.add_argument("--physics", default="mjx",
                   help="comma-separated physics backends to measure, each for every raw batch, sweep and profile: "
                        "mjx (default), c (MuJoCo C inside the program), or mjx,c")
    p.add_argument("--physics-threads", type=int, default=0,
                   help="MuJoCo C threads per worker process for --physics c (default 0: its share of the cores)")
    # worker-only arguments
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--raw-worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--compile-each", action="store_true", help=argparse.SUPPRESS)
    for a, t in (("--policy", str), ("--clusters", int), ("--runs", int), ("--seed0", int), ("--barrier", str),
                 ("--worker-id", int), ("--num-workers", int), ("--batch", int), ("--epochs", int),
                 ("--solver-iterations", int), ("--ls-iterations", int)):
        p.add_argument(a, type=t, default=None, help=argparse.SUPPRESS)
    return p


def parse_backends(text, env):
    """--physics: the backends to measure, each checked against the task; ValueError naming the flag."""

    backends = [b.strip() for b in text.split(",")]
    for b in backends:
        try:
            envs.check_backend(env, Physics(backend=b))
        except ValueError as e:
            raise ValueError(f"--physics: {e}") from None
    return list(dict.fromkeys(backends))


def make_plan(args):
    """What to measure: {sizes, procs, batches, policies, variant, repeats, backends, plan, raw_plan}: plan
    entries (policy, runs, processes, solver variant, backend), raw_plan (batch, processes, variant, backend);
    ValueError on bad input."""
    envs.check_name(args.env)
    backends = parse_backends(args.physics, args.env)
    cores = os.cpu_count() or 1
    policies = args.policies.split(",") if args.policies else ["mixture"]
    sizes = positive_ints("--sizes", args.sizes, list(QUICK_SIZES if args.quick else SIZES))
    procs = positive_ints("--processes", args.processes, sorted({1, cores}))
    batches = positive_ints("--raw-batches", args.raw_batches, [256] if args.quick else list(RAW_BATCHES))
    variant = parse_solver_variant(args.solver_variant, args.quick)
    profile_procs = positive_ints("--profile-processes", args.profile_processes, [1])
    if args.profile_runs and max(profile_procs) > args.profile_runs:
        raise ValueError(f"--profile-processes {max(profile_procs)} is more than --profile-runs {args.profile_runs}")
    for pol, be in itertools.product(policies, backends):  # the sweeps' own validation, before anything compiles
        check_spec({"envs": [args.env], "policies": [pol], "clusters": [6], "steps": 1,
                    "config": {"value_target": args.value_target, "backend": be}}, source="bench")
    plan = [(pol, n, k, None, be) for be in backends for pol in policies for n in sizes for k in procs if k <= n]
    raw_plan = [(b, k, None, be) for be in backends for b in batches for k in procs if k <= b]
    if args.quick and not args.processes:  # under 3 min: each size on as many processes as it can use
        plan = [(pol, n, max(k for k in procs if k <= n), None, be) for be in backends for pol in policies for n in sizes]
        raw_plan = [(b, max(k for k in procs if k <= b), None, be) for be in backends for b in batches]
    k_all = max(k for k in procs if k <= max(sizes))
    if not args.policies and not args.quick:  # the flat baseline where it matters most, to stay under ~20 min
        plan += [("mlp", max(sizes), k_all, None, be) for be in backends]
    if variant and "mjx" in backends:  # MJX's solver options
        plan += [("mixture", max(sizes), k_all, variant, "mjx")]
        raw_plan += [(max(batches), max(k for k in procs if k <= max(batches)), variant, "mjx")]
    return {"sizes": sizes, "procs": procs, "batches": batches, "policies": policies, "variant": variant, "backends": backends,
            "profile_procs": profile_procs,
            "repeats": args.repeats or (2 if args.quick else 3), "plan": plan, "raw_plan": raw_plan}


def add_ratios(r, c_ref, solver):
    """ratio_vs_mujoco_c: against MuJoCo C with the same solver settings (the same simulator);
    ratio_vs_mujoco_c_task_solver: against MuJoCo C with the MJCF's own (differs for the variant)."""
    r["ratio_vs_mujoco_c"] = r["env_steps_per_s"] / c_ref[solver]["env_steps_per_s"]
    r["ratio_vs_mujoco_c_task_solver"] = r["env_steps_per_s"] / c_ref[None]["env_steps_per_s"]


def solver_tag(solver):
    return f"  solver {solver[0]}/{solver[1]}" if solver else ""


def measure_references(env, variant):
    """MuJoCo C's rate with the task's solver (key None) and, if asked, with the variant's."""
    mujoco_c = measure_mujoco_c(env)
    print(f"MuJoCo C rollout: {mujoco_c['env_steps_per_s']:,.0f} env-steps/s ({mujoco_c['threads']} threads, "
          f"batch {mujoco_c['batch']}, {mujoco_c['substeps_per_env_step']} substeps)", flush=True)
    c_ref = {None: mujoco_c}
    if variant:
        c_ref[variant] = measure_mujoco_c(env, solver=variant)
        print(f"MuJoCo C rollout with {variant[0]} solver / {variant[1]} line-search iterations: "
              f"{c_ref[variant]['env_steps_per_s']:,.0f} env-steps/s", flush=True)
    return c_ref


def measure_raw_plan(args, info, report, c_ref, save):
    print(f"{'raw':8} {'physics':>7} {'batch':>5} {'procs':>5} {'env-steps/s':>12} {'ratio_vs_C':>10} {'compile_s':>9}", flush=True)
    for b, k, sol, be in info["raw_plan"]:
        try:
            r = measure_raw(args.env, b, k, info["repeats"], solver=sol, backend=be, physics_threads=args.physics_threads)
            add_ratios(r, c_ref, sol)
            print(f"{'':8} {be:>7} {b:5d} {k:5d} {r['env_steps_per_s']:12,.0f} {r['ratio_vs_mujoco_c']:10.3f} {r['compile_s']:9.1f}"
                  + solver_tag(sol), flush=True)
        except BenchError as e:
            r = {"env": args.env, "batch": b, "processes": k, **_solver_field(sol), "backend": be, "error": str(e)}
        report["raw"].append(r)
        save()


def measure_sweep_plan(args, info, report, c_ref, save):
    print(f"{'policy':8} {'physics':>7} {'runs':>5} {'procs':>5} {'env-steps/s':>12} {'ratio_vs_C':>10} {'compile_s':>9} "
          f"{'peak_MiB':>9}", flush=True)
    for pol, n, k, sol, be in info["plan"]:
        try:
            cell = SweepCell(args.env, pol, n, k, solver=sol, run_batch=args.run_batch, value_target=args.value_target,
                             backend=be, physics_threads=args.physics_threads)
            r = measure_sweep(cell, reps(info["repeats"], n, args.repeats is not None))
            add_ratios(r, c_ref, sol)
            print(f"{pol:8} {be:>7} {n:5d} {k:5d} {r['env_steps_per_s']:12,.0f} {r['ratio_vs_mujoco_c']:10.3f} "
                  f"{r['compile_s']:9.1f} {r['peak_rss_mib']:9.0f}" + solver_tag(sol), flush=True)
            if "in_run" in r:
                r["in_run"].update(in_run_ceiling(r["in_run"], c_ref[sol]))
                r["in_run"]["sweep_of_ceiling"] = r["ratio_vs_mujoco_c"] / r["in_run"]["ratio_ceiling_in_run"]
                print_in_run(r["in_run"])
        except BenchError as e:
            r = {"env": args.env, "policy": pol, "runs": n, "processes": k, **_solver_field(sol), "backend": be, "error": str(e)}
        report["sweeps"].append(r)
        save()


def print_in_run(split):
    """One line: a 'c' sweep's split of its time and its in-run ceiling."""
    f = split["fractions"]
    print(f"{'':8} in the run: MuJoCo C {f['mujoco_c']:.0%} ({split['mujoco_c_us_per_env_step']:.1f} us per env step and "
          f"worker; its rollout {split['rollout_us_per_env_step']:.1f}), rest of the host calls {f['host_other']:.0%}, "
          f"program {f['program']:.0%}; ceiling {split['ratio_ceiling_in_run']:.2f} of MuJoCo C, the sweep at "
          f"{split['sweep_of_ceiling']:.2f} of it ({split['sweep_of_ceiling_at_own_mujoco_c']:.2f} with MuJoCo C at its "
          f"own cost in the run)", flush=True)


def measure_profile(args, repeats, mujoco_c, backend="mjx", processes=1):
    """The time profile at --profile-runs runs on `processes` workers, with the ratio ceiling when MuJoCo C
    was measured."""
    try:
        prof = time_profile(args.env, "mixture", args.profile_runs, repeats, args.run_batch, backend=backend,
                            processes=processes)
        f = prof["fractions"]
        print(f"time profile ({backend}, mixture, {args.profile_runs} runs, {processes} process(es)), per PPO iteration "
              f"{prof['iteration_s']:.2f} s: "
              f"physics {f['physics']:.0%}, rest of rollout (policy, normalization, GAE) {f['rollout_other']:.0%}, "
              f"PPO update ({prof['num_epochs']} epochs) {f['update']:.0%}", flush=True)
        if "error" not in mujoco_c:
            prof.update(ratio_ceiling(prof, mujoco_c))
            print(f"with physics as cheap as MuJoCo C's and this policy + PPO update, ours / MuJoCo C could reach at most "
                  f"{prof['ratio_ceiling_with_mujoco_c_physics']:.2f}", flush=True)
    except BenchError as e:
        prof = {"backend": backend, "processes": processes, "error": str(e)}
    return prof


def main(argv=None):
    args = build_parser().parse_args(argv)
    if args.worker or args.raw_worker:
        args.repeats = args.repeats or 3
        (worker if args.worker else raw_worker)(args)
        return 0
    try:
        info = make_plan(args)
    except ValueError as e:
        print(f"gsa_jax.bench: error: {e}", file=sys.stderr)
        return 2
    plan, raw_plan, variant, repeats = info["plan"], info["raw_plan"], info["variant"], info["repeats"]
    n_profiles = len(info["backends"]) * len(info["profile_procs"])
    print(f"gsa_jax.bench: {args.env}: raw stepping at batch {info['batches']}, {len(plan)} sweep configurations (runs "
          f"{info['sizes']}, policies {info['policies']}, processes {info['procs']})"
          + (f", a time profile at {args.profile_runs} runs on {info['profile_procs']} process(es)" if args.profile_runs else "")
          + (f", the largest sizes again with {variant[0]} solver / {variant[1]} line-search iterations" if variant else "")
          + f"; {repeats} timed chunks each (median); about {estimate_s(plan, raw_plan, args.profile_runs, repeats, n_profiles) / 60:.0f} min",
          flush=True)
    os.makedirs(args.out, exist_ok=True)
    t_start = time.perf_counter()
    c_ref = measure_references(args.env, variant)
    mujoco_c = c_ref[None]
    report = {"env": args.env, "quick": args.quick, "repeats": repeats, "run_batch": args.run_batch, "mujoco_c": mujoco_c,
              "raw": [], "sweeps": [],
              **({"mujoco_c_solver_variant": c_ref[variant]} if variant else {}), **run_metadata()}

    def save():
        report["wall_s"] = time.perf_counter() - t_start
        write_atomic(os.path.join(args.out, "bench.json"), json.dumps(report, indent=1))

    measure_raw_plan(args, info, report, c_ref, save)
    measure_sweep_plan(args, info, report, c_ref, save)
    if args.profile_runs:
        report["profiles"] = [measure_profile(args, repeats, mujoco_c, be, k) for be in info["backends"]
                              for k in info["profile_procs"]]
        save()
    plot(report["sweeps"], report["raw"], mujoco_c, os.path.join(args.out, "bench.png"), report.get("mujoco_c_solver_variant"))
    print(f"wrote {args.out}/bench.json and bench.png in {(time.perf_counter() - t_start) / 60:.1f} min", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
