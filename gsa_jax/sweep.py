"""Sweeps: a grid of (env, policy, K, seed, hyperparameters) trained as one vmapped program per (env, policy).

    python -m gsa_jax.sweep experiments/fig1_small/fig1_small.toml [--out DIR] [--devices N]
    make sweep EXP=experiments/fig1_small/fig1_small.toml

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
  sweep.json            the spec, every run of the grid, runs per sub-batch, versions, git commit; failed_runs at the end
  metrics.csv           tidy: one row per run per iteration (env, policy, K, seed, swept hparams, metrics with
                        eval_return, the deterministic controller's mean return where evaluated; a swept
                        hparam named like a metric is hparam_<name>, e.g. hparam_lr next to the annealed lr)
  groups/<env>-<policy>/{state.npz, metrics.npz (+ their .prev.npz), params.npz, runs.csv, failed.json, DONE}
  tensorboard/<run>/    TensorBoard event files of every run (tensorboard --logdir DIR; --no-tensorboard: none)
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
  value_targets = ["gae", "retrace"]      # optional: the critics to compare (default [config] value_target, gae)
  seeds = 8                               # seeds 0..7, or a list [0, 5, 9]
  steps = 200_000                         # env steps per run
  chunk = 10                              # PPO iterations per compiled chunk (optional)
  eval_every = 8                          # iterations between deterministic evaluations (default ~25 per run; 0: none)
  eval_seed = 0                           # evaluation start states: the same for every run of the sweep
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
import sys
import time
import tomllib

import numpy as np

from gsa_jax.checkpoint import CheckpointError, DiskFullError, read_with_fallback, write_atomic
from gsa_jax.driver import failed_mask, rows_before_failure
from gsa_jax.metrics import EVALUATIONS_PER_RUN, INTEGER_METRICS, TIDY_METRICS
from gsa_jax.policies import POLICY_KINDS, SUBPOLICY_KINDS
from gsa_jax.ppo import HPARAM_DEFAULTS, Config, check_hparam
from gsa_jax.programs import RUN_BATCH, pad_runs
from gsa_jax.retrace import VALUE_TARGETS

SPEC_FIELDS = ("name", "envs", "policies", "subpolicies", "value_targets", "clusters", "cluster_multipliers", "seeds", "steps", "chunk",
               "eval_every", "eval_seed",
               "hparams", "config")
TRACKED = TIDY_METRICS + ("failed_at",)  # per run and iteration in metrics.npz; failed_at is not a CSV column
_STATIC_FIELDS = {f.name for f in dataclasses.fields(Config)} - {"env", "policy", "k_max"}
# Static options a spec may list to compare (one compiled group each): (spec field, run column = Config field,
# the policy it applies to or None for every policy, allowed values). Absent from a spec: no column, no group.
GROUP_AXES = (("subpolicies", "subpolicy", "mixture", SUBPOLICY_KINDS), ("value_targets", "value_target", None, VALUE_TARGETS))
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
    for field in ("eval_every", "eval_seed"):
        if field in spec and (not isinstance(spec[field], int) or isinstance(spec[field], bool) or spec[field] < 0):
            bad(field, f"must be an integer >= 0, got {spec[field]!r}")
    spec["hparams"] = check_hparams_table(spec.get("hparams", {}), bad)
    cfg = spec.get("config", {})
    if not isinstance(cfg, dict):
        bad("config", "must be a table")
    for k in cfg:
        if k not in _STATIC_FIELDS:
            bad(f"config.{k}", f"unknown; allowed: {', '.join(sorted(_STATIC_FIELDS))}")
    spec["config"] = cfg
    try:
        for e in spec["envs"]:  # every env: the physics backend must run it
            Config(env=e, **{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}).validate()
    except (ValueError, TypeError) as e:
        bad("config", str(e))
    check_group_axes(spec, bad)
    return spec


def check_cluster_fields(spec, bad):
    """clusters / cluster_multipliers of a spec, normalized to lists in place."""
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


def check_group_axes(spec, bad):
    """subpolicies / value_targets (GROUP_AXES) of a spec, normalized to lists in place; absent stays absent
    (a spec's identity, sweep.json, must not change)."""
    for field, column, policy, allowed in GROUP_AXES:
        if field not in spec:
            continue
        values = spec[field] if isinstance(spec[field], list) else [spec[field]]
        if policy is not None and policy not in spec["policies"]:
            bad(field, f"applies to {policy} policies; add '{policy}' to policies")
        if not values or any(x not in allowed for x in values) or len(set(values)) != len(values):
            bad(field, f"must be distinct names from {', '.join(allowed)}, got {spec[field]!r}")
        if column in spec.get("config", {}):
            bad(field, f"set {column} either here or in [config], not both")
        spec[field] = values


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


def cluster_counts(spec, env_name):
    """K values of a mixture group: absolute, or ceil(m * action_dim) for each multiplier (deduplicated, sorted)."""
    if "clusters" in spec:
        return sorted(set(spec["clusters"]))
    import envs

    d_a = envs.action_size(env_name)
    return sorted({cluster_count(m, d_a) for m in spec["cluster_multipliers"]})


def cluster_count(multiplier, action_dim):
    """K of a cluster multiplier m on a task with action_dim actions: ceil(m * action_dim), at least 1."""
    return max(1, math.ceil(multiplier * action_dim - 1e-9))


def swept_names(spec):
    return [k for k, v in spec["hparams"].items() if len(v) > 1]


def id_columns(spec):
    """Columns that identify a run in runs.csv and the tidy metrics.csv."""
    axes = [column for field, column, _, _ in GROUP_AXES if field in spec]
    return ["env", "policy", *axes, "K", "seed", "run", *swept_names(spec)]


def axis_values(spec, axis, policy):
    """A group axis's values for one policy: [None] (not in the spec: no column), the listed values,
    or [""] (listed, but it does not apply to this policy)."""
    field, _, applies_to, _ = axis
    if field not in spec:
        return [None]
    return spec[field] if applies_to in (None, policy) else [""]


def build_grid(spec):
    """[(env, policy, [run dicts])]: every combination of K x swept hparams x seed exactly once, per group.
    A group is one compiled program: (env, policy), and one per value of each listed GROUP_AXES field."""
    names = list(spec["hparams"])
    combos = list(itertools.product(*(spec["hparams"][n] for n in names))) or [()]
    groups = []
    for env_name in spec["envs"]:
        for policy in spec["policies"]:
            ks = cluster_counts(spec, env_name) if policy == "mixture" else [1]
            for values in itertools.product(*(axis_values(spec, axis, policy) for axis in GROUP_AXES)):
                axes = {axis[1]: v for axis, v in zip(GROUP_AXES, values) if v is not None}
                runs = []
                for k in ks:
                    for combo in combos:
                        for seed in spec["seeds"]:
                            runs.append({"run": len(runs), "env": env_name, "policy": policy, **axes,
                                         "K": k, "seed": seed, **dict(zip(names, combo))})
                groups.append((env_name, policy, runs))
    return groups


def run_label(row):
    """A run's name in file and TensorBoard names: env-policy[-K<k>][-<sub-policy>][-<critic>][-<hparam>=<value>...]-s<seed>."""
    fixed = ("env", "policy", "K", "seed", "run")
    parts = [row["env"], row["policy"]] + ([f"K{row['K']}"] if row["policy"] == "mixture" else [])
    parts += [f"{c}={v}" if c not in ("subpolicy", "value_target") else str(v) for c, v in row.items() if c not in fixed and v]
    return "-".join(parts + [f"s{row['seed']}"])


def group_name(env_name, policy, runs):
    first = runs[0] if runs else {}
    return f"{env_name}-{policy}" + "".join(f"-{first[c]}" for _, c, _, _ in GROUP_AXES if first.get(c))


def group_config(spec, env_name, policy, runs):
    static = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["config"].items()}
    static.update({c: runs[0][c] for _, c, _, _ in GROUP_AXES if runs[0].get(c)})
    return Config(env=env_name, policy=policy, k_max=max(r["K"] for r in runs), **static)


