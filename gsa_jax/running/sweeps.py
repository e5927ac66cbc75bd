"""A sweep's groups trained one after the other: group checkpoints (GroupStore), the tidy metrics table,
sweep.json and the failed-runs report; `gsa sweep` is its command (workers, watchdog)."""

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import numpy as np

from gsa_jax.algorithm.config import HPARAM_DEFAULTS, Config
from gsa_jax.running import xla_cache
from gsa_jax.running.checkpoint import DiskFullError, write_atomic
from gsa_jax.running.formats import read_json, refuse_trained_whole, stamped
from gsa_jax.running.driver import Plan, Result, drive, rows_before_failure
from gsa_jax.running.metrics import INTEGER_METRICS, TIDY_METRICS
from gsa_jax.running.programs import GroupRuns, GroupShape, group_program, pad_runs
from gsa_jax.running.runinfo import ResumeRefused, check_unchanged, physics_record, run_metadata
from gsa_jax.running.spec import (
    RUN_BATCH, Group, SpecError, SweepSpec, build_grid, check_spec, default_chunk, group_config, group_eval_at,
    group_eval_every, group_iterations, group_name,
)
from gsa_jax.running.tasks import task_of
from gsa_jax.running.store import GroupStore, failed_runs, finished_group, write_runs_table
from gsa_jax.running.trained import part_dir, run_label

EXIT_FAILED_RUNS = 1


# ----------------------------------------------------------------------------------------------- files
def group_csv(runs: list[dict], id_cols: list[str], metrics: dict, upto: int) -> tuple[str, list[str]]:
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


def tidy_name(column: str) -> str:
    """A swept hyperparameter's column in the tidy table: 'hparam_<name>' where a metric has its name (lr)."""
    return f"hparam_{column}" if column in TIDY_METRICS else column


# ----------------------------------------------------------------------------------------------- groups
@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """How this process runs a sweep -- not what it computes (the spec; sweep.json records both).
    devices: () = every local device; process_id / num_processes: this process's share of each group's runs;
    heartbeat(seconds) after every chunk (the supervisor's watchdog); run_batch: see
    programs.make_group_program; local_workers: the processes share this machine and `out` (False for
    multi-host sweeps: each process compiles for itself); force: resume a changed spec; runs_per_program: every program
    trains this many runs (0: a group's own count): a group of more is trained in consecutive parts of it, one call of
    the same compiled program each (program_parts), and one of fewer is padded to it, so sweeps of any size share
    one program."""

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
    runs_per_program: int = 0


class GroupContext(NamedTuple):
    """What this process brings to training one group: devices, log, options; pad_to: pad the runs to at
    least this many (every worker process builds the same program); share: see programs.compile_group;
    board_dir: the sweep's TensorBoard directory (None: no event files); on_chunk: see GroupStore; name, cfg: a part's
    directory name (program_parts) and its whole group's Config (defaults: the group's own)."""

    devices: list
    log: Callable
    options: SweepOptions
    pad_to: int = 0
    share: tuple | None = None
    board_dir: str | None = None
    on_chunk: Callable | None = None
    name: str | None = None
    cfg: Config | None = None


def program_parts(group: Group, per_program: int) -> list:
    """[(directory name, Group)] a group is trained as: itself (per_program 0), else its runs in consecutive parts of
    per_program runs, named <group>, <group>-part2, ...: each part is one call of the same compiled program."""
    name = group_name(group)
    if not per_program or len(group.runs) <= per_program:
        return [(name, group)]
    parts = [group.runs[i:i + per_program] for i in range(0, len(group.runs), per_program)]
    return [(part_dir(name, i), group._replace(runs=p)) for i, p in enumerate(parts)]


