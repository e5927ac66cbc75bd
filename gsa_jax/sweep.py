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
  sweep.json            the spec, every run of the grid, versions, git commit; failed_runs at the end
  metrics.csv           tidy: one row per run per iteration (env, policy, K, seed, swept hparams, metrics; a swept
                        hparam named like a metric is hparam_<name>, e.g. hparam_lr next to the annealed lr)
  groups/<env>-<policy>/{state.npz, metrics.npz (+ their .prev.npz), params.npz, runs.csv, failed.json, DONE}
  LOCK                  pid and host of the sweep writing DIR (a second one is refused)
  xla_cache/            compiled programs (JAX's persistent cache): worker 0 compiles each group's
                        program once, the other workers and any resumed run load it (seconds)
With --num-processes P each process writes its share under DIR/process-<i>/ (`gsa_jax.plot` merges them).

Failures are loud and lose nothing: a run whose loss or parameters turn NaN/inf is frozen inside the
compiled program (ppo.guarded_iteration; the others train on bit for bit), its metrics end there and
its last finite parameters are kept; sweep.json and the final summary list it and the sweep exits 1.
A checkpoint unreadable on resume falls back to its previous version; a full disk stops with one line
(exit 4) and the same command resumes once space is freed; a changed experiment file is refused with
the difference (--force continues with it). Exit status: see main().

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

import argparse
import dataclasses
import itertools
import json
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import time
import tomllib

import numpy as np

from gsa_jax.checkpoint import CheckpointError, DiskFullError, read_with_fallback, write_atomic
from gsa_jax.policies import POLICY_KINDS, SUBPOLICY_KINDS
from gsa_jax.ppo import HPARAM_DEFAULTS, Config, check_hparam

SPEC_FIELDS = ("name", "envs", "policies", "subpolicies", "clusters", "cluster_multipliers", "seeds", "steps", "chunk",
               "hparams", "config")
SWEEP_METRICS = (
    "iteration", "env_steps", "episode_return", "episodes", "epsilon", "sigma_min", "lr", "policy_loss",
    "value_loss", "approx_kl", "clip_fraction", "grad_norm", "partition_entropy", "clusters_used",
)
TRACKED = SWEEP_METRICS + ("failed_at",)  # per run and iteration on the host; failed_at is not a CSV column
_STATIC_FIELDS = {f.name for f in dataclasses.fields(Config)} - {"env", "policy", "k_max"}
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
EXIT_FAILED_RUNS, EXIT_DISK_FULL = 1, 4


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
    if not isinstance(spec["name"], str) or not NAME_PATTERN.fullmatch(spec["name"]):
        bad("name", f"must be a plain name (letters, digits, '-', '_', '.'; not starting with '.' or '-'), got {spec['name']!r}")
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
    check_cluster_fields(spec, bad)
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
    spec["hparams"] = check_hparams_table(spec.get("hparams", {}), bad)
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


def check_cluster_fields(spec, bad):
    """clusters / cluster_multipliers / subpolicies of a spec, normalized to lists in place."""
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


def check_hparams_table(hps, bad):
    """The [hparams] table: known names, numbers (or lists of numbers) in their ranges -> {name: [values]}."""
    if not isinstance(hps, dict):
        bad("hparams", "must be a table")
    out = {}
    for k, v in hps.items():
        if k in ("K", "total_iterations"):
            bad(f"hparams.{k}", "is set by the sweep (use 'clusters'/'cluster_multipliers' and 'steps')")
        if k not in HPARAM_DEFAULTS:
            bad(f"hparams.{k}", f"unknown hyperparameter; known: {', '.join(h for h in HPARAM_DEFAULTS if h not in ('K', 'total_iterations'))}")
        values = v if isinstance(v, list) else [v]
        if not values or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values):
            bad(f"hparams.{k}", f"must be a number or a list of numbers, got {v!r}")
        for x in values:
            try:
                check_hparam(k, x)
            except ValueError as e:
                bad(f"hparams.{k}", str(e))
        out[k] = values
    return out


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


