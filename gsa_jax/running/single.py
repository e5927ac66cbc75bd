"""One training run: its plan (RunPlan), this invocation's options (RunOptions), its store (metrics.csv,
params.npz, state.npz, config.json) and the chunk loop around it; `python -m gsa_jax.train` is its command."""

import csv
import dataclasses
import io
import json
import math
import os
import sys
import time
from typing import NamedTuple

import numpy as np

from envs import solver_settings
from envs.physics import resolve_threads
from gsa_jax.algorithm.ppo import Config
from gsa_jax.algorithm.retrace import buffer_bytes
from gsa_jax.running.checkpoint import (
    CheckpointError, DiskFullError, FormatError, load_pytree, read_with_fallback, save_pytree, write_atomic,
)
from gsa_jax.running.curve import plot_curve
from gsa_jax.running.driver import Plan, drive, duration, fmt, rows_before_failure
from gsa_jax.running.metrics import INTEGER_METRICS
from gsa_jax.running.metrics import RUN_COLUMNS as METRIC_COLUMNS
from gsa_jax.running.programs import single_program
from gsa_jax.running.runinfo import ResumeRefused, check_unchanged, physics_record, run_metadata
from gsa_jax.running.store import Store, warn


class UsageError(Exception):
    pass


class RunPlan(NamedTuple):
    """What a single run computes: its Config, hyperparameters (python numbers, K and total_iterations
    included), iterations, PPO iterations per compiled chunk, iterations between deterministic evaluations
    (0: none), the evaluation's start-state seed and the training seed."""

    cfg: Config
    hp: dict
    iterations: int
    chunk: int
    eval_every: int
    eval_seed: int
    seed: int


class RunOptions(NamedTuple):
    """How this invocation runs it: the output directory, whether to resume it (force: with changed settings),
    stop (resumably) after stop_after iterations, the command line recorded, progress lines, TensorBoard files."""

    out: str
    resume: bool = False
    force: bool = False
    stop_after: int | None = None
    argv: list | None = None
    quiet: bool = False
    tensorboard: bool = True


def rows_to_csv(rows):
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def read_rows(path):
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


RESUME_KEYS = ("config", "hparams", "seed", "iterations", "chunk")


def check_resume_config(old, config, force):
    """Refuse (ResumeRefused, one line) to resume a saved run whose settings differ, unless force. A config
    field the saved run's config.json lacks (it was written before the field existed) ran at its default."""
    mine = {k: config[k] for k in RESUME_KEYS}
    theirs = {k: old.get(k) for k in RESUME_KEYS}
    defaults = json.loads(json.dumps({f.name: f.default for f in dataclasses.fields(Config)}))
    theirs["config"] = {**{k: defaults[k] for k in mine["config"] if k in defaults}, **(theirs["config"] or {})}
    check_unchanged(theirs, mine, force, "--resume with a different run than the one in the output directory",
                    "pass --force to continue it with the new settings")


class RunStore(Store):
    """The files of a single run (the driver's store): metrics.csv, params.npz and state.npz (the
    checkpoint files keep their previous version) in `out`."""

    def __init__(self, out, config, resume):
        super().__init__(out, os.path.join(out, "tensorboard") if config.get("tensorboard") else None, [""])
        self.config, self.resume = config, resume

    def has_checkpoint(self):
        return self.resume and super().has_checkpoint()

    def load_checkpoint(self, template):
        """(state, metrics [1, done], done) of the run saved in out: state.npz, or state.prev.npz if that
        is unreadable; metrics.csv (or its previous version) cut to the state's iteration."""
        state, path = read_with_fallback(self.path("state.npz"), lambda p: load_pytree(p, template), warn)
        done = int(state.iteration)
        rows, _ = read_with_fallback(self.path("metrics.csv"), read_rows_checked, warn)
        if int(state.failed_at) >= 0:
            raise UsageError(f"the run in {self.root} stopped at a NaN/inf at iteration {int(state.failed_at)}; nothing to resume")
        rows = [r for r in rows if int(r["iteration"]) <= done]
        if len(rows) < done:
            raise UsageError(f"{self.root}: metrics.csv holds {len(rows)} iterations but {os.path.basename(path)} is at "
                             f"iteration {done}; delete the directory to start over")
        return state, rows_to_metrics(rows), done

    def save(self, state, metrics, done):
        """Metrics, parameters and state after a chunk."""
        write_atomic(self.path("metrics.csv"), rows_to_csv(metrics_to_rows(metrics, done)), keep_previous=True)
        self.save_params(state)
        save_pytree(self.path("state.npz"), state, keep_previous=True)
        self.follow_save(metrics, done)

    def save_params(self, state):
        save_pytree(self.path("params.npz"), {"params": state.params, "obs_stats": state.obs_stats},
                    **{"meta/config_json": np.array(json.dumps(self.config))})

    def finish(self, state, metrics, done, timing):
        """Nothing beyond the last chunk's files: train.finish writes the result into config.json."""


