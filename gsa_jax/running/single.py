"""One training run: its plan (RunPlan), this invocation's options (RunOptions) and the chunk loop around it;
`gsa train` (gsa_jax.commands.train) is its command, which prints how it ended. The run is stored as a group of one (gsa_jax.running.store: runs.csv,
metrics.npz, state.npz, params.npz, DONE), with its own config.json, metrics.csv (one row per iteration, a view
of metrics.npz rewritten after every chunk) and curve.png."""

import csv
import dataclasses
import io
import json
import math
import os
import sys
import time
from typing import Any, Callable, NamedTuple

import numpy as np

from envs import solver_settings
from envs.families.record import TaskRecord
from envs.physics import C, resolve_threads
from gsa_jax.algorithm.config import Config, config_record
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.algorithm.run_parts import Trainer
from gsa_jax.algorithm.retrace import buffer_bytes
from gsa_jax.running.checkpoint import DiskFullError, write_atomic
from gsa_jax.running.curve import plot_curve
from gsa_jax.running.driver import Plan, drive, failed_mask, rows_before_failure
from gsa_jax.running.metrics import INTEGER_METRICS
from gsa_jax.running.metrics import RUN_COLUMNS as METRIC_COLUMNS
from gsa_jax.running.programs import single_program
from gsa_jax.running.runinfo import ResumeRefused, check_unchanged, physics_record, run_metadata
from gsa_jax.running.store import GroupStore, write_runs_table
from gsa_jax.running.formats import check_run_directory, read_json, stamped


class RunPlan(NamedTuple):
    """What a single run computes: its Config, hyperparameters (python numbers, K and total_iterations
    included), iterations, PPO iterations per compiled chunk, iterations between deterministic evaluations
    (0: none), the evaluation's start-state seed, the training seed and the task's record (resolved once, by the
    command that read the task's name)."""

    cfg: Config
    hp: dict
    iterations: int
    chunk: int
    eval_every: int
    eval_seed: int
    seed: int
    task: TaskRecord


class RunOptions(NamedTuple):
    """How this invocation runs it: the output directory, whether to resume it (force: with changed settings),
    stop (resumably) after stop_after iterations, the command line recorded, TensorBoard files."""

    out: str
    resume: bool = False
    force: bool = False
    stop_after: int | None = None
    argv: list | None = None
    tensorboard: bool = True


class RunEnd(NamedTuple):
    """How an invocation of a run ended: the driver's result (None: the run had already ended, nothing was
    trained) and the run's config.json record (its timing and result once trained)."""

    result: Any
    config: dict


def rows_to_csv(rows: list) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


RESUME_KEYS = ("config", "hparams", "seed", "iterations", "chunk", "eval_every", "eval_seed")


def check_resume_config(old: dict, config: dict, force: bool, source: dict) -> None:
    """Refuse (ResumeRefused, one line) to resume a saved run whose settings or task code (the sha256 of the file
    that defines a task of the user's) differ, unless force. A config field the saved run's config.json lacks (it
    was written before the field existed) ran at its default; a setting it lacks is not compared. source: the task's
    source as it is now (TaskRecord.source())."""
    mine = {k: config[k] for k in RESUME_KEYS if k in old}
    theirs = {k: old.get(k) for k in RESUME_KEYS if k in old}
    if "task" in old:
        mine["task"], theirs["task"] = source, old["task"]
    theirs["config"] = config_record(theirs["config"] or {})
    check_unchanged(theirs, mine, force, "--resume with a different run than the one in the output directory",
                    "pass --force to continue it with the new settings")


RUN_ID_COLUMNS = ("env", "policy", "K", "seed")  # a run directory's runs.csv


def run_row(plan: RunPlan) -> dict:
    """The run's row in runs.csv."""
    return {"env": plan.cfg.env, "policy": plan.cfg.policy, "K": plan.hp["K"], "seed": plan.seed}