_PROGRAMS = {}  # (cfg, chunk, devices, run_batch, runs) -> compiled (init, run, place): reused within a process


def compile_group(cfg, chunk, devices, runs, hparam_names, iterations, run_batch=RUN_BATCH, share=None, log=print):
    """The group program for `runs` (already padded), compiled, and its initial state.
    share: None, or (mark_dir, leader) to compile once for all worker processes (xla_cache.compile_with;
    inside xla_cache.enabled(...) or after xla_cache.enable(...), with the same cache for every process).
    A program this process compiled before (same shapes) is reused.
    Returns (states, run, hps, place, how): run(states, hps) -> (states, metrics [R, chunk])."""
    import jax

    from gsa_jax import xla_cache

    key = (cfg, chunk, tuple(devices), run_batch, len(runs))
    how = "reused (compiled earlier in this process)"
    if key not in _PROGRAMS:
        _, init, run, place = make_group_program(cfg, chunk, devices, run_batch)
        hps = place(stack_hparams(runs, hparam_names, iterations))
        keys = place(jax.numpy.stack([jax.random.PRNGKey(r["seed"]) for r in runs]))
        init, _ = xla_cache.compile_with(init.lower(keys, hps), share, log)
        run, how = xla_cache.compile_with(run.lower(init(keys, hps), hps), share, log)
        _PROGRAMS.clear()  # keep the last program only: resumed groups and tests reuse it
        _PROGRAMS[key] = (init, run, place)
    init, run, place = _PROGRAMS[key]
    hps = place(stack_hparams(runs, hparam_names, iterations))
    keys = place(jax.numpy.stack([jax.random.PRNGKey(r["seed"]) for r in runs]))
    return init(keys, hps), run, hps, place, how


# ----------------------------------------------------------------------------------------------- files
def rows_of_run(metrics, i, upto):
    """Iterations of run i to write: up to `upto`, ending before the iteration where it failed (NaN/inf)."""
    failed_at = int(metrics["failed_at"][i, upto - 1]) if upto else -1
    return upto if failed_at < 0 else min(upto, failed_at - 1)


def group_csv(runs, id_cols, metrics, upto):
    """Tidy rows (run-major) of one group's metrics [R, iters] for the first `upto` iterations (a failed
    run's rows end before its failing iteration)."""
    lines = []
    for i, r in enumerate(runs):
        ids = ",".join(str(r[c]) for c in id_cols)
        cols = [metrics[m][i] for m in SWEEP_METRICS]
        for j in range(rows_of_run(metrics, i, upto)):
            vals = []
            for m, c in zip(SWEEP_METRICS, cols):
                v = c[j]
                vals.append("" if isinstance(v, float) and math.isnan(v) else (str(int(v)) if m in ("iteration", "env_steps", "clusters_used") else f"{float(v):.6g}"))
            lines.append(ids + "," + ",".join(vals))
    return ",".join([tidy_name(c) for c in id_cols] + list(SWEEP_METRICS)), lines


def tidy_name(column):
    """A swept hyperparameter's column in the tidy table: 'hparam_<name>' where a metric has its name (lr)."""
    return f"hparam_{column}" if column in SWEEP_METRICS else column


def failed_runs(runs, metrics, upto):
    """[run dict + failed_at] of the runs that stopped at a NaN/inf."""
    out = []
    for i, r in enumerate(runs):
        fa = int(metrics["failed_at"][i, upto - 1]) if upto else -1
        if fa >= 0:
            out.append({**r, "failed_at": fa})
    return out


def warn(msg):
    """A line the user must see even with --quiet (stderr)."""
    print(msg, file=sys.stderr, flush=True)


