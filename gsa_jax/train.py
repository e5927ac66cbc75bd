"""Train one policy: `python -m gsa_jax.train [--env NAME] [--policy mixture|mlp] [--clusters K] [--steps N] ...`

Writes to --out (default runs/<env>-<policy>[-K<k>]-s<seed>-<time>/):
  config.json   resolved config, hyperparameters, versions, git commit (and timings once finished)
  metrics.csv   one row per PPO iteration (env_steps, episode_return, eval_return, epsilon, sigma_min, ...)
  params.npz    final parameters (policy, value, observation-normalizer statistics), updated after every chunk
  state.npz     full training state, for --resume after an interruption
  curve.png     the learning curve
Training runs as compiled chunks of iterations; between chunks the CLI logs, evaluates and saves.
"""

import argparse
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

import envs
from envs import solver_settings
from envs.physics import resolve_threads
from gsa_jax.checkpoint import CheckpointError, DiskFullError, FormatError, load_pytree, read_with_fallback, save_pytree, write_atomic
from gsa_jax.curve import plot_curve
from gsa_jax.driver import Plan, drive, duration, fmt, rows_before_failure
from gsa_jax.metrics import EVALUATIONS_PER_RUN, INTEGER_METRICS
from gsa_jax.metrics import RUN_COLUMNS as METRIC_COLUMNS
from gsa_jax.policies import SUBPOLICY_KINDS
from gsa_jax.ppo import HPARAM_DEFAULTS, Config, make_hparams, validate_hparams
from gsa_jax.programs import single_program
from gsa_jax.retrace import VALUE_TARGETS, buffer_bytes
from gsa_jax.runinfo import ResumeRefused, check_unchanged, physics_record, run_metadata
from gsa_jax.runlock import LockError, hold
from gsa_jax.store import Store, warn

_HP_FLAGS = {  # CLI flag -> hparam name
    "lr": "lr", "clip": "clip_eps", "gamma": "gamma", "gae_lambda": "gae_lambda", "vf_coef": "vf_coef",
    "max_grad_norm": "max_grad_norm", "eps_init": "eps_init", "eps_decay": "eps_decay",
    "sigma_min_init": "sigma_min_init", "sigma_min_decay": "sigma_min_decay", "sigma_init_scale": "sigma_init_scale",
}


class UsageError(Exception):
    pass


