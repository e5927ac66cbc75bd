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
import json
import math
import os
import sys
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import numpy as np

from gsa_jax import xla_cache
from gsa_jax.checkpoint import CheckpointError, DiskFullError, FormatError, load_pytree, read_with_fallback, save_npz_atomic, save_pytree, write_atomic
from gsa_jax.driver import Plan, Result, drive, failed_mask, rows_before_failure
from gsa_jax.metrics import INTEGER_METRICS, TIDY_METRICS
from gsa_jax.programs import RUN_BATCH, GroupRuns, GroupShape, group_program, pad_runs
from gsa_jax.runinfo import ResumeRefused, check_unchanged, physics_record, run_metadata
from gsa_jax.runlock import LockError, hold
from gsa_jax.spec import Group, SpecError, build_grid, default_chunk, group_config, group_eval_every, group_iterations, group_name, load_spec, run_label
from gsa_jax.supervise import heartbeat_writer, supervise
from gsa_jax.store import Store, warn

TRACKED = TIDY_METRICS + ("failed_at",)  # per run and iteration in metrics.npz; failed_at is not a CSV column
EXIT_FAILED_RUNS, EXIT_DISK_FULL = 1, 4


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


def load_group_checkpoint(gdir, states, iterations, log):
    """(states, metrics arrays [R, iterations], done) of a group's last intact checkpoint: state.npz
    (or state.prev.npz) and the metrics covering its iteration (metrics.npz or metrics.prev.npz)."""
    def read_state(p):
        with np.load(p) as f:
            done = int(f["__done__"])
        return load_pytree(p, states), done

    (states, done), _ = read_with_fallback(os.path.join(gdir, "state.npz"), read_state, log)

    def read_metrics(p):
        with np.load(p) as m:
            if int(m["__done__"]) < done:
                raise ValueError(f"holds {int(m['__done__'])} iterations, the state {done}")
            check_format(p, m.files)
            return {k: m[k][:, :done] for k in TRACKED}

    saved, _ = read_with_fallback(os.path.join(gdir, "metrics.npz"), read_metrics, log)
    metrics = {m: np.full((saved["iteration"].shape[0], iterations), np.nan, np.float64) for m in TRACKED}
    for k in TRACKED:
        metrics[k][:, :done] = saved[k]
    return states, metrics, done


def save_group_checkpoint(gdir, states, metrics, done):
    """Metrics, then state (both keeping their previous version); the state records `done`."""
    save_npz_atomic(os.path.join(gdir, "metrics.npz"), True, __done__=np.array(done),
                    **{k: v[:, :done] for k, v in metrics.items()})
    save_pytree(os.path.join(gdir, "state.npz"), states, True, __done__=np.array(done))


def finish_group(gdir, states, runs, metrics, done, timing):
    """Final parameters (a failed run's last finite ones), failed.json and DONE; drop the resume state."""
    params = jax.device_get({"params": states.params, "obs_stats": states.obs_stats})
    save_pytree(os.path.join(gdir, "params.npz"), jax.tree.map(lambda x: x[: len(runs)], params))
    write_atomic(os.path.join(gdir, "failed.json"), json.dumps(failed_runs(runs, metrics, done)))
    write_atomic(os.path.join(gdir, "DONE"), json.dumps(timing))
    for name in ("state.npz", "state.prev.npz", "metrics.prev.npz"):  # the full state is only needed to resume
        if os.path.exists(os.path.join(gdir, name)):
            os.unlink(os.path.join(gdir, name))


# ----------------------------------------------------------------------------------------------- the worker
class GroupStore(Store):
    """The files of one group (the driver's store) in gdir: state.npz and metrics.npz after every chunk
    (each keeping its previous version); at the end params.npz, failed.json and DONE. on_chunk(runs,
    metrics [len(runs), iterations], done) runs after every save (the tidy table)."""

    def __init__(self, gdir, runs, iterations, on_chunk=None, board_dir=None):
        super().__init__(gdir, board_dir, [run_label(r) for r in runs])
        self.runs, self.iterations, self.on_chunk = runs, iterations, on_chunk

    def load_checkpoint(self, template):
        try:
            return load_group_checkpoint(self.root, template, self.iterations, warn)
        except CheckpointError as e:
            raise SpecError(f"{e} (a sweep resumes with the same --devices as the interrupted one)") from None

    def save(self, states, metrics, done):
        save_group_checkpoint(self.root, states, {k: metrics[k] for k in TRACKED}, done)
        self.follow_save(metrics, done)
        if self.on_chunk:
            self.on_chunk(self.runs, {k: v[: len(self.runs)] for k, v in metrics.items()}, done)

    def finish(self, states, metrics, done, timing):
        finish_group(self.root, states, self.runs, metrics, done, timing)