def run_group(spec: SweepSpec, out: str, group: Group, ctx: GroupContext) -> Result:
    """Train (or resume) one Group (this process's runs of it) with the run driver. Returns its driver Result."""
    name = ctx.name or group_name(group)
    gdir = os.path.join(out, "groups", name)
    os.makedirs(gdir, exist_ok=True)
    cfg = ctx.cfg or group_config(spec, group)
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    if os.path.exists(os.path.join(gdir, "DONE")):
        return finished_group(gdir, iterations)
    eval_every, eval_at = group_eval_every(spec, iterations), group_eval_at(spec, cfg.batch_size, chunk)
    write_runs_table(gdir, group.runs, spec.id_columns())
    write_group_record(gdir, spec, cfg, group.runs, (iterations, chunk, eval_every, eval_at))
    t0 = time.perf_counter()
    shape = GroupShape(cfg, chunk, tuple(ctx.devices), ctx.options.run_batch)
    runs = pad_runs(group.runs, len(ctx.devices), at_least=ctx.pad_to)
    program = group_program(shape, GroupRuns(runs, spec.run_hparam_names(), iterations),
                            (spec.eval_seed or 0) if eval_every or eval_at else None, ctx.share, ctx.log)
    tag = name.replace(f"{group.env}-", f"{group.env}/", 1)
    ctx.log(f"[{tag}] {len(group.runs)} runs x {iterations} iterations x {cfg.batch_size} steps on "
            f"{len(ctx.devices)} device(s); program {program.how} ({time.perf_counter() - t0:.1f}s)")
    plan = Plan(iterations, chunk, cfg.batch_size, len(group.runs), eval_every,
                stop_after_chunks=ctx.options.stop_after_chunks, tag=tag, eval_at=eval_at)
    store = GroupStore(gdir, group.runs, iterations, ctx.on_chunk, (ctx.board_dir, [run_label(r) for r in group.runs]))
    result = drive(program, store, plan, ctx.log, ctx.options.heartbeat, clock_start=t0)
    t = result.timing
    if t.get("eval_s"):
        ctx.log(f"[{tag}] deterministic evaluation: {t['eval_s']:.1f}s = {t['eval_s'] / max(t['train_s'] + t['eval_s'], 1e-9):.1%} "
                f"of this invocation's training and evaluation time")
    return result


def write_group_record(gdir: str, spec: SweepSpec, cfg: Config, runs: list[dict], schedule: tuple) -> None:
    """config.json of a group: what its runs compute -- the Config, iterations, chunk, evaluation schedule, each
    run's seed and full hyperparameters (gsa_jax.running.trained reads a run's settings from it), physics,
    versions and commit. schedule: (iterations, chunk, eval_every, eval_at: the iterations evaluated after, or ())."""
    iterations, chunk, eval_every, eval_at = schedule
    per_run = [{"seed": r["seed"], "hparams": {**HPARAM_DEFAULTS, **{n: r[n] for n in spec.run_hparam_names()}, "K": r["K"],
                                               "total_iterations": iterations}} for r in runs]
    evals = {"eval_every": eval_every, **({"eval_at_iterations": list(eval_at)} if eval_at else {})}
    record = {"config": dataclasses.asdict(cfg), "iterations": iterations, "chunk": chunk, **evals,
              "eval_seed": spec.eval_seed or 0, "env_steps": iterations * cfg.batch_size, "runs": per_run,
              "physics": physics_record(cfg, task_of(cfg)), "task": task_of(cfg).source(), **run_metadata()}
    write_atomic(os.path.join(gdir, "config.json"), json.dumps(stamped(record), indent=1))


def write_tidy(out: str, spec: SweepSpec, results: list[tuple]) -> None:
    """The tidy metrics.csv of out from [(runs, metrics [len(runs), iterations], done)] of its groups."""
    header, lines = None, []
    for runs, metrics, done in results:
        header, ls = group_csv(runs, spec.id_columns(), metrics, done)
        lines.extend(ls)
    if header:
        write_atomic(os.path.join(out, "metrics.csv"), header + "\n" + "\n".join(lines) + ("\n" if lines else ""))


def recorded_spec(raw: dict) -> dict:
    """sweep.json's spec as this version writes it (check_spec: what the file left out at its defaults), for
    comparing with the experiment file; as recorded where it no longer checks."""
    try:
        return check_spec(raw).to_json()
    except SpecError:
        return raw


