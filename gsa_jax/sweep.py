"""Sweeps: a grid of (env, policy, K, seed, hyperparameters) trained as one vmapped program per (env, policy).

    python -m gsa_jax.sweep experiments/fig1_small.toml [--out DIR] [--devices N]
    make sweep EXP=experiments/fig1_small.toml

Every run of an (env, policy) group trains at once: `jax.vmap` over the runs, the run axis
sharded over the local devices (`shard_map`). On a CPU, use the cores with --local-processes N
(default: one per core): N worker processes, each training its share of every group's runs
on its own XLA CPU device (or set --xla_force_host_platform_device_count and --local-processes 1); worker 0
compiles each group's program and the others load it from the sweep's compilation cache (gsa_jax.xla_cache).
Training goes in chunks of iterations; after each chunk the group's state, its
metrics and the tidy `metrics.csv` are written atomically, so a killed sweep resumes from its
last chunk when the same command runs again and ends with the same results. A supervisor
process watches a heartbeat and restarts a worker whose chunk takes far longer than usual
(XLA:CPU has been seen to hang in large vmapped MJX programs).

Output (DIR, default runs/sweeps/<name>):
  sweep.json            the spec, every run of the grid, versions, git commit
  metrics.csv           tidy: one row per run per iteration (env, policy, K, seed, swept hparams, metrics)
  groups/<env>-<policy>/{state.npz, metrics.npz, params.npz, runs.csv, DONE}
  xla_cache/            compiled programs (JAX's persistent cache): worker 0 compiles each group's
                        program once, the other workers and any resumed run load it (seconds)
With --num-processes P each process writes its share under DIR/process-<i>/ (`gsa_jax.plot` merges them).

Experiment file (TOML):
  name = "fig1_small"
  envs = ["inverted_double_pendulum", "hopper"]
  policies = ["mlp", "mixture"]
  cluster_multipliers = [0.5, 1, 2, 4]   # K = ceil(m * action_dim); or: clusters = [2, 4, 6]
  subpolicies = ["constant", "linear"]    # optional: sub-policy classes of the mixtures (default linear)
  seeds = 8                               # seeds 0..7, or a list [0, 5, 9]
  steps = 200_000                         # env steps per run
  chunk = 10                              # PPO iterations per compiled chunk (optional)
  [hparams]                               # scalars, or lists to sweep over (every combination)
  lr = 3e-4
  eps_decay = [0.99, 0.995]
  [config]                                # static gsa_jax.ppo.Config fields (num_envs, unroll_length, ...)
  num_envs = 32
"""

import os
import sys

import argparse
import dataclasses  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import signal  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402

import numpy as np  # noqa: E402

from gsa_jax.checkpoint import write_atomic  # noqa: E402

from gsa_jax.ppo import HPARAM_DEFAULTS, Config  # noqa: E402
from gsa_jax.policies import POLICY_KINDS, SUBPOLICY_KINDS  # noqa: E402

SPEC_FIELDS = ("name", "envs", "policies", "subpolicies", "clusters", "cluster_multipliers", "seeds", "steps", "chunk",
               "hparams", "config")
SWEEP_METRICS = (
    "iteration", "env_steps", "episode_return", "episodes", "epsilon", "sigma_min", "lr", "policy_loss",
    "value_loss", "approx_kl", "clip_fraction", "grad_norm", "partition_entropy", "clusters_used",
)
_STATIC_FIELDS = {f.name for f in dataclasses.fields(Config)} - {"env", "policy", "k_max"}


class SpecError(ValueError):
    pass


# ----------------------------------------------------------------------------------------------- spec and grid
def load_spec(path):
    """Read and check an experiment file; errors name the file and the bad field."""
    if os.path.isdir(path):
        candidates = [os.path.join(path, n) for n in ("sweep.toml", os.path.basename(path.rstrip("/")) + ".toml")]
        path = next((c for c in candidates if os.path.exists(c)), path)
    if not os.path.exists(path):
        raise SpecError(f"{path}: no such experiment file")
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML: {e}") from None
    return check_spec(raw, source=path)