def load_group_checkpoint(gdir, states, iterations, log):
    """(states, metrics arrays [R, iterations], done) of a group's last intact checkpoint: state.npz
    (or state.prev.npz) and the metrics covering its iteration (metrics.npz or metrics.prev.npz)."""
    from gsa_jax.checkpoint import load_pytree

    def read_state(p):
        with np.load(p) as f:
            done = int(f["__done__"])
        return load_pytree(p, states), done

    (states, done), _ = read_with_fallback(os.path.join(gdir, "state.npz"), read_state, log)

    def read_metrics(p):
        with np.load(p) as m:
            if int(m["__done__"]) < done:
                raise ValueError(f"holds {int(m['__done__'])} iterations, the state {done}")
            rows = m["iteration"].shape[0]
            return {k: m[k][:, :done] if k in m.files else np.full((rows, done), -1.0) for k in TRACKED}

    saved, _ = read_with_fallback(os.path.join(gdir, "metrics.npz"), read_metrics, log)
    metrics = {m: np.full((saved["iteration"].shape[0], iterations), np.nan, np.float64) for m in TRACKED}
    for k in TRACKED:
        metrics[k][:, :done] = saved[k]
    return states, metrics, done


def save_group_checkpoint(gdir, states, metrics, done):
    """Metrics, then state (both keeping their previous version); the state records `done`."""
    from gsa_jax.checkpoint import save_npz_atomic, save_pytree

    save_npz_atomic(os.path.join(gdir, "metrics.npz"), True, __done__=np.array(done),
                    **{k: v[:, :done] for k, v in metrics.items()})
    save_pytree(os.path.join(gdir, "state.npz"), states, True, __done__=np.array(done))


def finish_group(gdir, states, runs, metrics, done, timing):
    """Final parameters (a failed run's last finite ones), failed.json and DONE; drop the resume state."""
    import jax

    from gsa_jax.checkpoint import previous_path, save_pytree

    params = jax.device_get({"params": states["params"], "obs_stats": states["obs_stats"]})
    save_pytree(os.path.join(gdir, "params.npz"), jax.tree.map(lambda x: x[: len(runs)], params))
    write_atomic(os.path.join(gdir, "failed.json"), json.dumps(failed_runs(runs, metrics, done)))
    write_atomic(os.path.join(gdir, "DONE"), json.dumps(timing))
    for name in ("state.npz", "state.prev.npz", "metrics.prev.npz"):  # the full state is only needed to resume
        if os.path.exists(os.path.join(gdir, name)):
            os.unlink(os.path.join(gdir, name))


# ----------------------------------------------------------------------------------------------- the worker
class GroupResult(tuple):
    """(done, iterations, metrics, runs) of one group: iterations done and planned, the host's metric
    arrays [R, iterations] (TRACKED), the group's runs."""

    done = property(lambda self: self[0])
    iterations = property(lambda self: self[1])
    metrics = property(lambda self: self[2])
    runs = property(lambda self: self[3])

    @property
    def finished(self):
        return self.done >= self.iterations


def progress(tag, runs, metrics, done, iterations, chunk, steps_per_s, batch, chunk_s):
    """One progress line of a group after a chunk."""
    last = metrics["episode_return"][: len(runs), max(0, done - chunk):done]
    recent = np.array([np.nanmean(row) if np.any(np.isfinite(row)) else np.nan for row in last])
    eta = (iterations - done) * batch * len(runs) / max(steps_per_s, 1e-9)
    failed = int(np.sum(metrics["failed_at"][: len(runs), done - 1] >= 0))
    best = np.nanmax(recent) if np.any(np.isfinite(recent)) else float("nan")
    median = np.nanmedian(recent) if np.any(np.isfinite(recent)) else float("nan")
    return (f"[{tag}] it {done}/{iterations} | {steps_per_s:,.0f} env-steps/s | ETA {eta / 60:.1f} min | return "
            f"best {best:.1f} median {median:.1f}" + (f" | {failed} run(s) failed (NaN/inf)" if failed else "")
            + f" | chunk {chunk_s:.1f}s")