def check_format(path, names):
    """Refuse (one line) a group file written by a gsa_jax that tracked fewer metrics."""
    missing = [k for k in TRACKED if k not in names]
    if missing:
        raise FormatError(f"{path} was written by an older gsa_jax (no {', '.join(missing)}); finish that sweep with the "
                        "commit in its sweep.json (git_commit), or start over in another --out")


def finished_group(gdir, iterations):
    """The driver Result of a group whose DONE marker exists, from its metrics.npz."""
    with np.load(os.path.join(gdir, "metrics.npz")) as m:
        check_format(os.path.join(gdir, "metrics.npz"), m.files)
        saved = {k: m[k] for k in m.files if k != "__done__"}
    done = saved["iteration"].shape[1]
    return Result(done, iterations, saved, "finished" if done >= iterations else "failed", {}, done)


@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """How this process runs a sweep -- not what it computes (the spec; sweep.json records both).
    devices: () = every local device; process_id / num_processes: this process's share of each group's runs;
    heartbeat(seconds) after every chunk (the supervisor's watchdog); run_batch: see
    programs.make_group_program; local_workers: the processes share this machine and `out` (False for
    multi-host sweeps: each process compiles for itself); force: resume a changed spec."""

    devices: tuple = ()
    quiet: bool = False
    stop_after_chunks: int | None = None
    process_id: int = 0
    num_processes: int = 1
    heartbeat: Callable | None = None
    run_batch: int = RUN_BATCH
    local_workers: bool = True
    force: bool = False
    tensorboard: bool = True


class GroupContext(NamedTuple):
    """What this process brings to training one group: devices, log, options; pad_to: pad the runs to at
    least this many (every worker process builds the same program); share: see programs.compile_group;
    board_dir: the sweep's TensorBoard directory (None: no event files); on_chunk: see GroupStore."""

    devices: list
    log: Callable
    options: SweepOptions
    pad_to: int = 0
    share: tuple | None = None
    board_dir: str | None = None
    on_chunk: Callable | None = None


def run_group(spec, out, group, ctx):
    """Train (or resume) one Group (this process's runs of it) with the run driver. Returns its driver Result."""
    name = group_name(group)
    gdir = os.path.join(out, "groups", name)
    os.makedirs(gdir, exist_ok=True)
    cfg = group_config(spec, group)
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    if os.path.exists(os.path.join(gdir, "DONE")):
        return finished_group(gdir, iterations)
    cols = spec.id_columns()
    write_atomic(os.path.join(gdir, "runs.csv"), "\n".join(
        [",".join(cols)] + [",".join(str(r[c]) for c in cols) for r in group.runs]) + "\n")
    t0 = time.perf_counter()
    eval_every = group_eval_every(spec, iterations)
    shape = GroupShape(cfg, chunk, tuple(ctx.devices), ctx.options.run_batch)
    runs = pad_runs(group.runs, len(ctx.devices), at_least=ctx.pad_to)
    program = group_program(shape, GroupRuns(runs, list(spec.hparams), iterations),
                            (spec.eval_seed or 0) if eval_every else None, ctx.share, ctx.log)
    tag = name.replace(f"{group.env}-", f"{group.env}/", 1)
    ctx.log(f"[{tag}] {len(group.runs)} runs x {iterations} iterations x {cfg.batch_size} steps on "
            f"{len(ctx.devices)} device(s); program {program.how} ({time.perf_counter() - t0:.1f}s)")
    plan = Plan(iterations, chunk, cfg.batch_size, len(group.runs), eval_every,
                stop_after_chunks=ctx.options.stop_after_chunks, tag=tag)
    store = GroupStore(gdir, group.runs, iterations, ctx.on_chunk, ctx.board_dir)
    result = drive(program, store, plan, ctx.log, ctx.options.heartbeat, clock_start=t0)
    t = result.timing
    if t.get("eval_s"):
        ctx.log(f"[{tag}] deterministic evaluation: {t['eval_s']:.1f}s = {t['eval_s'] / max(t['train_s'] + t['eval_s'], 1e-9):.1%} "
                f"of this invocation's training and evaluation time")
    return result


def write_tidy(out, spec, results):
    """The tidy metrics.csv of out from [(runs, metrics [len(runs), iterations], done)] of its groups."""
    header, lines = None, []
    for runs, metrics, done in results:
        header, ls = group_csv(runs, spec.id_columns(), metrics, done)
        lines.extend(ls)
    if header:
        write_atomic(os.path.join(out, "metrics.csv"), header + "\n" + "\n".join(lines) + ("\n" if lines else ""))