def check_spec(raw, source="spec"):
    def bad(field, msg):
        raise SpecError(f"{source}: field '{field}': {msg}")

    unknown = set(raw) - set(SPEC_FIELDS)
    if unknown:
        bad(sorted(unknown)[0], f"unknown field; allowed: {', '.join(SPEC_FIELDS)}")
    import envs

    spec = dict(raw)
    spec.setdefault("name", os.path.splitext(os.path.basename(source))[0])
    for field in ("envs", "policies"):
        if field not in spec:
            bad(field, "missing")
        if isinstance(spec[field], str):
            spec[field] = [spec[field]]
        if not isinstance(spec[field], list) or not spec[field]:
            bad(field, "must be a non-empty list")
    for e in spec["envs"]:
        if e not in envs.NAMES:
            bad("envs", f"unknown env {e!r}; choose from {', '.join(envs.NAMES)}")
    for p in spec["policies"]:
        if p not in POLICY_KINDS:
            bad("policies", f"unknown policy {p!r}; choose from {', '.join(POLICY_KINDS)}")
    if "mixture" in spec["policies"]:
        if ("clusters" in spec) == ("cluster_multipliers" in spec):
            bad("clusters", "a mixture sweep needs exactly one of 'clusters' (absolute K) or 'cluster_multipliers' (K / action_dim)")
        if "clusters" in spec:
            ks = spec["clusters"] if isinstance(spec["clusters"], list) else [spec["clusters"]]
            if not ks or not all(isinstance(k, int) and k >= 1 for k in ks):
                bad("clusters", f"must be integers >= 1, got {spec['clusters']!r}")
            spec["clusters"] = ks
        else:
            ms = spec["cluster_multipliers"] if isinstance(spec["cluster_multipliers"], list) else [spec["cluster_multipliers"]]
            if not ms or not all(isinstance(m, (int, float)) and m > 0 for m in ms):
                bad("cluster_multipliers", f"must be positive numbers, got {spec['cluster_multipliers']!r}")
            spec["cluster_multipliers"] = ms
    if "subpolicies" in spec:  # absent stays absent: a spec's identity (sweep.json) must not change
        subs = spec["subpolicies"] if isinstance(spec["subpolicies"], list) else [spec["subpolicies"]]
        if "mixture" not in spec["policies"]:
            bad("subpolicies", "applies to mixture policies; add 'mixture' to policies")
        if not subs or any(x not in SUBPOLICY_KINDS for x in subs) or len(set(subs)) != len(subs):
            bad("subpolicies", f"must be distinct names from {', '.join(SUBPOLICY_KINDS)}, got {spec['subpolicies']!r}")
        spec["subpolicies"] = subs
    seeds = spec.get("seeds", 1)
    if isinstance(seeds, int):
        if seeds < 1:
            bad("seeds", f"must be >= 1 or a list of seeds, got {seeds}")
        seeds = list(range(seeds))
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        bad("seeds", "must be a count >= 1 or a list of non-negative integers")
    if len(set(seeds)) != len(seeds):
        bad("seeds", "repeats a seed")
    spec["seeds"] = seeds
    if not isinstance(spec.get("steps"), int) or spec["steps"] < 1:
        bad("steps", f"must be a positive integer, got {spec.get('steps')!r}")
    if "chunk" in spec and (not isinstance(spec["chunk"], int) or spec["chunk"] < 1):
        bad("chunk", f"must be a positive integer, got {spec['chunk']!r}")
    hps = spec.get("hparams", {})
    if not isinstance(hps, dict):
        bad("hparams", "must be a table")
    for k, v in hps.items():
        if k in ("K", "total_iterations"):
            bad(f"hparams.{k}", "is set by the sweep (use 'clusters'/'cluster_multipliers' and 'steps')")
        if k not in HPARAM_DEFAULTS:
            bad(f"hparams.{k}", f"unknown hyperparameter; known: {', '.join(h for h in HPARAM_DEFAULTS if h not in ('K', 'total_iterations'))}")
        values = v if isinstance(v, list) else [v]
        if not values or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values):
            bad(f"hparams.{k}", f"must be a number or a list of numbers, got {v!r}")
        hps[k] = values
    spec["hparams"] = hps
    cfg = spec.get("config", {})
    if not isinstance(cfg, dict):
        bad("config", "must be a table")
    for k in cfg:
        if k not in _STATIC_FIELDS:
            bad(f"config.{k}", f"unknown; allowed: {', '.join(sorted(_STATIC_FIELDS))}")
    spec["config"] = cfg
    try:
        Config(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}).validate()
    except (ValueError, TypeError) as e:
        bad("config", str(e))
    return spec


