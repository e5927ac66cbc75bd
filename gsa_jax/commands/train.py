"""Train one policy (`gsa train [--env NAME] [--policy mixture|mlp] [--clusters K] [--steps N] ...`).

Writes to --out (default runs/<env>-<policy>[-K<k>]-s<seed>-<time>/):
  config.json   resolved config, hyperparameters, versions, git commit (and timings once finished)
  metrics.csv   one row per PPO iteration (env_steps, episode_return, eval_return, epsilon, sigma_min, ...)
  params.npz    parameters (policy, value, observation-normalizer statistics), [1, ...]: updated after every chunk
  curve.png     the learning curve
and what makes it resumable, the same files as a sweep's group of runs (gsa_jax.running.store; the run is a
group of one): runs.csv, metrics.npz and state.npz (dropped once finished), failed.json and DONE at the end.
Training runs as compiled chunks of iterations; between chunks the command logs, evaluates and saves. The compiled
programs are kept in JAX's persistent compilation cache (JAX_COMPILATION_CACHE_DIR, else ~/.cache/gsa_jax/xla;
gsa_jax.running.xla_cache): an identical second invocation loads them instead of compiling.
Exit status: 0 done (or stopped as asked), 1 stopped at a NaN/inf, 2 bad input, 4 disk full, 130 interrupted.
"""

import argparse
import math
import os
import sys
import time
from typing import TYPE_CHECKING, Any, Callable

import envs
from envs.families.record import TaskRecord
from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.config import (
    Config, add_options, config_record, flag_names, for_task, make_hparams, options_config, options_hparams,
    saved_option_values, validate_hparams,
)
from gsa_jax.algorithm.kinds import MIXTURE, MLP, POLICY_KINDS
from gsa_jax.algorithm.subpolicies import SUBPOLICY_KINDS
from gsa_jax.commands.command_line import command_parser, options_over_saved, whole_number
from gsa_jax.errors import UserError, disk_full, run_command
from gsa_jax.running.checkpoint import DiskFullError
from gsa_jax.running.driver import duration, fmt
from gsa_jax.running.metrics import EVALUATIONS_PER_RUN
from gsa_jax.running.runinfo import resume_command
from gsa_jax.running.runlock import hold
from gsa_jax.running.trained import path_part

if TYPE_CHECKING:  # the modules that load JAX are imported where they are used: `gsa train --help` loads no JAX
    from gsa_jax.running.single import RunPlan


class UsageError(UserError):
    """A command line of `gsa train` that cannot run (one line)."""