def build_parser():
    p = argparse.ArgumentParser(prog="python -m gsa_jax.train", description=__doc__.split("\n")[0])
    p.add_argument("--env", default="inverted_double_pendulum", help=f"one of: {', '.join(envs.NAMES)}")
    p.add_argument("--policy", default="mixture", help="mixture (of linear controllers) or mlp (flat PPO baseline)")
    p.add_argument("--clusters", "-K", type=int, default=4, help="K, number of linear controllers (mixture)")
    p.add_argument("--subpolicy", default="linear",
                   help="sub-policy class of a mixture: constant (one action per cluster), linear (default), quadratic")
    p.add_argument("--k-max", type=int, default=None, help="pad the cluster axis to this size (default: K)")
    p.add_argument("--steps", type=int, default=1_000_000, help="environment steps (rounded up to whole chunks)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="output directory (default: runs/<env>-<policy>-...)")
    p.add_argument("--resume", action="store_true", help="continue the run saved in --out")
    p.add_argument("--force", action="store_true", help="with --resume: continue even if the settings differ from the saved run's")
    p.add_argument("--num-envs", type=int, default=Config.num_envs)
    p.add_argument("--unroll-length", type=int, default=Config.unroll_length)
    p.add_argument("--epochs", type=int, default=Config.num_epochs)
    p.add_argument("--minibatches", type=int, default=Config.num_minibatches)
    p.add_argument("--episode-length", type=int, default=None, help="time limit in steps (default: the task's own)")
    p.add_argument("--solver-iterations", type=int, default=None,
                   help="MJX constraint-solver iterations (default: the task's own; hopper 4). Fewer is faster but a "
                        "changed simulator -- see experiments/solver_hopper/")
    p.add_argument("--ls-iterations", type=int, default=None,
                   help="MJX line-search iterations per solver iteration (default: the task's own; hopper 50)")
    p.add_argument("--linesearch", default=Config.linesearch, choices=("exact", "iterative"),
                   help="MJX solver line search: exact where the model allows it (default), or MJX's iterative one")
    p.add_argument("--cholesky", default=Config.cholesky, choices=("unrolled", "lapack"),
                   help="MJX's small Cholesky factorizations: unrolled elementwise ops (default) or LAPACK")
    p.add_argument("--physics", default=Config.backend, choices=("mjx", "c"),
                   help="physics backend: MJX (default; what accelerators run) or MuJoCo C stepped from inside the "
                        "compiled program (the CPU speed path; hopper, walker2d, halfcheetah, ant, allegro_cylinder)")
    p.add_argument("--physics-threads", type=int, default=Config.physics_threads,
                   help="--physics c: MuJoCo C threads in this process (default 0: its share of the cores)")
    p.add_argument("--value-target", default=Config.value_target,
                   help=f"the value function's targets, one of {', '.join(VALUE_TARGETS)}: GAE(lambda) on each "
                        "iteration's samples (default), or Retrace "
                        "over the samples of the last --retrace-iterations iterations (the paper's critic)")
    p.add_argument("--retrace-iterations", type=int, default=Config.retrace_iterations,
                   help="iterations of samples the Retrace critic is fitted on (default %(default)s)")
    p.add_argument("--b-init-scale", type=float, default=Config.b_init_scale, help="initial biases spread over [-s, s]^d_a")
    for flag, name in _HP_FLAGS.items():
        p.add_argument("--" + flag.replace("_", "-"), type=float, default=HPARAM_DEFAULTS[name], dest=flag)
    p.add_argument("--no-anneal-lr", action="store_true", help="keep the learning rate constant")
    p.add_argument("--no-normalize-reward", action="store_true", help="train on raw rewards")
    p.add_argument("--eval-every", type=int, default=None,
                   help="iterations between deterministic evaluations (0: none; default ~25 per run)")
    p.add_argument("--eval-seed", type=int, default=0,
                   help="evaluation start states: the same for every training seed (default 0)")
    p.add_argument("--eval-envs", type=int, default=Config.eval_envs)
    p.add_argument("--chunk", type=int, default=None, help="PPO iterations per compiled chunk (default: auto)")
    p.add_argument("--stop-after", type=int, default=None,
                   help="stop (resumably) after this many iterations in this invocation; continue with --resume")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/, open with tensorboard --logdir OUT)")
    return p


def make_config(args, k_max):
    """The run's validated Config; a bad field is a UsageError naming its flag."""
    cfg = Config(
        env=args.env, policy=args.policy, subpolicy=args.subpolicy, k_max=max(k_max, 1), num_envs=args.num_envs,
        unroll_length=args.unroll_length, num_epochs=args.epochs, num_minibatches=args.minibatches,
        episode_length=args.episode_length, normalize_reward=not args.no_normalize_reward,
        b_init_scale=args.b_init_scale, eval_envs=args.eval_envs,
        solver_iterations=args.solver_iterations, ls_iterations=args.ls_iterations, linesearch=args.linesearch,
        cholesky=args.cholesky, value_target=args.value_target, retrace_iterations=args.retrace_iterations,
        backend=args.physics, physics_threads=args.physics_threads,
    )
    try:
        return cfg.validate()
    except ValueError as e:
        msg = str(e)
        for field, flag in (("num_envs", "--num-envs"), ("num_minibatches", "--minibatches"),
                            ("solver_iterations", "--solver-iterations"), ("ls_iterations", "--ls-iterations"),
                            ("retrace_iterations", "--retrace-iterations"), ("value_target", "--value-target"),
                            ("backend", "--physics"), ("threads", "--physics-threads")):
            msg = msg.replace(field, flag)
        raise UsageError(msg) from None


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