def run_group(spec, out, env_name, policy, runs, devices, log, stop_after_chunks=None, heartbeat=None, on_chunk=None,
              run_batch=RUN_BATCH, pad_to=0, share=None):
    """Train (or resume) one group. Returns a GroupResult. pad_to: pad the runs to at least this many
    (every worker process builds the same program); share: see compile_group."""
    gdir = os.path.join(out, "groups", group_name(env_name, policy, runs))
    os.makedirs(gdir, exist_ok=True)
    cfg = group_config(spec, env_name, policy, runs)
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    if os.path.exists(os.path.join(gdir, "DONE")):
        with np.load(os.path.join(gdir, "metrics.npz")) as m:
            saved = {k: m[k] for k in m.files}
        saved.setdefault("failed_at", np.full_like(saved["iteration"], -1.0))
        return GroupResult((iterations, iterations, saved, runs))
    cols = id_columns(spec)
    write_atomic(os.path.join(gdir, "runs.csv"), "\n".join(
        [",".join(cols)] + [",".join(str(r[c]) for c in cols) for r in runs]) + "\n")
    padded = pad_runs(runs, len(devices), at_least=pad_to)
    t0 = time.perf_counter()
    states, run, hps, place, how = compile_group(cfg, chunk, devices, padded, list(spec["hparams"]), iterations, run_batch,
                                                 share, log)
    compile_s = time.perf_counter() - t0
    metrics = {m: np.full((len(padded), iterations), np.nan, np.float64) for m in TRACKED}
    done, tag = 0, group_name(env_name, policy, runs).replace(f"{env_name}-", f"{env_name}/", 1)
    if os.path.exists(os.path.join(gdir, "state.npz")) or os.path.exists(os.path.join(gdir, "state.prev.npz")):
        try:
            loaded, metrics, done = load_group_checkpoint(gdir, states, iterations, warn)
        except CheckpointError as e:
            raise SpecError(f"{e} (a sweep resumes with the same --devices as the interrupted one)") from None
        states = place(loaded)
        log(f"[{tag}] resumed at iteration {done}/{iterations}")
    log(f"[{tag}] {len(runs)} runs x {iterations} iterations x {cfg.batch_size} steps on "
        f"{len(devices)} device(s); program {how} ({compile_s:.1f}s)")
    loop = {"done": done, "chunks": 0, "steps": 0, "t": time.perf_counter(), "states": states}
    try:
        train_chunks(run, hps, metrics, loop, iterations, chunk, stop_after_chunks, gdir, tag, runs, cfg, log,
                     on_chunk, heartbeat)
    except DiskFullError as e:
        e.last_intact = f"iteration {loop['intact']} of group {tag}"
        raise
    if loop["done"] >= iterations:
        train_s = time.perf_counter() - loop["t"]
        finish_group(gdir, loop["states"], runs, metrics, loop["done"],
                     {"compile_s": compile_s, "train_s": train_s, "env_steps_per_s": loop["steps"] / max(train_s, 1e-9)})
    return GroupResult((loop["done"], iterations, metrics, runs))


def train_chunks(run, hps, metrics, loop, iterations, chunk, stop_after_chunks, gdir, tag, runs, cfg, log,
                 on_chunk, heartbeat):
    """run_group's chunk loop: train, record, checkpoint, report. loop: done, chunks, steps, t, states (updated)."""
    import jax

    loop["intact"] = loop["done"]
    while loop["done"] < iterations:
        tc = time.perf_counter()
        loop["states"], m = run(loop["states"], hps)
        m = jax.device_get(m)
        done = loop["done"]
        for k in TRACKED:
            metrics[k][:, done:done + chunk] = m[k]
        loop["done"] = done = done + chunk
        loop["steps"] += chunk * cfg.batch_size * len(runs)
        loop["chunks"] += 1
        save_group_checkpoint(gdir, loop["states"], metrics, done)
        loop["intact"] = done
        if on_chunk:
            on_chunk(GroupResult((done, iterations, {k: v[: len(runs)] for k, v in metrics.items()}, runs)))
        if heartbeat:
            heartbeat(time.perf_counter() - tc)
        _maybe_inject_hang(gdir, loop["chunks"])
        sps = loop["steps"] / (time.perf_counter() - loop["t"])
        log(progress(tag, runs, metrics, done, iterations, chunk, sps, cfg.batch_size, time.perf_counter() - tc))
        if stop_after_chunks is not None and loop["chunks"] >= stop_after_chunks and done < iterations:
            break


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