def write_sweep_meta(root, spec, groups, options):
    """sweep.json: spec, every run, runs per sub-batch, versions, commit (a resumed sweep must have the same
    spec, unless options.force)."""
    meta_path = os.path.join(root, "sweep.json")
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            old = json.load(f).get("spec", {})
        check_unchanged(old, spec.to_json(), options.force,
                        f"{root} holds a sweep with a different spec", "use another --out, or --force to continue it with the new spec")
    physics = {group_name(g): physics_record(group_config(spec, g)) for g in groups}
    meta = {"spec": spec.to_json(), "runs": [r for g in groups for r in g.runs], "num_processes": options.num_processes,
            "run_batch": options.run_batch, "tensorboard": options.tensorboard, "physics": physics, **run_metadata()}
    write_atomic(meta_path, json.dumps(meta, indent=1))


def run_sweep(spec, out, options=SweepOptions()):
    """Train every group of the spec (this process's share of each). Returns True when all groups are done;
    failed runs (NaN/inf) go to failed_runs.json in this process's directory; TensorBoard: out/tensorboard/<run>/."""
    pid, nproc = options.process_id, options.num_processes
    prefix = f"[process {pid}] " if nproc > 1 else ""

    def log(msg):
        if not options.quiet:
            print(prefix + msg, flush=True)

    devices = list(options.devices or jax.local_devices())
    root, out = out, os.path.join(out, f"process-{pid}") if nproc > 1 else out
    os.makedirs(out, exist_ok=True)
    groups = build_grid(spec)
    if pid == 0:
        write_sweep_meta(root, spec, groups, options)
    log(f"sweep {spec.name}: {sum(len(g.runs) for g in groups)} runs in {len(groups)} group(s) on {len(devices)} device(s)"
        + (f", process {pid}/{nproc}" if nproc > 1 else "") + f" -> {out}")
    # compiled programs are kept in a cache: a resumed or restarted worker loads them; local worker
    # processes share one compile (worker 0 compiles, the others load -- gsa_jax.xla_cache)
    cache_dir = os.path.join(root if options.local_workers else out, "xla_cache")
    ctx = GroupContext(devices, log, options, share=(cache_dir, pid == 0 or not options.local_workers),
                       board_dir=os.path.join(root, "tensorboard") if options.tensorboard else None)
    results = []
    try:
        with xla_cache.enabled(cache_dir):
            complete = train_groups(spec, out, groups, ctx, results)
        failed = [f for runs, metrics, done in results for f in failed_runs(runs, metrics, done)]
        write_atomic(os.path.join(out, "failed_runs.json"), json.dumps(failed))
    except DiskFullError as e:
        if not hasattr(e, "last_intact"):
            runs, _, done = results[-1] if results else (None, None, None)
            e.last_intact = (f"iteration {done} of group {group_name(Group(runs[0]['env'], runs[0]['policy'], runs))}"
                             if results else "none (nothing trained yet)")
        raise
    for f in failed:
        log(f"run failed (NaN/inf in loss or parameters) at iteration {f['failed_at']}: "
            + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "K", "seed") if k in f) + "; its metrics end there")
    for line in eval_failure_lines(results):
        log(line)
    return complete


def train_groups(spec, out, groups, ctx, results):
    """Train this process's share of every group in turn, appending (runs, metrics, done) to results and
    rewriting the tidy table after every chunk. Returns False if a group stopped before its end."""
    pid, nproc = ctx.options.process_id, ctx.options.num_processes
    for group in groups:
        mine = group.runs[pid::nproc]
        if not mine:
            continue
        group_ctx = ctx._replace(pad_to=math.ceil(len(group.runs) / nproc),
                                 on_chunk=lambda *partial: write_tidy(out, spec, results + [partial]))
        res = run_group(spec, out, group._replace(runs=mine), group_ctx)
        results.append((mine, {k: v[: len(mine)] for k, v in res.metrics.items()}, res.done))
        write_tidy(out, spec, results)
        if not res.finished:
            return False
    return True


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
    lock_dir = out if args.num_processes == 1 else os.path.join(out, f"process-{args.process_id}")
    os.makedirs(lock_dir, exist_ok=True)
    try:
        with hold(lock_dir, f"gsa_jax.sweep {spec.name}", log=lambda m: print(m, file=sys.stderr)):
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
        options = SweepOptions(tuple(devices), args.quiet, args.stop_after_chunks, args.process_id, args.num_processes,
                               heartbeat, args.run_batch, local_workers=args.coordinator is None, force=args.force,
                               tensorboard=args.tensorboard)
        complete = run_sweep(spec, out, options)
    except (SpecError, ResumeRefused, FormatError) as e:
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