def resolve(args):
    """Check every argument and return the RunPlan. No compiling."""
    if args.policy not in ("mixture", "mlp"):
        raise UsageError(f"unknown --policy {args.policy!r}; choose mixture or mlp")
    if args.steps <= 0:
        raise UsageError(f"--steps must be positive, got {args.steps}")
    k = args.clusters if args.policy == "mixture" else 1
    k_max = args.k_max if args.k_max is not None else k
    if args.policy == "mixture" and k < 1:
        raise UsageError(f"--clusters must be >= 1, got {k}")
    if args.policy == "mixture" and k > k_max:
        raise UsageError(f"--clusters {k} exceeds --k-max {k_max}; use 1 <= K <= k_max")
    if args.subpolicy not in SUBPOLICY_KINDS:
        raise UsageError(f"unknown --subpolicy {args.subpolicy!r}; choose one of {', '.join(SUBPOLICY_KINDS)}")
    if args.policy != "mixture" and args.subpolicy != "linear":
        raise UsageError("--subpolicy applies to --policy mixture only")
    cfg = make_config(args, k_max)
    iterations = math.ceil(args.steps / cfg.batch_size)
    chunk = args.chunk if args.chunk is not None else max(1, min(10, iterations // 20))
    if chunk < 1:
        raise UsageError(f"--chunk must be >= 1, got {chunk}")
    iterations = math.ceil(iterations / chunk) * chunk
    hp = {name: getattr(args, flag) for flag, name in _HP_FLAGS.items()}
    hp.update(K=k, total_iterations=iterations, anneal_lr=0.0 if args.no_anneal_lr else 1.0)
    try:
        validate_hparams(cfg, make_hparams(**hp))
    except ValueError as e:
        raise UsageError(str(e).replace("clusters K", "--clusters")) from None
    eval_every = args.eval_every if args.eval_every is not None else max(1, iterations // EVALUATIONS_PER_RUN)
    if eval_every < 0:
        raise UsageError(f"--eval-every must be >= 0, got {eval_every}")
    if args.eval_seed < 0:
        raise UsageError(f"--eval-seed must be >= 0, got {args.eval_seed}")
    if args.stop_after is not None and args.stop_after < 1:
        raise UsageError(f"--stop-after must be >= 1, got {args.stop_after}")
    return RunPlan(cfg, hp, iterations, chunk, eval_every, args.eval_seed, args.seed)


def default_out(cfg, hp, seed):
    tag = f"{cfg.env}-{cfg.policy}" + (f"-K{hp['K']}" if cfg.policy == "mixture" else "")
    tag += f"-{cfg.subpolicy}" if cfg.policy == "mixture" and cfg.subpolicy != "linear" else ""
    tag += "-retrace" if cfg.value_target == "retrace" else ""
    return os.path.join("runs", f"{tag}-s{seed}-{time.strftime('%Y%m%d-%H%M%S')}")


def prepare_out(out, resume):
    """Create --out and prove it is writable, before anything compiles."""
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, ".write_test")
        with open(probe, "w") as f:
            f.write("ok")
        os.unlink(probe)
    except OSError as e:
        raise UsageError(f"--out {out!r} is not writable: {e.strerror or e}") from None
    has_run = any(os.path.exists(os.path.join(out, n)) for n in ("state.npz", "state.prev.npz"))
    if has_run and not resume:
        raise UsageError(f"--out {out!r} already holds a run; pass --resume to continue it or choose another --out")


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


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        envs.check_name(args.env)
        plan = resolve(args)
        out = args.out or default_out(plan.cfg, plan.hp, plan.seed)
        prepare_out(out, args.resume)
    except (UsageError, ValueError) as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2
    try:
        with hold(out, "gsa_jax.train", log=lambda m: print(m, file=sys.stderr)):
            return run(plan, RunOptions(out, args.resume, args.force, args.stop_after, argv, args.quiet, args.tensorboard))
    except LockError as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2


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


if __name__ == "__main__":
    sys.exit(main())