def run_store(plan: RunPlan, options: RunOptions, config: dict, warn: Callable) -> GroupStore:
    """The run's GroupStore (a group of one) in options.out; after every chunk it rewrites metrics.csv from
    the metrics, at the end it records the result in config.json."""
    metrics_csv = os.path.join(options.out, "metrics.csv")

    def write_table(runs, metrics, done):
        write_atomic(metrics_csv, rows_to_csv(metrics_to_rows(metrics, done)))

    def write_result(metrics, done, timing):
        status = "nan" if failed_mask(metrics, done)[0] else "finished"
        record_result(plan, options.out, config, (metrics, done, timing, status), warn)

    board = (os.path.join(options.out, "tensorboard"), [""]) if options.tensorboard else None
    return GroupStore(options.out, [run_row(plan)], plan.iterations, write_table, board, write_result)


def metrics_to_rows(metrics: dict, done: int) -> list:
    """metrics.csv rows (dicts) of the single run in the driver's metrics {name: [1, iterations]}: the
    first `done` iterations, ending before a failing iteration; NaN as an empty cell."""
    rows = []
    for j in range(rows_before_failure(metrics, 0, done)):
        row = {}
        for k in METRIC_COLUMNS:
            v = float(metrics[k][0, j])
            row[k] = "" if math.isnan(v) else (int(v) if k in INTEGER_METRICS else v)
        rows.append(row)
    return rows


def run(plan: RunPlan, options: RunOptions, log: Callable, warn: Callable) -> RunEnd:
    """Train (or resume) one run into options.out; log: its progress lines, warn: what it could not write but
    went on without. Raises a UserError for a run it cannot continue, and a DiskFullError (with last_intact, the
    newest intact checkpoint) where the disk is full."""
    cfg, out = plan.cfg, options.out
    config = {
        "config": dataclasses.asdict(cfg), "hparams": plan.hp, "seed": plan.seed, "iterations": plan.iterations,
        "chunk": plan.chunk, "eval_every": plan.eval_every, "eval_seed": plan.eval_seed,
        "env_steps": plan.iterations * cfg.batch_size, "argv": list(sys.argv[1:] if options.argv is None else options.argv),
        "tensorboard": options.tensorboard,
    }
    try:
        config_path = os.path.join(out, "config.json")
        if options.resume and os.path.exists(config_path):
            check_run_directory(out)
            check_resume_config(read_json(config_path, "run"), config, options.force, plan.task.source())
            if os.path.exists(os.path.join(out, "DONE")):
                return RunEnd(report_ended(out, log), config)
        config.update(physics=physics_record(cfg, plan.task), task=plan.task.source(), **run_metadata())
        write_runs_table(out, [run_row(plan)], RUN_ID_COLUMNS)  # first: it marks the directory's layout
        write_atomic(config_path, json.dumps(stamped(config), indent=2))
        return RunEnd(train_run(plan, options, config, (log, warn)), config)
    except DiskFullError as e:  # the command says so; the newest intact checkpoint goes with it
        e.last_intact = getattr(e, "last_intact", None) or f"iteration {saved_iteration(out)}"
        raise


def report_ended(out: str, log: Callable) -> None:
    """--resume of a run that has ended: nothing to train (a finished run is logged; a run stopped by a NaN/inf
    is refused: ResumeRefused)."""
    with open(os.path.join(out, "failed.json")) as f:
        failed = json.load(f)
    if failed:
        raise ResumeRefused(f"the run in {out} stopped at a NaN/inf at iteration {failed[0]['failed_at']}; nothing to resume")
    log(f"the run in {out} is finished; nothing to resume")


def saved_iteration(out: str) -> int:
    """The iteration of the newest readable checkpoint in out (0 if none)."""
    for name in ("state.npz", "state.prev.npz"):
        try:
            with np.load(os.path.join(out, name)) as f:
                return int(f["__done__"])
        except (OSError, KeyError, ValueError):
            continue
    return 0