def read_rows_checked(path):
    rows = read_rows(path) if os.path.exists(path) else None
    if rows is None:
        raise OSError("missing")
    if rows and set(METRIC_COLUMNS) - set(rows[0]):
        missing = sorted(set(METRIC_COLUMNS) - set(rows[0]))
        if set(rows[0]) & set(METRIC_COLUMNS):
            raise FormatError(f"{path} was written by an older gsa_jax (no {', '.join(missing)}); continue that run with "
                              "the commit in its config.json (git_commit), or start over in another --out")
        raise ValueError("not a metrics table")
    return rows


def metrics_to_rows(metrics, done):
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


def rows_to_metrics(rows):
    """The inverse of metrics_to_rows: {name: float64 [1, len(rows)]} (a written row never failed)."""
    metrics = {k: np.array([[float(r[k]) if r.get(k, "") != "" else math.nan for r in rows]], np.float64)
               for k in METRIC_COLUMNS}
    metrics["failed_at"] = np.full((1, len(rows)), -1.0)
    return metrics


def run(plan, options):
    """Train (or resume) one run into options.out. Returns the exit status: 0, 1 (NaN/inf), 2 (bad resume),
    4 (disk full), 130 (interrupted)."""
    cfg, out = plan.cfg, options.out
    log = (lambda msg: None) if options.quiet else (lambda msg: print(msg, flush=True))
    config = {
        "config": dataclasses.asdict(cfg), "hparams": plan.hp, "seed": plan.seed, "iterations": plan.iterations,
        "chunk": plan.chunk, "eval_every": plan.eval_every, "eval_seed": plan.eval_seed,
        "env_steps": plan.iterations * cfg.batch_size, "argv": list(sys.argv[1:] if options.argv is None else options.argv),
        "tensorboard": options.tensorboard,
    }
    try:
        config_path = os.path.join(out, "config.json")
        if options.resume and os.path.exists(config_path):
            with open(config_path) as f:
                check_resume_config(json.load(f), config, options.force)
        config.update(physics=physics_record(cfg), **run_metadata())
        write_atomic(config_path, json.dumps(config, indent=2))
        return train_run(plan, options, config, log)
    except (UsageError, CheckpointError, ResumeRefused, FormatError) as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2
    except DiskFullError as e:
        intact = getattr(e, "last_intact", None) or f"iteration {saved_iteration(out)}"
        print(f"gsa_jax.train: error: {e.describe(intact)}", file=sys.stderr)
        return 4


def saved_iteration(out):
    """The iteration of the newest readable checkpoint in out (0 if none)."""
    for name in ("state.npz", "state.prev.npz"):
        try:
            with np.load(os.path.join(out, name)) as f:
                return int(f[".iteration"])
        except (OSError, KeyError, ValueError):
            continue
    return 0