def check_resumable(root: str, spec: SweepSpec, tasks: dict, options: SweepOptions) -> None:
    """Nothing, or ResumeRefused where root/sweep.json holds another sweep: another spec or task code (unless
    options.force), or other runs per program (even with force: parts are directories, so another N would train
    runs again). Read-only: the supervisor checks before it starts the workers, process 0 before it writes."""
    meta_path = os.path.join(root, "sweep.json")
    if not os.path.exists(meta_path):
        return
    old = read_json(meta_path, "sweep")
    refuse_trained_whole(old, root, ResumeRefused)
    check_unchanged({"spec": recorded_spec(old.get("spec", {})), "tasks": old.get("tasks", tasks)},
                    {"spec": spec.to_json(), "tasks": tasks},
                    options.force, f"{root} holds a sweep with a different spec or task code",
                    "use another --out, or --force to continue it with the new spec")
    before = int(old["runs_per_program"])
    if before != options.runs_per_program:
        raise ResumeRefused(f"{root} holds a sweep trained with --runs-per-program {before}, not "
                            f"{options.runs_per_program}: resume it with {before} (or --resume {root} alone), "
                            "or use another --out")


def spec_tasks(spec: SweepSpec, groups: list[Group]) -> tuple:
    """({group name: Config}, {env: its task's source record}) of a sweep's groups."""
    configs = {group_name(g): group_config(spec, g) for g in groups}
    sources = {cfg.env: task_of(cfg).source() for cfg in configs.values()}
    return configs, {e: sources[e] for e in spec.envs if e in sources}


def write_sweep_meta(root: str, spec: SweepSpec, groups: list[Group], options: SweepOptions) -> None:
    """sweep.json: spec, every run, runs per sub-batch and per program, versions, commit (a resumed sweep must be
    the same: check_resumable)."""
    configs, tasks = spec_tasks(spec, groups)
    check_resumable(root, spec, tasks, options)
    physics = {name: physics_record(cfg, task_of(cfg)) for name, cfg in configs.items()}
    meta = {"spec": spec.to_json(), "runs": [r for g in groups for r in g.runs], "num_processes": options.num_processes,
            "run_batch": options.run_batch, "tensorboard": options.tensorboard, "runs_per_program": options.runs_per_program,
            "physics": physics, "tasks": tasks, **run_metadata()}
    write_atomic(os.path.join(root, "sweep.json"), json.dumps(stamped(meta), indent=1))


def run_sweep(spec: SweepSpec, out: str, options: SweepOptions = SweepOptions()) -> bool:
    """Train every group of the spec (this process's share of each). Returns True when all groups are done;
    failed runs (NaN/inf) go to failed_runs.json in this process's directory; TensorBoard: out/tensorboard/<run>/.

    spec: an experiment file, checked (gsa_jax.running.spec.load_spec); out: the sweep directory (a directory that
    holds this sweep is resumed); options: devices, processes, chunking, progress (SweepOptions)."""
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
    # processes share one compile (worker 0 compiles, the others load -- gsa_jax.running.xla_cache)
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


def train_groups(spec: SweepSpec, out: str, groups: list[Group], ctx: GroupContext, results: list[tuple]) -> bool:
    """Train this process's share of every group in turn, appending (runs, metrics, done) to results and
    rewriting the tidy table after every chunk. Returns False if a group stopped before its end."""
    pid, nproc = ctx.options.process_id, ctx.options.num_processes
    per_program = ctx.options.runs_per_program
    for group, (name, part) in ((g, p) for g in groups for p in program_parts(g, per_program)):
        mine = part.runs[pid::nproc]
        if not mine:
            continue
        group_ctx = ctx._replace(pad_to=math.ceil(max(len(part.runs), per_program) / nproc), name=name,
                                 cfg=group_config(spec, group),
                                 on_chunk=lambda *partial: write_tidy(out, spec, results + [partial]))
        res = run_group(spec, out, part._replace(runs=mine), group_ctx)
        results.append((mine, {k: v[: len(mine)] for k, v in res.metrics.items()}, res.done))
        write_tidy(out, spec, results)
        if not res.finished:
            return False
    return True


def eval_failure_lines(results: list[tuple]) -> list[str]:
    """Summary lines of the evaluation episodes that failed (non-finite reward or observation; each ended
    at its last finite step, gsa_jax.algorithm.episodes), per run, from [(runs, metrics, done)]; [] if none."""
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


def report_failures(root: str, dirs: list[str], log: Callable = print) -> list[dict]:
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
            log("  " + ", ".join(f"{k}={f[k]}" for k in ("env", "policy", "subpolicy", "partition", "value_target", "K", "seed", "run") if k in f)
                + f": failed at iteration {f['failed_at']}")
    return failed