def check_same_spec(meta_path, spec, force):
    """Refuse (SpecError with a one-line diff) to resume a sweep whose spec changed, unless force."""
    from gsa_jax.runinfo import describe_changes

    with open(meta_path) as f:
        old = json.load(f)
    diff = describe_changes(old.get("spec", {}), json.loads(json.dumps(spec)))
    if diff and not force:
        raise SpecError(f"{os.path.dirname(meta_path) or '.'} holds a sweep with a different spec ({diff}); use another "
                        "--out, or --force to continue it with the new spec")


def write_sweep_meta(root, spec, groups, num_processes, force):
    """sweep.json: spec, every run, versions, commit (a resumed sweep must have the same spec, unless force)."""
    from gsa_jax.runinfo import run_metadata

    meta_path = os.path.join(root, "sweep.json")
    if os.path.exists(meta_path):
        check_same_spec(meta_path, spec, force)
    meta = {"spec": spec, "runs": [r for _, _, runs in groups for r in runs], "num_processes": num_processes, **run_metadata()}
    write_atomic(meta_path, json.dumps(meta, indent=1))


def run_sweep(spec, out, devices=None, quiet=False, stop_after_chunks=None, process_id=0, num_processes=1, heartbeat=None,
              run_batch=RUN_BATCH, local_workers=True, force=False):
    """Train every group of the spec (this process's share of each). Returns True when all groups are done;
    the runs that failed (NaN/inf) are written to failed_runs.json in this process's directory.
    run_batch: see make_group_program. local_workers: the processes share this machine and `out`
    (False for multi-host sweeps: each process compiles for itself). force: resume a changed spec."""
    import jax

    from gsa_jax import xla_cache

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
    if process_id == 0:
        write_sweep_meta(root, spec, groups, num_processes, force)
    total_runs = sum(len(r) for _, _, r in groups)
    log(f"sweep {spec['name']}: {total_runs} runs in {len(groups)} group(s) on {len(devices)} device(s)"
        + (f", process {process_id}/{num_processes}" if num_processes > 1 else "") + f" -> {out}")
    # compiled programs are kept in a cache: a resumed or restarted worker loads them; local worker
    # processes share one compile (worker 0 compiles, the others load -- gsa_jax.xla_cache)
    cache_dir = os.path.join(root if local_workers else out, "xla_cache")
    share = (cache_dir, process_id == 0 or not local_workers)
    results, complete = [], True
    try:
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
                if not res.finished:
                    complete = False
                    break
        failed = [f for res in results for f in failed_runs(res.runs, res.metrics, res.done)]
        write_atomic(os.path.join(out, "failed_runs.json"), json.dumps(failed))
    except DiskFullError as e:
        if not hasattr(e, "last_intact"):
            last = results[-1] if results else None
            e.last_intact = (f"iteration {last.done} of group {group_name(last.runs[0]['env'], last.runs[0]['policy'], last.runs)}"
                             if last else "none (nothing trained yet)")
        raise
    for f in failed:
        log(f"run failed (NaN/inf in loss or parameters) at iteration {f['failed_at']}: "
            + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "K", "seed") if k in f) + "; its metrics end there")
    return complete