def action_size(env_name):
    import envs

    return envs.make_base(env_name).action_size


def cluster_counts(spec, env_name):
    """K values of a mixture group: absolute, or ceil(m * action_dim) for each multiplier (deduplicated, sorted)."""
    if "clusters" in spec:
        return sorted(set(spec["clusters"]))
    d_a = action_size(env_name)
    return sorted({max(1, math.ceil(m * d_a - 1e-9)) for m in spec["cluster_multipliers"]})


def swept_names(spec):
    return [k for k, v in spec["hparams"].items() if len(v) > 1]


def id_columns(spec):
    """Columns that identify a run in runs.csv and the tidy metrics.csv."""
    sub = ["subpolicy"] if "subpolicies" in spec else []
    return ["env", "policy", *sub, "K", "seed", "run", *swept_names(spec)]


def build_grid(spec):
    """[(env, policy, [run dicts])]: every combination of K x swept hparams x seed exactly once, per group.
    A group is one compiled program: (env, policy), and for mixtures with `subpolicies`, one per class."""
    names = list(spec["hparams"])
    combos = list(itertools.product(*(spec["hparams"][n] for n in names))) or [()]
    groups = []
    for env_name in spec["envs"]:
        for policy in spec["policies"]:
            ks = cluster_counts(spec, env_name) if policy == "mixture" else [1]
            subs = spec.get("subpolicies", [None]) if policy == "mixture" else ([""] if "subpolicies" in spec else [None])
            for sub in subs:
                runs = []
                for k in ks:
                    for combo in combos:
                        for seed in spec["seeds"]:
                            runs.append({"run": len(runs), "env": env_name, "policy": policy,
                                         **({} if sub is None else {"subpolicy": sub}),
                                         "K": k, "seed": seed, **dict(zip(names, combo))})
                groups.append((env_name, policy, runs))
    return groups


def group_name(env_name, policy, runs):
    sub = runs[0].get("subpolicy") if runs else None
    return f"{env_name}-{policy}" + (f"-{sub}" if sub else "")


def group_config(spec, env_name, policy, runs):
    static = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["config"].items()}
    sub = runs[0].get("subpolicy") or "linear"
    return Config(env=env_name, policy=policy, subpolicy=sub, k_max=max(r["K"] for r in runs), **static)


def group_iterations(spec, cfg, chunk):
    iters = math.ceil(spec["steps"] / cfg.batch_size)
    return math.ceil(iters / chunk) * chunk