def train_run(plan, options, config, log):
    """Compile (or reuse) the run's program and drive it with a RunStore; then finish. Returns the exit status."""
    cfg, out = plan.cfg, options.out
    t0 = time.perf_counter()
    program, trainer = single_program(cfg, plan.chunk, plan.seed, plan.hp, plan.eval_seed)
    log_start(plan, trainer, out, log)
    if cfg.value_target == "retrace":
        config["retrace_buffer_bytes"] = buffer_bytes(program.state.buffer)
        log(f"value targets: Retrace over the samples of the last {cfg.retrace_iterations} iterations "
            f"(buffer {config['retrace_buffer_bytes'] / 2**20:.2f} MiB)")
    log(f"compiled in {time.perf_counter() - t0:.1f}s")
    store = RunStore(out, config, options.resume)
    if not os.path.exists(store.path("params.npz")):  # the initial parameters: "last good" even if chunk 1 diverges
        store.save_params(program.state)
    stop = None if options.stop_after is None else math.ceil(options.stop_after / plan.chunk)
    drive_plan = Plan(plan.iterations, plan.chunk, cfg.batch_size, 1, plan.eval_every, mixture=cfg.policy == "mixture",
                      stop_after_chunks=stop)
    result = drive(program, store, drive_plan, log, clock_start=t0)
    status = {"failed": 1, "interrupted": 130}.get(result.status, 0)
    if result.status == "failed":
        failed_at = int(result.metrics["failed_at"][0, result.done - 1])
        print(f"gsa_jax.train: error: NaN/inf in the loss or parameters at iteration {failed_at}; stopped. "
              f"Last good parameters (iteration {failed_at - 1}) are in {store.path('params.npz')}", file=sys.stderr)
    elif result.status == "interrupted":
        print(f"\ninterrupted; everything up to iteration {result.intact} is saved in {out} "
              f"(continue with --resume --out {out})", file=sys.stderr)
    finish(plan, out, config, (metrics_to_rows(result.metrics, result.done), status, result), log)
    return status


def log_start(plan, trainer, out, log):
    """The run's first lines: task, policy, length; a changed MJX solver; the physics backend."""
    cfg, hp_py, iterations = plan.cfg, plan.hp, plan.iterations
    log(f"gsa_jax: {cfg.env} ({trainer.env.observation_size} obs, {trainer.env.action_size} actions), "
        f"{cfg.policy}" + (f" K={hp_py['K']} (k_max {cfg.k_max}, {cfg.subpolicy} sub-policies)" if cfg.policy == "mixture" else "")
        + f", {iterations} iterations x {cfg.batch_size} steps = {iterations * cfg.batch_size:,} env steps -> {out}")
    if cfg.solver_iterations is not None or cfg.ls_iterations is not None:
        sol = solver_settings(trainer.env.unwrapped)
        ls = "exact line search" if sol["linesearch_in_force"] == "exact" else f"{sol['ls_iterations'] or sol['task_ls_iterations']} line-search iterations"
        log(f"MJX solver: {sol['iterations_in_force']} iterations, {ls} (the task's own: "
            f"{sol['task_iterations']}, {sol['task_ls_iterations']}) -- a changed simulator, see experiments/solver_hopper/")
    if cfg.backend == "c":
        log(f"physics: MuJoCo C inside the program ({resolve_threads(cfg.physics_threads)} thread(s))")


def finish(plan, out, config, outcome, log):
    """Curve, timings and result into config.json; the closing line. outcome: (metrics.csv rows, exit status,
    driver Result)."""
    rows, status, result = outcome
    cfg, hp_py, seed = plan.cfg, plan.hp, plan.seed
    if rows:
        title = f"{cfg.env} - {cfg.policy}" + (f" K={hp_py['K']}" if cfg.policy == "mixture" else "") + f" - seed {seed}"
        try:
            plot_curve(rows, os.path.join(out, "curve.png"), title)
        except OSError as e:  # a figure is not worth failing a run for (e.g. a full disk)
            print(f"gsa_jax.train: warning: curve.png not written ({e.strerror or e})", file=sys.stderr)
    config["timing"] = result.timing
    last = [r for r in rows if r["episode_return"] != ""]
    config["result"] = {
        "iterations_done": result.done,
        "final_episode_return": float(last[-1]["episode_return"]) if last else None,
        "final_eval_return": next((float(r["eval_return"]) for r in reversed(rows) if r["eval_return"] != ""), None),
        "status": "nan" if status == 1 else "interrupted" if status == 130 or result.done < result.iterations else "finished",
    }
    write_atomic(os.path.join(out, "config.json"), json.dumps(config, indent=2))
    timing, res = config["timing"], config["result"]
    if status == 0 and result.done < result.iterations:
        log(f"stopped at iteration {result.done}/{result.iterations} as asked; continue with --resume --out {out}")
    elif status == 0:
        log(f"done: {timing['env_steps_run']:,} steps in {duration(timing['wall_s'])} (compile {timing['compile_s']:.1f}s, "
            f"{timing['env_steps_per_s']:,.0f} steps/s); final return {fmt(res['final_episode_return'], '.1f')}, "
            f"eval {fmt(res['final_eval_return'], '.1f')}; results in {out}")