def group_iterations(spec, cfg, chunk):
    iters = math.ceil(spec["steps"] / cfg.batch_size)
    return math.ceil(iters / chunk) * chunk


def group_eval_every(spec, iterations):
    """Iterations between deterministic evaluations of a group's runs (0: none); default ~25 per run."""
    return spec["eval_every"] if "eval_every" in spec else max(1, iterations // EVALUATIONS_PER_RUN)


def default_chunk(spec, cfg):
    return spec.get("chunk") or max(1, min(10, math.ceil(spec["steps"] / cfg.batch_size) // 20))


# ----------------------------------------------------------------------------------------------- files
def group_csv(runs, id_cols, metrics, upto):
    """Tidy rows (run-major) of one group's metrics [R, iters] for the first `upto` iterations (a failed
    run's rows end before its failing iteration)."""
    lines = []
    for i, r in enumerate(runs):
        ids = ",".join(str(r[c]) for c in id_cols)
        cols = [metrics[m][i] for m in TIDY_METRICS]
        for j in range(rows_before_failure(metrics, i, upto)):
            vals = []
            for m, c in zip(TIDY_METRICS, cols):
                v = c[j]
                vals.append("" if isinstance(v, float) and math.isnan(v) else (str(int(v)) if m in INTEGER_METRICS else f"{float(v):.6g}"))
            lines.append(ids + "," + ",".join(vals))
    return ",".join([tidy_name(c) for c in id_cols] + list(TIDY_METRICS)), lines


def tidy_name(column):
    """A swept hyperparameter's column in the tidy table: 'hparam_<name>' where a metric has its name (lr)."""
    return f"hparam_{column}" if column in TIDY_METRICS else column


def failed_runs(runs, metrics, upto):
    """[run dict + failed_at] of the runs that stopped at a NaN/inf."""
    failed = failed_mask(metrics, upto)
    return [{**r, "failed_at": int(metrics["failed_at"][i, upto - 1])} for i, r in enumerate(runs) if failed[i]]


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
            missing = {"failed_at": -1.0}  # a checkpoint older than a tracked metric: never failed, not evaluated
            return {k: m[k][:, :done] if k in m.files else np.full((rows, done), missing.get(k, np.nan)) for k in TRACKED}

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

    from gsa_jax.checkpoint import save_pytree

    params = jax.device_get({"params": states.params, "obs_stats": states.obs_stats})
    save_pytree(os.path.join(gdir, "params.npz"), jax.tree.map(lambda x: x[: len(runs)], params))
    write_atomic(os.path.join(gdir, "failed.json"), json.dumps(failed_runs(runs, metrics, done)))
    write_atomic(os.path.join(gdir, "DONE"), json.dumps(timing))
    for name in ("state.npz", "state.prev.npz", "metrics.prev.npz"):  # the full state is only needed to resume
        if os.path.exists(os.path.join(gdir, name)):
            os.unlink(os.path.join(gdir, name))


# ----------------------------------------------------------------------------------------------- the worker
class GroupStore:
    """The files of one group (the driver's store) in gdir: state.npz and metrics.npz after every chunk
    (each keeping its previous version); at the end params.npz, failed.json and DONE. on_chunk(runs,
    metrics [len(runs), iterations], done) runs after every save (the tidy table)."""

    def __init__(self, gdir, runs, iterations, on_chunk=None, board_dir=None):
        from gsa_jax.tensorboard import Board

        self.gdir, self.runs, self.iterations, self.on_chunk = gdir, runs, iterations, on_chunk
        self.board = Board(board_dir, [run_label(r) for r in runs]) if board_dir else None

    def load(self, template):
        from gsa_jax.tensorboard import follow

        return follow(self.board, self.load_checkpoint(template))

    def load_checkpoint(self, template):
        if not any(os.path.exists(os.path.join(self.gdir, n)) for n in ("state.npz", "state.prev.npz")):
            return None
        try:
            return load_group_checkpoint(self.gdir, template, self.iterations, warn)
        except CheckpointError as e:
            raise SpecError(f"{e} (a sweep resumes with the same --devices as the interrupted one)") from None

    def save(self, states, metrics, done):
        save_group_checkpoint(self.gdir, states, {k: metrics[k] for k in TRACKED}, done)
        if self.board:
            self.board.append(metrics, done)
        if self.on_chunk:
            self.on_chunk(self.runs, {k: v[: len(self.runs)] for k, v in metrics.items()}, done)

    def finish(self, states, metrics, done, timing):
        finish_group(self.gdir, states, self.runs, metrics, done, timing)


def finished_group(gdir, iterations):
    """The driver Result of a group whose DONE marker exists, from its metrics.npz."""
    from gsa_jax.driver import Result

    with np.load(os.path.join(gdir, "metrics.npz")) as m:
        saved = {k: m[k] for k in m.files if k != "__done__"}
    saved.setdefault("failed_at", np.full_like(saved["iteration"], -1.0))
    done = saved["iteration"].shape[1]
    return Result(done, iterations, saved, "finished" if done >= iterations else "failed", {}, done)


def run_group(spec, out, env_name, policy, runs, devices, log, stop_after_chunks=None, heartbeat=None, on_chunk=None,
              run_batch=RUN_BATCH, pad_to=0, share=None, board_dir=None):
    """Train (or resume) one group with the run driver. Returns its driver Result. pad_to: pad the runs to
    at least this many (every worker process builds the same program); share: see programs.compile_group;
    board_dir: the sweep's TensorBoard directory (None: no event files)."""
    from gsa_jax.driver import Plan, drive
    from gsa_jax.programs import group_program

    gdir = os.path.join(out, "groups", group_name(env_name, policy, runs))
    os.makedirs(gdir, exist_ok=True)
    cfg = group_config(spec, env_name, policy, runs)
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    if os.path.exists(os.path.join(gdir, "DONE")):
        return finished_group(gdir, iterations)
    cols = id_columns(spec)
    write_atomic(os.path.join(gdir, "runs.csv"), "\n".join(
        [",".join(cols)] + [",".join(str(r[c]) for c in cols) for r in runs]) + "\n")
    t0 = time.perf_counter()
    eval_every = group_eval_every(spec, iterations)
    program = group_program(cfg, chunk, devices, pad_runs(runs, len(devices), at_least=pad_to), list(spec["hparams"]),
                            iterations, run_batch, share, log, spec.get("eval_seed", 0) if eval_every else None)
    tag = group_name(env_name, policy, runs).replace(f"{env_name}-", f"{env_name}/", 1)
    log(f"[{tag}] {len(runs)} runs x {iterations} iterations x {cfg.batch_size} steps on "
        f"{len(devices)} device(s); program {program.how} ({time.perf_counter() - t0:.1f}s)")
    plan = Plan(iterations, chunk, cfg.batch_size, len(runs), eval_every, stop_after_chunks=stop_after_chunks, tag=tag)
    result = drive(program, GroupStore(gdir, runs, iterations, on_chunk, board_dir), plan, log, heartbeat, clock_start=t0)
    t = result.timing
    if t.get("eval_s"):
        log(f"[{tag}] deterministic evaluation: {t['eval_s']:.1f}s = {t['eval_s'] / max(t['train_s'] + t['eval_s'], 1e-9):.1%} "
            f"of this invocation's training and evaluation time")
    return result


def write_tidy(out, spec, results):
    """The tidy metrics.csv of out from [(runs, metrics [len(runs), iterations], done)] of its groups."""
    header, lines = None, []
    for runs, metrics, done in results:
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


def write_sweep_meta(root, spec, groups, num_processes, force, run_batch=RUN_BATCH, tensorboard=True):
    """sweep.json: spec, every run, runs per sub-batch, versions, commit (a resumed sweep must have the same
    spec, unless force)."""
    from gsa_jax.runinfo import physics_record, run_metadata

    meta_path = os.path.join(root, "sweep.json")
    if os.path.exists(meta_path):
        check_same_spec(meta_path, spec, force)
    physics = {group_name(e, p, runs): physics_record(group_config(spec, e, p, runs)) for e, p, runs in groups}
    meta = {"spec": spec, "runs": [r for _, _, runs in groups for r in runs], "num_processes": num_processes,
            "run_batch": run_batch, "tensorboard": tensorboard, "physics": physics, **run_metadata()}
    write_atomic(meta_path, json.dumps(meta, indent=1))


def run_sweep(spec, out, devices=None, quiet=False, stop_after_chunks=None, process_id=0, num_processes=1, heartbeat=None,
              run_batch=RUN_BATCH, local_workers=True, force=False, tensorboard=True):
    """Train every group of the spec (this process's share of each). Returns True when all groups are done;
    failed runs (NaN/inf) go to failed_runs.json in this process's directory; tensorboard: out/tensorboard/<run>/.
    run_batch: see programs.make_group_program. local_workers: the processes share this machine and `out`
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
        write_sweep_meta(root, spec, groups, num_processes, force, run_batch, tensorboard)
    total_runs = sum(len(r) for _, _, r in groups)
    log(f"sweep {spec['name']}: {total_runs} runs in {len(groups)} group(s) on {len(devices)} device(s)"
        + (f", process {process_id}/{num_processes}" if num_processes > 1 else "") + f" -> {out}")
    # compiled programs are kept in a cache: a resumed or restarted worker loads them; local worker
    # processes share one compile (worker 0 compiles, the others load -- gsa_jax.xla_cache)
    cache_dir, board_dir = os.path.join(root if local_workers else out, "xla_cache"), os.path.join(root, "tensorboard") if tensorboard else None
    share = (cache_dir, process_id == 0 or not local_workers)
    results, complete = [], True
    try:
        with xla_cache.enabled(cache_dir):
            for env_name, policy, runs in groups:
                mine = runs[process_id::num_processes]
                if not mine:
                    continue
                res = run_group(spec, out, env_name, policy, mine, devices, log, stop_after_chunks, heartbeat,
                                on_chunk=lambda *partial: write_tidy(out, spec, results + [partial]), run_batch=run_batch,
                                pad_to=math.ceil(len(runs) / num_processes), share=share, board_dir=board_dir)
                results.append((mine, {k: v[: len(mine)] for k, v in res.metrics.items()}, res.done))
                write_tidy(out, spec, results)
                if not res.finished:
                    complete = False
                    break
        failed = [f for runs, metrics, done in results for f in failed_runs(runs, metrics, done)]
        write_atomic(os.path.join(out, "failed_runs.json"), json.dumps(failed))
    except DiskFullError as e:
        if not hasattr(e, "last_intact"):
            runs, _, done = results[-1] if results else (None, None, None)
            e.last_intact = (f"iteration {done} of group {group_name(runs[0]['env'], runs[0]['policy'], runs)}"
                             if results else "none (nothing trained yet)")
        raise
    for f in failed:
        log(f"run failed (NaN/inf in loss or parameters) at iteration {f['failed_at']}: "
            + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "K", "seed") if k in f) + "; its metrics end there")
    for line in eval_failure_lines(results):
        log(line)
    return complete


def eval_failure_lines(results):
    """Summary lines of the evaluation episodes that failed (non-finite reward or observation; each ended
    at its last finite step, gsa_jax.episodes), per run, from [(runs, metrics, done)]; [] if none."""
    lines = []
    for runs, metrics, done in results:
        counts = metrics["eval_failures"][:, :done]
        for r, row in zip(runs, counts):
            if np.nansum(row) > 0:
                its = [i + 1 for i in np.flatnonzero(row > 0)]
                lines.append("  " + ", ".join(f"{k}={r[k]}" for k in ("env", "policy", "K", "seed") if k in r)
                             + f": {int(np.nansum(row))} episode(s) at iteration(s) {', '.join(map(str, its))}")
    if lines:
        lines.insert(0, f"evaluation episodes failed (non-finite reward or observation; scored up to their last finite "
                        f"step, counted in eval_failures) in {len(lines)} run(s):")
    return lines


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
            log("  " + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "subpolicy", "value_target", "K", "seed", "run") if k in f)
                + f": failed at iteration {f['failed_at']}")
    return failed


def build_parser():
    p = argparse.ArgumentParser(prog="python -m gsa_jax.sweep", description=__doc__.split("\n")[0])
    p.add_argument("experiment", help="experiment file (TOML), e.g. experiments/fig1_small/fig1_small.toml")
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
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/<run>/, open with tensorboard --logdir OUT)")
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


def main(argv=None, after_chunk=None):
    """Exit status: 0 done (or stopped as asked), 1 some runs failed (NaN/inf), 2 bad input or a locked /
    changed / unreadable output directory, 3 a worker hung repeatedly, 4 disk full, 130 interrupted.
    after_chunk: see run_worker."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec, out, local = check_args(args, argv)
    except SpecError as e:
        print(f"gsa_jax.sweep: error: {e}", file=sys.stderr)
        return 2
    if args.worker:
        return run_worker(args, spec, out, after_chunk)
    from gsa_jax.runlock import LockError, hold

    lock_dir = out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")
    os.makedirs(lock_dir, exist_ok=True)
    try:
        with hold(lock_dir, f"gsa_jax.sweep {spec['name']}", log=lambda m: print(m, file=sys.stderr)):
            if local > 1 or not args.no_watchdog:
                return supervise_workers(args, argv, out, local)
            return run_worker(args, spec, out, after_chunk)
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
    from gsa_jax.supervise import supervise

    cmds = [[sys.executable, "-m", "gsa_jax.sweep", *a, "--worker"] for a in argvs]
    status = supervise(cmds, dirs, args.watchdog_min, args.max_restarts)
    if status == 0:
        try:
            if report_failures(out, dirs):
                return EXIT_FAILED_RUNS
        except DiskFullError as e:
            print(f"gsa_jax.sweep: error: {e.describe('the final one of every group (training is done; only sweep.json is behind)')}", file=sys.stderr)
            return EXIT_DISK_FULL
        print(f"sweep complete: {out}", flush=True)
    return status


def run_worker(args, spec, out, after_chunk=None):
    """Train this process's share in this process (a supervised worker, or --no-watchdog). after_chunk:
    called after every chunk's heartbeat (tests inject faults with it)."""
    import jax

    from gsa_jax.supervise import heartbeat_writer

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
    beat = heartbeat_writer(wdir)

    def heartbeat(duration):
        beat(duration)
        if after_chunk:
            after_chunk()

    try:
        complete = run_sweep(spec, out, devices, args.quiet, args.stop_after_chunks, args.process_id, args.num_processes,
                             heartbeat, args.run_batch, local_workers=args.coordinator is None, force=args.force,
                             tensorboard=args.tensorboard)
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