def build_parser() -> argparse.ArgumentParser:
    """`gsa train`'s options."""
    p = command_parser("train", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    add_options(p)
    p.add_argument("--steps", type=whole_number, default=1_000_000,
                   help="environment steps to train (rounded up to whole chunks; default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="training seed: initial parameters, start states and every random draw (default %(default)s)")
    p.add_argument("--out", default=None, help="output directory (default: runs/<env>-<policy>-...)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run saved in --out with its saved settings; an option given with it must "
                        "match the saved run's (or --force)")
    p.add_argument("--force", action="store_true", help="with --resume: continue with the options given even where they differ from the saved run's")
    p.add_argument("--eval-every", type=int, default=None,
                   help="iterations between deterministic evaluations (0: none; default ~25 per run)")
    p.add_argument("--eval-seed", type=int, default=0,
                   help="evaluation start states: the same for every training seed (default 0)")
    p.add_argument("--chunk", type=int, default=None, help="PPO iterations per compiled chunk (default: auto)")
    p.add_argument("--stop-after", type=whole_number, default=None,
                   help="stop (resumably) after this many iterations in this invocation; continue with --resume "
                        "(default: train to the end)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/, open with tensorboard --logdir OUT)")
    return p


def make_config(args: argparse.Namespace, k_max: int, task: TaskRecord) -> Config:
    """The run's validated Config on `task` (its record); a bad field is a UsageError naming its flag."""
    try:
        return for_task(options_config(args, k_max=max(k_max, 1)), task).validate(task)
    except ValueError as e:
        raise UsageError(flag_names(str(e))) from None


def resolve(args: argparse.Namespace) -> "RunPlan":
    """Check every argument and return the RunPlan. No compiling. The one lookup of --env: everything below is
    handed the task's record (plan.task)."""
    from gsa_jax.running.single import RunPlan

    task = envs.resolve(args.env)
    envs.check_task(task)
    if args.policy not in POLICY_KINDS:
        raise UsageError(f"unknown --policy {args.policy!r}; choose mixture or mlp")
    if args.steps <= 0:
        raise UsageError(f"--steps must be positive, got {args.steps}")
    k = args.clusters if args.policy == MIXTURE else 1
    k_max = args.k_max if args.k_max is not None else k
    if args.policy == MIXTURE and k < 1:
        raise UsageError(f"--clusters must be >= 1, got {k}")
    if args.policy == MIXTURE and k > k_max:
        raise UsageError(f"--clusters {k} exceeds --k-max {k_max}; use 1 <= K <= k_max")
    if args.subpolicy not in SUBPOLICY_KINDS:
        raise UsageError(f"unknown --subpolicy {args.subpolicy!r}; choose one of {', '.join(SUBPOLICY_KINDS)}")
    if args.policy != MIXTURE and args.subpolicy != subpolicies.DEFAULT:
        raise UsageError("--subpolicy applies to --policy mixture only")
    if args.policy != MIXTURE and args.partition != partitions.DEFAULT:
        raise UsageError("--partition applies to --policy mixture only")
    cfg = make_config(args, k_max, task)
    iterations = math.ceil(args.steps / cfg.batch_size)
    chunk = args.chunk if args.chunk is not None else max(1, min(10, iterations // 20))
    if chunk < 1:
        raise UsageError(f"--chunk must be >= 1, got {chunk}")
    iterations = math.ceil(iterations / chunk) * chunk
    hp = {**options_hparams(args), "K": k, "total_iterations": iterations}
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
    return RunPlan(cfg, hp, iterations, chunk, eval_every, args.eval_seed, args.seed, task)


def saved_options(saved: dict) -> dict:
    """Option values (dest -> value) that give back a saved run's settings (its config.json): what
    `--resume --out DIR` continues with. Config fields a config.json written before they existed lacks ran at
    their defaults."""
    c, hp = config_record(saved["config"]), saved["hparams"]
    opts = saved_option_values(c, hp)
    opts.update({"seed": saved["seed"], "steps": saved["iterations"] * c["num_envs"] * c["unroll_length"],
                 "eval_every": saved.get("eval_every"), "eval_seed": saved["eval_seed"],
                 "chunk": saved["chunk"], "tensorboard": saved["tensorboard"]})
    return opts


def resume_args(parser: argparse.ArgumentParser, argv: list | None, out: str | None) -> argparse.Namespace:
    """With --resume: the command line parsed again over the run saved in `out` (its settings are the
    defaults, so only the options typed differ from them; run() refuses a difference without --force).
    A directory without a saved run keeps the command line's own settings where it names the task (a first
    invocation of a resumable command), else it is a one-line UsageError. Raises UsageError."""
    if out is None:
        raise UsageError("--resume needs --out DIR, the directory of the run to continue")
    path = os.path.join(out, "config.json")
    if not os.path.exists(path):
        if not typed(argv, "--env"):
            raise UsageError(f"no run in {out} to resume (to start one there with --resume, name its task: --env NAME)")
        return parser.parse_args(argv)
    return options_over_saved(parser, argv, path, saved_options, UsageError, "run")[0]


def typed(argv: list | None, *flags: str) -> bool:
    """Whether the command line argv names one of the options `flags` ('--flag', '--flag=V', or a one-letter '-KV')."""
    argv = sys.argv[1:] if argv is None else argv
    return any(a == f or a.startswith(f + "=") or (len(f) == 2 and a.startswith(f)) for a in argv for f in flags)


def check_policy_options(args: argparse.Namespace, argv: list | None) -> None:
    """UsageError (one line) for an option the chosen policy does not use (the mixture's, with --policy mlp)."""
    if args.policy == MLP:
        spellings = {"--clusters": ("--clusters", "-K"), "--k-max": ("--k-max",)}
        given = [flag for flag, names in spellings.items() if typed(argv, *names)]
        if given:
            raise UsageError(f"{' and '.join(given)} appl{'ies' if len(given) == 1 else 'y'} to --policy mixture only "
                             "(--policy mlp trains one flat MLP)")


def default_out(cfg: Config, hp: dict, seed: int) -> str:
    """runs/<env>-<policy>[-K<k>][-<subpolicy>][-<partition>-partition]-s<seed>-<time>: a new run's directory when
    --out is not given."""
    tag = f"{path_part(cfg.env)}-{cfg.policy}" + (f"-K{hp['K']}" if cfg.policy == MIXTURE else "")
    tag += f"-{cfg.subpolicy}" if cfg.policy == MIXTURE and cfg.subpolicy != subpolicies.DEFAULT else ""
    tag += f"-{cfg.partition}-partition" if cfg.policy == MIXTURE and cfg.partition != partitions.DEFAULT else ""
    tag += "-retrace" if cfg.value_target == "retrace" else ""
    return os.path.join("runs", f"{tag}-s{seed}-{time.strftime('%Y%m%d-%H%M%S')}")


def prepare_out(out: str, resume: bool) -> None:
    """Create --out and prove it is writable, before anything compiles."""
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, ".write_test")
        with open(probe, "w") as f:
            f.write("ok")
        os.unlink(probe)
    except OSError as e:
        raise UsageError(f"--out {out!r} is not writable: {e.strerror or e}") from None
    has_run = any(os.path.exists(os.path.join(out, n)) for n in ("state.npz", "state.prev.npz", "DONE"))
    if has_run and not resume:
        raise UsageError(f"--out {out!r} already holds a run; pass --resume to continue it or choose another --out")


def note_physics(cfg: Config, task: TaskRecord) -> None:
    """One line on stderr where MJX (the default backend, what accelerators run) is to train on a CPU a task that
    MuJoCo C steps too: --physics c is the CPU's speed path (the backend stays as given, and recorded)."""
    if cfg.physics.backend != "mjx" or not task.has_c:
        return
    import jax

    if jax.default_backend() == "cpu":
        print("gsa train: note: no accelerator here, and MJX (the default backend, what accelerators run) is the slow "
              "path on a CPU: --physics c steps this task in MuJoCo C inside the compiled program, the CPU's fast path "
              "(experiments/bench_c_backend/)",
              file=sys.stderr)


def train(argv: list | None) -> int:
    """Check the command line, then train (or resume) the run in its locked output directory."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.resume:
            args = resume_args(parser, argv, args.out)
        check_policy_options(args, argv)
        plan = resolve(args)
    except ValueError as e:
        raise UsageError(e) from None
    out = args.out or default_out(plan.cfg, plan.hp, plan.seed)
    prepare_out(out, args.resume)
    if not (args.quiet or args.resume or typed(argv, "--physics")):
        note_physics(plan.cfg, plan.task)
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    warn = lambda msg: print(f"gsa train: warning: {msg}", file=sys.stderr)  # noqa: E731
    from gsa_jax.running import xla_cache
    from gsa_jax.running.single import RunOptions, run

    with hold(out, "gsa_jax.train", log=lambda m: print(m, file=sys.stderr)), xla_cache.enabled(xla_cache.user_dir()):
        options = RunOptions(out, args.resume, args.force, args.stop_after, argv, args.tensorboard)
        try:
            end = run(plan, options, log, warn)
        except DiskFullError as e:
            raise disk_full(e, e.last_intact) from None
    return 0 if end.result is None else report_end(end.result, end.config, out, log)


def report_end(result: Any, config: dict, out: str, log: Callable) -> int:
    """The closing lines of this invocation. Returns the exit status: 0, 1 (NaN/inf), 130 (interrupted)."""
    timing, res = config["timing"], config["result"]
    if result.status == "failed":
        print(f"gsa train: error: {failure_line(result.metrics, result.done, out)}", file=sys.stderr)
        return 1
    if result.status == "interrupted":
        print(f"\ninterrupted; everything up to iteration {result.intact} is saved in {out} "
              f"(continue with: {resume_command('train', '--resume', '--out', out)})", file=sys.stderr)
        return 130
    if result.done < result.iterations:
        again = resume_command("train", "--resume", "--out", out)
        log(f"stopped at iteration {result.done}/{result.iterations} as asked; continue with: {again}")
    else:
        log(f"done: {timing['env_steps_run']:,} steps in {duration(timing['wall_s'])} (compile {timing['compile_s']:.1f}s, "
            f"{timing['env_steps_per_s']:,.0f} steps/s); final return {returned(res, 'final_episode_return')}, "
            f"eval {returned(res, 'final_eval_return')}; results in {out}")
    return 0


def returned(result: dict, key: str) -> str:
    """A result's return with the iteration it is from ('-' where there is none)."""
    it = result.get(f"{key}_iteration")
    return fmt(result[key], ".1f") + (f" (iteration {it})" if it is not None else "")


def failure_line(metrics: dict, done: int, out: str) -> str:
    """What stopped a run at a NaN/inf, from its metrics [1, iterations] up to `done`: the task's reward where an
    episode that ended in the failing iteration returned a non-finite total, else the loss or parameters."""
    failed_at = int(metrics["failed_at"][0, done - 1])
    ended, total = metrics["episodes"][0, failed_at - 1], float(metrics["episode_return"][0, failed_at - 1])
    if ended > 0 and not math.isfinite(total):
        what = (f"NaN/inf in the task's reward (the episodes that ended in iteration {failed_at} returned {total}: "
                "check its outcome()), and so in the loss")
    elif ended > 0:
        what = "NaN/inf in the loss or parameters (the episodes that ended in it returned finite rewards)"
    else:
        what = ("NaN/inf in the loss or parameters (no episode ended in it, so its rewards are not known here: if "
                "the task's reward can be NaN/inf, check its outcome())")
    return (f"{what} at iteration {failed_at}; stopped. Last good parameters (iteration {failed_at - 1}) are in "
            f"{os.path.join(out, 'params.npz')}")


def main(argv: list | None = None) -> int:
    """`gsa train` (exit statuses: the module docstring)."""
    return run_command("train", lambda: train(argv))
