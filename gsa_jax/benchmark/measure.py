"""The benchmark's measurements: sweeps of N runs timed in worker processes (SweepCell, measure_sweep),
raw stepping, the time profile of one PPO iteration, MuJoCo C's own rollout as the reference, and the
in-run ceiling. `gsa bench` is its command."""

import copy
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Callable, NamedTuple

import numpy as np

import envs
from gsa_jax.algorithm.config import Config
from gsa_jax.errors import UserError
from gsa_jax.running.spec import RUN_BATCH
from gsa_jax.running.supervise import worker_env

SIZES = (1, 16, 64, 256)
QUICK_SIZES = (1, 16)
RAW_BATCHES = (256, 4096)
RAW_UNROLL = 20  # env steps per timed raw-stepping chunk
WORKER = (sys.executable, "-m", "gsa_jax.benchmark.workers")  # a worker process: its kind (sweep or raw), then its cell
SOLVER_VARIANT = (1, 4)  # (solver iterations, line-search iterations) of the extra "cheaper solver" lines


class BenchError(UserError):
    pass


def run_workers(cmds: list, compile_limit_s: float = 900, retries: int = 1, log: Callable = print,
                compile_each: bool = False) -> list:
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


def solver_field(solver: "tuple | None") -> dict:
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
    randomize: str = ""  # the runs' domain randomization (envs/randomization.py's text; '': none)


def worker_command(cell: SweepCell, runs: int, seed0: int, repeats: int) -> list:
    """The command line of one bench worker training `runs` runs of the cell from seed seed0."""
    return ([*WORKER, "sweep", "--env", cell.env, "--policy", cell.policy,
             "--clusters", str(cell.clusters), "--runs", str(runs), "--seed0", str(seed0), "--repeats", str(repeats)]
            + (["--epochs", str(cell.epochs)] if cell.epochs else []) + _solver_args(cell.solver)
            + ["--run-batch", str(cell.run_batch)]
            + ["--value-target", cell.value_target, "--physics", cell.backend, "--physics-threads", str(cell.physics_threads)]
            + (["--randomize", cell.randomize] if cell.randomize else []))


def measure_sweep(cell: SweepCell, repeats: int, log: Callable = print, compile_each: bool = False) -> dict:
    """Throughput of a SweepCell, its workers measured together; compile_each: see run_workers."""
    cmds, seed0 = [], 0
    for n in _split(cell.runs, cell.processes):
        cmds.append(worker_command(cell, n, seed0, repeats))
        seed0 += n
    results = run_workers(cmds, log=log, compile_each=compile_each)
    return {
        "env": cell.env, "policy": cell.policy, "runs": cell.runs, "processes": cell.processes,
        **({"num_epochs": cell.epochs} if cell.epochs else {}), **solver_field(cell.solver), "value_target": cell.value_target,
        "backend": cell.backend, "physics_threads": cell.physics_threads, "randomize": cell.randomize,
        "env_steps_per_s": sum(r["env_steps_per_s"] for r in results),
        "compile_s": max(r["compile_s"] for r in results), **_compile_fields(results),
        "peak_rss_mib": sum(r["peak_rss_mib"] for r in results),
        "peak_rss_mib_per_process": max(r["peak_rss_mib"] for r in results),
        "chunk_s": [r["chunk_s"] for r in results],
        "env_steps_per_iteration": sum(r["env_steps_per_chunk"] for r in results),
        **({"in_run": split} if (split := in_run_split(results)) else {}),
    }


def in_run_split(results: list) -> "dict | None":
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


def in_run_ceiling(split: dict, mujoco_c: dict) -> dict:
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


def measure_raw(env: str, batch: int, processes: int, repeats: int, solver: "tuple | None" = None,
                log: Callable = print, backend: str = "mjx", physics_threads: int = 0) -> dict:
    """Raw stepping throughput (physics backend `backend`) of `batch` envs split over `processes` workers."""
    cmds = [[*WORKER, "raw", "--env", env, "--batch", str(b), "--seed0", str(i),
             "--repeats", str(repeats), "--physics", backend, "--physics-threads", str(physics_threads)] + _solver_args(solver)
            for i, b in enumerate(_split(batch, processes))]
    results = run_workers(cmds, log=log)
    return {"env": env, "batch": batch, "processes": processes, **solver_field(solver), "backend": backend,
            "physics_threads": physics_threads,
            "env_steps_per_s": sum(r["env_steps_per_s"] for r in results),
            "compile_s": max(r["compile_s"] for r in results), **_compile_fields(results), "chunk_s": [r["chunk_s"] for r in results]}


def time_profile(env: str, policy: str, runs: int, repeats: int, run_batch: int = RUN_BATCH, log: Callable = print,
                 backend: str = "mjx", processes: int = 1) -> dict:
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


def measure_mujoco_c(env_name: str, batch: int = 256, steps: int = 200, repeats: int = 3, threads: "int | None" = None,
                     solver: "tuple | None" = None) -> dict:
    """Env-steps/s of MuJoCo C (`mujoco.rollout`) on the env's own MJCF: random controls, the env's
    substeps (n_frames) per env step, one MjData per thread. Models with a start keyframe (allegro)
    start there and random-walk their PD targets as the env's actions do (contacts stay active).
    solver: None (the MJCF's settings) or (iterations, ls_iterations) set on a copy of the model."""
    import mujoco  # here, its one use: the plan's names and checks load without MuJoCo (`gsa bench --help`)
    from mujoco import rollout

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
    return {"env": env_name, "batch": batch, "threads": threads, "substeps_per_env_step": n_frames, **solver_field(solver),
            "env_steps_per_s": batch * steps / med, "physics_steps_per_s": batch * steps * n_frames / med, "times_s": times}


def ratio_ceiling(prof: dict, mujoco_c: dict) -> dict:
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