def train_run(plan: RunPlan, options: RunOptions, config: dict, outputs: tuple) -> Any:
    """Compile (or reuse) the run's program and drive it with its store; then finish. outputs: (log, warn).
    Returns the driver's result."""
    (log, warn), cfg, out = outputs, plan.cfg, options.out
    t0 = time.perf_counter()
    program, trainer = single_program(cfg, plan.chunk, plan.seed, plan.hp, plan.eval_seed, plan.eval_every > 0, plan.task)
    log_start(plan, trainer, out, log)
    if cfg.value_target == "retrace":
        config["retrace_buffer_bytes"] = buffer_bytes(program.state.buffer)
        log(f"value targets: Retrace over the samples of the last {cfg.retrace_iterations} iterations "
            f"(buffer {config['retrace_buffer_bytes'] / 2**20:.2f} MiB)")
    log(f"compiled in {time.perf_counter() - t0:.1f}s")
    store = run_store(plan, options, config, warn)
    stop = None if options.stop_after is None else math.ceil(options.stop_after / plan.chunk)
    drive_plan = Plan(plan.iterations, plan.chunk, cfg.batch_size, 1, plan.eval_every, mixture=cfg.policy == MIXTURE,
                      stop_after_chunks=stop)
    result = drive(program, store, drive_plan, log, clock_start=t0)
    if not result.finished:  # stopped as asked or interrupted: the store recorded no result
        record_result(plan, out, config, (result.metrics, result.done, result.timing, "interrupted"), warn)
    return result


def log_start(plan: RunPlan, trainer: Trainer, out: str, log: Callable) -> None:
    """The run's first lines: task, policy, length; a changed MJX solver; the physics backend."""
    cfg, hp_py, iterations = plan.cfg, plan.hp, plan.iterations
    log(f"gsa_jax: {cfg.env} ({trainer.env.observation_size} obs, {trainer.env.action_size} actions), "
        f"{cfg.policy}" + (f" K={hp_py['K']} (k_max {cfg.k_max}, {cfg.subpolicy} sub-policies, {cfg.partition} "
                           "partition)" if cfg.policy == MIXTURE else "")
        + f", {iterations} iterations x {cfg.batch_size} steps = {iterations * cfg.batch_size:,} env steps -> {out}")
    if cfg.physics.solver_iterations is not None or cfg.physics.ls_iterations is not None:
        sol = solver_settings(trainer.env.unwrapped)
        ls = "exact line search" if sol["linesearch_in_force"] == "exact" else f"{sol['ls_iterations'] or sol['task_ls_iterations']} line-search iterations"
        log(f"MJX solver: {sol['iterations_in_force']} iterations, {ls} (the task's own: "
            f"{sol['task_iterations']}, {sol['task_ls_iterations']}) -- a changed simulator, see experiments/solver_hopper/")
    if cfg.physics.backend == C:
        log(f"physics: MuJoCo C inside the program ({resolve_threads(cfg.physics.threads)} thread(s))")


def record_result(plan: RunPlan, out: str, config: dict, ended: tuple, warn: Callable) -> None:
    """The learning curve, and the timings and result into config.json. ended: (metrics [1, iterations], done,
    driver timing, status: 'finished', 'nan' or 'interrupted'); warn: told when the curve cannot be written."""
    metrics, done, timing, status = ended
    rows = metrics_to_rows(metrics, done)
    cfg, hp_py = plan.cfg, plan.hp
    if rows:
        title = f"{cfg.env} - {cfg.policy}" + (f" K={hp_py['K']}" if cfg.policy == MIXTURE else "") + f" - seed {plan.seed}"
        try:
            plot_curve(rows, os.path.join(out, "curve.png"), title)
        except OSError as e:  # a figure is not worth failing a run for (e.g. a full disk)
            warn(f"curve.png not written ({e.strerror or e})")
    last = [r for r in rows if r["episode_return"] != ""]
    evals = [r for r in rows if r["eval_return"] != ""]
    config["timing"] = timing
    config["result"] = {
        "iterations_done": done,
        "final_episode_return": float(last[-1]["episode_return"]) if last else None,
        "final_episode_return_iteration": int(last[-1]["iteration"]) if last else None,
        "final_eval_return": float(evals[-1]["eval_return"]) if evals else None,
        "final_eval_return_iteration": int(evals[-1]["iteration"]) if evals else None,
        "status": status,
    }
    write_atomic(os.path.join(out, "config.json"), json.dumps(stamped(config), indent=2))