def default_chunk(spec, cfg):
    return spec.get("chunk") or max(1, min(10, math.ceil(spec["steps"] / cfg.batch_size) // 20))


# ----------------------------------------------------------------------------------------------- programs
def stack_hparams(runs, names, iterations):
    import jax.numpy as jnp

    from gsa_jax.ppo import make_hparams

    per_run = [make_hparams(K=r["K"], total_iterations=iterations, **{n: r[n] for n in names}) for r in runs]
    return {k: jnp.stack([h[k] for h in per_run]) for k in per_run[0]}


RUN_BATCH = 8  # runs per sub-batch (make_group_program); measured in experiments/README.md (benchmark)


def sub_batched(fn, size):
    """fn (vmapped over a leading run axis R) applied to sequential slices of `size` runs in a lax.scan,
    when size divides R and is smaller; else fn itself. (Explicit shapes: jax.lax.map(batch_size=) fails
    on MJX's zero-size arrays.)"""
    import jax

    def run(*xs):
        n = jax.tree.leaves(xs)[0].shape[0]
        if not size or size >= n or n % size:
            return fn(*xs)
        split = jax.tree.map(lambda x: x.reshape((n // size, size) + x.shape[1:]), xs)
        _, ys = jax.lax.scan(lambda c, x: (c, fn(*x)), None, split)
        return jax.tree.map(lambda y: y.reshape((n,) + y.shape[2:]), ys)

    return run


def make_group_program(cfg, chunk, devices, run_batch=RUN_BATCH):
    """(init(keys [R], hps [R]) -> states, run(states, hps) -> (states, metrics [R, chunk])), jit-compiled,
    vmapped over runs and, with several devices, sharded over them (R must be a multiple of len(devices)).
    run_batch: train each device's runs in sequential sub-batches of this many (sub_batched) instead of
    all at once (0 or None) -- the same per-run computation; MJX's batched solver loops then stop at each sub-batch's
    slowest env instead of the whole device's."""
    import jax
    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

    from gsa_jax.ppo import make_train

    trainer = make_train(cfg)
    init = jax.vmap(trainer.init)
    run = sub_batched(jax.vmap(lambda s, h: trainer.run_chunk(s, h, chunk)), run_batch)
    if len(devices) > 1:
        # check_vma=False: MJX's solver has lax.cond branches whose outputs shard_map's varying-axis
        # type check rejects; every op here is per-run, so nothing needs that check.
        mesh = jax.sharding.Mesh(np.array(devices), ("runs",))
        init = jax.shard_map(init, mesh=mesh, in_specs=(P("runs"), P("runs")), out_specs=P("runs"), check_vma=False)
        run = jax.shard_map(run, mesh=mesh, in_specs=(P("runs"), P("runs")), out_specs=P("runs"), check_vma=False)
        sharding = NamedSharding(mesh, P("runs"))
    else:
        sharding = jax.sharding.SingleDeviceSharding(devices[0])
    place = lambda tree: jax.device_put(tree, sharding)  # noqa: E731
    return trainer, jax.jit(init), jax.jit(run, donate_argnums=0), place


def pad_runs(runs, multiple, at_least=0):
    """Pad with copies of the last run to at least `at_least` runs and a multiple of `multiple` (the
    devices), so the run axis splits evenly (copies are dropped later)."""
    n = max(len(runs), at_least)
    pad = n - len(runs) + (-n) % multiple
    return runs + [dict(runs[-1], run=-1)] * pad


def compile_group(cfg, chunk, devices, runs, hparam_names, iterations, run_batch=RUN_BATCH, share=None, log=print):
    """The group program for `runs` (already padded), compiled, and its initial state.
    share: None, or (mark_dir, leader) to compile once for all worker processes (xla_cache.compile_with;
    inside xla_cache.enabled(...) or after xla_cache.enable(...), with the same cache for every process).
    Returns (states, run, hps, place, how): run(states, hps) -> (states, metrics [R, chunk])."""
    import jax

    from gsa_jax import xla_cache

    _, init, run, place = make_group_program(cfg, chunk, devices, run_batch)
    hps = place(stack_hparams(runs, hparam_names, iterations))
    keys = place(jax.numpy.stack([jax.random.PRNGKey(r["seed"]) for r in runs]))
    init, _ = xla_cache.compile_with(init.lower(keys, hps), share, log)
    states = init(keys, hps)
    run, how = xla_cache.compile_with(run.lower(states, hps), share, log)
    return states, run, hps, place, how


# ----------------------------------------------------------------------------------------------- files
def group_csv(runs, id_cols, metrics, upto):
    """Tidy rows (run-major) of one group's metrics [R, iters] for the first `upto` iterations."""
    lines = []
    for i, r in enumerate(runs):
        ids = ",".join(str(r[c]) for c in id_cols)
        cols = [metrics[m][i, :upto] for m in SWEEP_METRICS]
        for j in range(upto):
            vals = []
            for m, c in zip(SWEEP_METRICS, cols):
                v = c[j]
                vals.append("" if isinstance(v, float) and math.isnan(v) else (str(int(v)) if m in ("iteration", "env_steps", "clusters_used") else f"{float(v):.6g}"))
            lines.append(ids + "," + ",".join(vals))
    return ",".join(id_cols + list(SWEEP_METRICS)), lines


# ----------------------------------------------------------------------------------------------- the worker
def run_group(spec, out, env_name, policy, runs, devices, log, stop_after_chunks=None, heartbeat=None, on_chunk=None,
              run_batch=RUN_BATCH, pad_to=0, share=None):
    """Train (or resume) one group. Returns (iterations done, iterations total, metrics dict, runs).
    pad_to: pad the runs to at least this many (every worker process builds the same program);
    share: see compile_group."""
    import jax

    from gsa_jax.checkpoint import load_pytree, save_npz_atomic, save_pytree

    gdir = os.path.join(out, "groups", group_name(env_name, policy, runs))
    tag = group_name(env_name, policy, runs).replace(f"{env_name}-", f"{env_name}/", 1)
    os.makedirs(gdir, exist_ok=True)
    cfg = group_config(spec, env_name, policy, runs)
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    padded = pad_runs(runs, len(devices), at_least=pad_to)
    R = len(padded)
    state_path, metrics_path = os.path.join(gdir, "state.npz"), os.path.join(gdir, "metrics.npz")
    if os.path.exists(os.path.join(gdir, "DONE")):
        with np.load(metrics_path) as m:
            return iterations, iterations, {k: m[k] for k in m.files}, runs
    cols = id_columns(spec)
    write_atomic(os.path.join(gdir, "runs.csv"), "\n".join(
        [",".join(cols)] + [",".join(str(r[c]) for c in cols) for r in runs]) + "\n")

    t0 = time.perf_counter()
    states, run, hps, place, how = compile_group(cfg, chunk, devices, padded, list(spec["hparams"]), iterations, run_batch,
                                                 share, log)
    compile_s = time.perf_counter() - t0
    metrics = {m: np.full((R, iterations), np.nan, np.float64) for m in SWEEP_METRICS}
    done = 0
    if os.path.exists(state_path) and os.path.exists(metrics_path):
        try:
            states = place(load_pytree(state_path, states))
        except ValueError as e:
            raise SpecError(f"cannot resume {gdir} ({e}); resume with the same --devices as the interrupted sweep") from None
        with np.load(metrics_path) as m:
            done = int(m["__done__"])
            for k in SWEEP_METRICS:
                metrics[k][:, :done] = m[k][:, :done]
        log(f"[{tag}] resumed at iteration {done}/{iterations}")
    log(f"[{tag}] {len(runs)} runs x {iterations} iterations x {cfg.batch_size} steps on "
        f"{len(devices)} device(s); program {how} ({compile_s:.1f}s)")
    t_train, steps_run, chunks_run = time.perf_counter(), 0, 0
    while done < iterations:
        tc = time.perf_counter()
        states, m = run(states, hps)
        m = jax.device_get(m)
        for k in SWEEP_METRICS:
            metrics[k][:, done:done + chunk] = m[k]
        done += chunk
        steps_run += chunk * cfg.batch_size * len(runs)
        chunks_run += 1
        save_pytree(state_path, states)
        save_npz_atomic(metrics_path, __done__=np.array(done), **{k: v[:, :done] for k, v in metrics.items()})
        if on_chunk:
            on_chunk((done, iterations, {k: v[: len(runs)] for k, v in metrics.items()}, runs))
        if heartbeat:
            heartbeat(time.perf_counter() - tc)
        _maybe_inject_hang(gdir, chunks_run)
        sps = steps_run / (time.perf_counter() - t_train)
        last = metrics["episode_return"][: len(runs), max(0, done - chunk):done]
        recent = np.array([np.nanmean(row) if np.any(np.isfinite(row)) else np.nan for row in last])
        eta = (iterations - done) * cfg.batch_size * len(runs) / max(sps, 1e-9)
        log(f"[{tag}] it {done}/{iterations} | {sps:,.0f} env-steps/s | ETA {eta / 60:.1f} min | return "
            f"best {np.nanmax(recent) if np.any(np.isfinite(recent)) else float('nan'):.1f} "
            f"median {np.nanmedian(recent) if np.any(np.isfinite(recent)) else float('nan'):.1f} | chunk {time.perf_counter() - tc:.1f}s")
        if stop_after_chunks is not None and chunks_run >= stop_after_chunks and done < iterations:
            return done, iterations, metrics, runs
    params = jax.device_get({"params": states["params"], "obs_stats": states["obs_stats"]})
    save_pytree(os.path.join(gdir, "params.npz"), jax.tree.map(lambda x: x[: len(runs)], params))
    write_atomic(os.path.join(gdir, "DONE"), json.dumps({"compile_s": compile_s, "train_s": time.perf_counter() - t_train,
                                                          "env_steps_per_s": steps_run / max(time.perf_counter() - t_train, 1e-9)}))
    if os.path.exists(state_path):
        os.unlink(state_path)  # the full state is only needed to resume
    return done, iterations, metrics, runs


def _maybe_inject_hang(gdir, chunks_run):
    """Fault injection for the watchdog test: with GSA_JAX_FAULT_HANG_AFTER_CHUNKS=N the worker stalls
    (like an XLA:CPU hang: alive, no progress) once, after its N-th chunk in a group."""
    n = os.environ.get("GSA_JAX_FAULT_HANG_AFTER_CHUNKS")
    marker = os.path.join(gdir, ".fault_injected")
    if n and chunks_run == int(n) and not os.path.exists(marker):
        write_atomic(marker, "1")
        time.sleep(1e9)


def write_tidy(out, spec, results):
    header, lines = None, []
    for done, _, metrics, runs in results:
        header, ls = group_csv(runs, id_columns(spec), metrics, done)
        lines.extend(ls)
    if header:
        write_atomic(os.path.join(out, "metrics.csv"), header + "\n" + "\n".join(lines) + ("\n" if lines else ""))


def run_sweep(spec, out, devices=None, quiet=False, stop_after_chunks=None, process_id=0, num_processes=1, heartbeat=None,
              run_batch=RUN_BATCH, local_workers=True):
    """Train every group of the spec (this process's share of each). Returns True when all groups are done.
    run_batch: see make_group_program. local_workers: the processes share this machine and `out`
    (False for multi-host sweeps: each process compiles for itself)."""
    import jax

    from gsa_jax import xla_cache

    from gsa_jax.runinfo import run_metadata

    prefix = f"[process {process_id}] " if num_processes > 1 else ""

    def log(msg):
        if not quiet:
            print(prefix + msg, flush=True)

    devices = list(devices or jax.local_devices())
    root = out
    if num_processes > 1:
        out = os.path.join(out, f"process-{process_id}")
    os.makedirs(out, exist_ok=True)
    groups = build_grid(spec)
    meta_path = os.path.join(root, "sweep.json")
    if process_id == 0:
        if os.path.exists(meta_path):
            with open(meta_path) as f:
                old = json.load(f)
            if old.get("spec") != json.loads(json.dumps(spec)):
                raise SpecError(f"{root} holds a sweep with a different spec; use another --out")
        meta = {"spec": spec, "runs": [r for _, _, runs in groups for r in runs], "num_processes": num_processes,
                **run_metadata()}
        write_atomic(meta_path, json.dumps(meta, indent=1))
    total_runs = sum(len(r) for _, _, r in groups)
    log(f"sweep {spec['name']}: {total_runs} runs in {len(groups)} group(s) on {len(devices)} device(s)"
        + (f", process {process_id}/{num_processes}" if num_processes > 1 else "") + f" -> {out}")
    # compiled programs are kept in a cache: a resumed or restarted worker loads them; local worker
    # processes share one compile (worker 0 compiles, the others load -- gsa_jax.xla_cache)
    cache_dir = os.path.join(root if local_workers else out, "xla_cache")
    share = (cache_dir, process_id == 0 or not local_workers)
    results, complete = [], True
    with xla_cache.enabled(cache_dir):
        for env_name, policy, runs in groups:
            mine = runs[process_id::num_processes]
            if not mine:
                continue
            res = run_group(spec, out, env_name, policy, mine, devices, log, stop_after_chunks, heartbeat,
                            on_chunk=lambda partial: write_tidy(out, spec, results + [partial]), run_batch=run_batch,
                            pad_to=math.ceil(len(runs) / num_processes), share=share)
            results.append(res)
            write_tidy(out, spec, results)
            if res[0] < res[1]:
                complete = False
                break
    return complete


# ----------------------------------------------------------------------------------------------- supervisor
SINGLE_THREAD_EIGEN = "--xla_cpu_multi_thread_eigen=false"


def worker_env(processes):
    """Environment of `processes` local worker processes. With a worker on every core, XLA's Eigen ops
    run single-threaded in each (their thread pools would only compete with the other workers; 256
    hopper runs on 2 cores: 1.05-1.12x, experiments/README.md), unless XLA_FLAGS already sets it."""
    env = dict(os.environ)
    if 1 < (os.cpu_count() or 1) <= processes and "xla_cpu_multi_thread_eigen" not in env.get("XLA_FLAGS", ""):
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + SINGLE_THREAD_EIGEN).strip()
    return env


def supervise(worker_argvs, heartbeat_dirs, watchdog_min_s, max_restarts, log=print):
    """Run one worker process per argv; kill and restart (from its last checkpoint) any worker whose
    heartbeat stalls for longer than max(watchdog_min_s, 10 x its median chunk time). Returns the
    first non-zero exit status, or 0."""
    workers = {}

    def start(i):
        hb = os.path.join(heartbeat_dirs[i], "heartbeat.json")
        if os.path.exists(hb):
            os.unlink(hb)
        proc = subprocess.Popen([sys.executable, "-m", "gsa_jax.sweep", *worker_argvs[i], "--worker"], start_new_session=True,
                                env=worker_env(len(worker_argvs)))
        workers[i] = {"proc": proc, "hb": hb, "seen": None, "last": time.time(), "durations": [], "restarts": workers.get(i, {}).get("restarts", 0)}

    for i in range(len(worker_argvs)):
        start(i)
    status = 0
    try:
        while workers:
            time.sleep(1.0)
            for i, w in list(workers.items()):
                rc = w["proc"].poll()
                if rc is not None:
                    del workers[i]
                    status = status or rc
                    continue
                try:
                    with open(w["hb"]) as f:
                        hb = json.load(f)
                    if hb["count"] != w["seen"]:
                        w["seen"], w["last"], w["durations"] = hb["count"], time.time(), hb["durations"][-20:]
                except (OSError, ValueError, KeyError):
                    pass
                # before the first chunk (compiling, possibly several minutes for big groups): generous
                limit = (max(watchdog_min_s, 10 * statistics.median(w["durations"])) if w["durations"]
                         else max(3 * watchdog_min_s, 600.0))
                if time.time() - w["last"] > limit:
                    log(f"watchdog: worker {i} made no progress for {time.time() - w['last']:.0f}s (limit {limit:.0f}s); "
                        f"killing it and restarting from its last checkpoint")
                    os.killpg(w["proc"].pid, signal.SIGKILL)
                    w["proc"].wait()
                    if w["restarts"] >= max_restarts:
                        log(f"watchdog: worker {i} gave up after {max_restarts} restarts")
                        del workers[i]
                        status = status or 3
                        continue
                    w["restarts"] += 1
                    start(i)
    except KeyboardInterrupt:
        for w in workers.values():
            os.killpg(w["proc"].pid, signal.SIGKILL)
            w["proc"].wait()
        log("\ninterrupted; finished chunks are saved: run the same command again to resume")
        return 130
    return status


def build_parser():
    p = argparse.ArgumentParser(prog="python -m gsa_jax.sweep", description=__doc__.split("\n")[0])
    p.add_argument("experiment", help="experiment file (TOML), e.g. experiments/fig1_small.toml")
    p.add_argument("--out", default=None, help="output directory (default runs/sweeps/<name>)")
    p.add_argument("--devices", type=int, default=None, help="shard each worker's runs over its first N local devices (default: all)")
    p.add_argument("--local-processes", type=int, default=None,
                   help="worker processes on this machine, each with its share of the runs (default: one per CPU core)")
    p.add_argument("--no-watchdog", action="store_true", help="run in this process, without the restarting supervisor")
    p.add_argument("--watchdog-min", type=float, default=600.0, help="seconds without progress before a restart (at least)")
    p.add_argument("--max-restarts", type=int, default=5)
    p.add_argument("--stop-after-chunks", type=int, default=None, help="stop (resumably) after N chunks")
    p.add_argument("--coordinator", default=None, help="host:port of process 0, for multi-process sweeps")
    p.add_argument("--num-processes", type=int, default=1)
    p.add_argument("--process-id", type=int, default=0)
    p.add_argument("--run-batch", type=int, default=RUN_BATCH,
                   help=f"train each device's runs in sequential sub-batches of N (default {RUN_BATCH}; 0: all at once). "
                        "Same runs; MJX's batched solver loops stop at each sub-batch's slowest env")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    return p


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec = load_spec(args.experiment)
        if args.num_processes < 1 or not 0 <= args.process_id < args.num_processes:
            raise SpecError(f"--process-id must be in 0..{args.num_processes - 1}")
        out = args.out or os.path.join("runs", "sweeps", spec["name"])
        os.makedirs(out, exist_ok=True)
    except (SpecError, OSError) as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2
    local = args.local_processes if args.local_processes is not None else (1 if args.no_watchdog else (os.cpu_count() or 1))
    if args.num_processes > 1 or args.worker:
        local = 1  # multi-host: one process per host runs here, as launched
    if local < 1:
        print("gsa_jax.sweep: error: --local-processes must be >= 1", file=sys.stderr)
        return 2
    if args.run_batch < 0:
        print(f"gsa_jax.sweep: error: --run-batch must be >= 0, got {args.run_batch}", file=sys.stderr)
        return 2
    if not args.worker and (local > 1 or not args.no_watchdog):
        base = [a for a in argv]
        if args.out is None:
            base += ["--out", out]
        if local > 1:
            argvs = [base + ["--process-id", str(i), "--num-processes", str(local), "--local-processes", "1"] for i in range(local)]
            dirs = [os.path.join(out, f"process-{i}") for i in range(local)]
        else:
            argvs = [base]
            dirs = [out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")]
        for d in dirs:
            os.makedirs(d, exist_ok=True)
        if local > 1:
            print(f"sweep: {local} local worker processes (one XLA CPU device each); logs prefixed [process i]", flush=True)
        status = supervise(argvs, dirs, args.watchdog_min, args.max_restarts)
        if status == 0:
            print(f"sweep complete: {out}", flush=True)
        return status

    import jax

    if args.num_processes > 1 and args.coordinator:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
        # eager arrays (the MJX model Brax builds) would otherwise land on global device 0, which
        # belongs to process 0; each process works on its own devices only
        jax.config.update("jax_default_device", jax.local_devices()[0])
    devices = jax.local_devices()
    if args.devices is not None:
        if not 1 <= args.devices <= len(devices):
            print(f"gsa_jax.sweep: error: --devices must be in 1..{len(devices)}", file=sys.stderr)
            return 2
        devices = devices[: args.devices]
    wdir = out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")
    os.makedirs(wdir, exist_ok=True)
    beats = {"count": 0, "durations": []}

    def heartbeat(duration):
        beats["count"] += 1
        beats["durations"] = (beats["durations"] + [duration])[-50:]
        write_atomic(os.path.join(wdir, "heartbeat.json"), json.dumps(beats))

    try:
        complete = run_sweep(spec, out, devices, args.quiet, args.stop_after_chunks, args.process_id, args.num_processes, heartbeat,
                             args.run_batch, local_workers=args.coordinator is None)
    except SpecError as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2
    if not args.quiet:
        done_msg = "done" if complete else "stopped; run the same command again to resume"
        print((f"[process {args.process_id}] " if args.num_processes > 1 else "sweep ") + done_msg + f": {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