def report_failures(root, dirs, log=print):
    """Collect the workers' failed_runs.json into sweep.json ('failed_runs') and print the summary.
    Returns the failed runs."""
    failed = []
    for d in dirs:
        path = os.path.join(d, "failed_runs.json")
        if os.path.exists(path):
            with open(path) as f:
                failed.extend(json.load(f))
    meta_path = os.path.join(root, "sweep.json")
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            meta = json.load(f)
        meta["failed_runs"] = failed
        write_atomic(meta_path, json.dumps(meta, indent=1))
    if failed:
        log(f"{len(failed)} run(s) failed (NaN/inf in the loss or parameters; listed in sweep.json 'failed_runs'):")
        for f in failed:
            log("  " + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "subpolicy", "K", "seed", "run") if k in f)
                + f": failed at iteration {f['failed_at']}")
    return failed


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
    p.add_argument("--force", action="store_true", help="resume even if the experiment file changed (continues with the new spec)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    return p


def check_args(args, argv):
    """(spec, out, local worker count) after checking every argument; raises SpecError. Nothing compiles."""
    spec = load_spec(args.experiment)
    if args.num_processes < 1 or not 0 <= args.process_id < args.num_processes:
        raise SpecError(f"--process-id must be in 0..{args.num_processes - 1}")
    out = args.out or os.path.join("runs", "sweeps", spec["name"])
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise SpecError(f"--out {out!r} cannot be created: {e.strerror or e}") from None
    local = args.local_processes if args.local_processes is not None else (1 if args.no_watchdog else (os.cpu_count() or 1))
    if args.num_processes > 1 or args.worker:
        local = 1  # multi-host: one process per host runs here, as launched
    if local < 1:
        raise SpecError("--local-processes must be >= 1")
    if args.run_batch < 0:
        raise SpecError(f"--run-batch must be >= 0, got {args.run_batch}")
    return spec, out, local


def main(argv=None):
    """Exit status: 0 done (or stopped as asked), 1 some runs failed (NaN/inf), 2 bad input or a locked /
    changed / unreadable output directory, 3 a worker hung repeatedly, 4 disk full, 130 interrupted."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec, out, local = check_args(args, argv)
    except SpecError as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2
    if args.worker:
        return run_worker(args, spec, out)
    from gsa_jax.runlock import LockError, hold

    lock_dir = out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")
    os.makedirs(lock_dir, exist_ok=True)
    try:
        with hold(lock_dir, f"gsa_jax.sweep {spec['name']}", log=lambda m: print(m, file=sys.stderr)):
            if local > 1 or not args.no_watchdog:
                return supervise_workers(args, argv, out, local)
            return run_worker(args, spec, out)
    except LockError as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2


def supervise_workers(args, argv, out, local):
    """Start the worker processes under the watchdog; then collect failed runs into sweep.json."""
    base = list(argv) + (["--out", out] if args.out is None else [])
    if local > 1:
        argvs = [base + ["--process-id", str(i), "--num-processes", str(local), "--local-processes", "1"] for i in range(local)]
        dirs = [os.path.join(out, f"process-{i}") for i in range(local)]
        print(f"sweep: {local} local worker processes (one XLA CPU device each); logs prefixed [process i]", flush=True)
    else:
        argvs = [base]
        dirs = [out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")]
    for d in dirs:
        os.makedirs(d, exist_ok=True)
    status = supervise(argvs, dirs, args.watchdog_min, args.max_restarts)
    if status == 0:
        try:
            if report_failures(out, dirs):
                return EXIT_FAILED_RUNS
        except DiskFullError as e:
            print(f"gsa_jax.sweep: error: {e.describe('the final one of every group (training is done; only sweep.json is behind)')}", file=sys.stderr)
            return EXIT_DISK_FULL
        print(f"sweep complete: {out}", flush=True)
    return status


def run_worker(args, spec, out):
    """Train this process's share in this process (a supervised worker, or --no-watchdog)."""
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
        complete = run_sweep(spec, out, devices, args.quiet, args.stop_after_chunks, args.process_id, args.num_processes,
                             heartbeat, args.run_batch, local_workers=args.coordinator is None, force=args.force)
    except SpecError as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2
    except DiskFullError as e:
        print(f"gsa_jax.sweep: error: {e.describe(getattr(e, 'last_intact', 'none (nothing trained yet)'))}", file=sys.stderr)
        return EXIT_DISK_FULL
    if not args.quiet:
        done_msg = "done" if complete else "stopped; run the same command again to resume"
        print((f"[process {args.process_id}] " if args.num_processes > 1 else "sweep ") + done_msg + f": {out}", flush=True)
    if args.worker or args.num_processes > 1:
        return 0
    try:
        return EXIT_FAILED_RUNS if report_failures(out, [wdir], log=print) else 0
    except DiskFullError as e:
        print(f"gsa_jax.sweep: error: {e.describe('the final one of every group (training is done; only sweep.json is behind)')}",
              file=sys.stderr)
        return EXIT_DISK_FULL


if __name__ == "__main__":
    sys.exit(main())
