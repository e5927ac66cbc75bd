"""Train one policy: `python -m gsa_jax.train [--env NAME] [--policy mixture|mlp] [--clusters K] [--steps N] ...`

Writes to --out (default runs/<env>-<policy>[-K<k>]-s<seed>-<time>/):
  config.json   resolved config, hyperparameters, versions, git commit (and timings once finished)
  metrics.csv   one row per PPO iteration (env_steps, episode_return, eval_return, epsilon, sigma_min, ...)
  params.npz    parameters (policy, value, observation-normalizer statistics), [1, ...]: updated after every chunk
  curve.png     the learning curve
and what makes it resumable, the same files as a sweep's group of runs (gsa_jax.running.store; the run is a
group of one): runs.csv, metrics.npz and state.npz (dropped once finished), failed.json and DONE at the end.
Training runs as compiled chunks of iterations; between chunks the CLI logs, evaluates and saves.
"""

import argparse
import json
import math
import os
import sys
import time

import envs
from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.config import (
    add_options, config_record, flag_names, make_hparams, options_config, options_hparams, saved_option_values,
    validate_hparams,
)
from gsa_jax.algorithm.kinds import MIXTURE, MLP, POLICY_KINDS
from gsa_jax.algorithm.policies import SUBPOLICY_KINDS
from gsa_jax.running.metrics import EVALUATIONS_PER_RUN
from gsa_jax.running.runinfo import cli_description
from gsa_jax.running.runlock import LockError, hold
from gsa_jax.running.single import RunOptions, RunPlan, UsageError, run
from gsa_jax.running.trained import path_part

def build_parser():
    p = argparse.ArgumentParser(prog="python -m gsa_jax.train", description=cli_description(__doc__))
    add_options(p)
    p.add_argument("--steps", type=int, default=1_000_000, help="environment steps (rounded up to whole chunks)")
    p.add_argument("--seed", type=int, default=0)
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
    p.add_argument("--stop-after", type=int, default=None,
                   help="stop (resumably) after this many iterations in this invocation; continue with --resume")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/, open with tensorboard --logdir OUT)")
    return p


def make_config(args, k_max):
    """The run's validated Config; a bad field is a UsageError naming its flag."""
    cfg = options_config(args, k_max=max(k_max, 1))
    try:
        return cfg.validate()
    except ValueError as e:
        raise UsageError(flag_names(str(e))) from None


def resolve(args):
    """Check every argument and return the RunPlan. No compiling."""
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
    cfg = make_config(args, k_max)
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
    return RunPlan(cfg, hp, iterations, chunk, eval_every, args.eval_seed, args.seed)


def saved_options(saved):
    """Option values (dest -> value) that give back a saved run's settings (its config.json): what
    `--resume --out DIR` continues with. Config fields a config.json written before they existed lacks ran at
    their defaults."""
    c, hp = config_record(saved["config"]), saved["hparams"]
    opts = saved_option_values(c, hp)
    opts.update({"seed": saved["seed"], "steps": saved["iterations"] * c["num_envs"] * c["unroll_length"],
                 "eval_every": saved.get("eval_every"), "eval_seed": saved.get("eval_seed", 0),
                 "chunk": saved["chunk"], "tensorboard": saved.get("tensorboard", True)})
    return opts


def resume_args(parser, argv, out):
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
    try:
        with open(path) as f:
            saved = json.load(f)
        defaults = saved_options(saved)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UsageError(f"cannot resume: {path} is not a gsa_jax run's config ({type(e).__name__}: {e})") from None
    parser.set_defaults(**defaults)
    return parser.parse_args(argv)


def typed(argv, *flags):
    """Whether the command line argv names one of the options `flags` ('--flag', '--flag=V', or a one-letter '-KV')."""
    argv = sys.argv[1:] if argv is None else argv
    return any(a == f or a.startswith(f + "=") or (len(f) == 2 and a.startswith(f)) for a in argv for f in flags)


def check_policy_options(args, argv):
    """UsageError (one line) for an option the chosen policy does not use (the mixture's, with --policy mlp)."""
    if args.policy == MLP:
        spellings = {"--clusters": ("--clusters", "-K"), "--k-max": ("--k-max",)}
        given = [flag for flag, names in spellings.items() if typed(argv, *names)]
        if given:
            raise UsageError(f"{' and '.join(given)} appl{'ies' if len(given) == 1 else 'y'} to --policy mixture only "
                             "(--policy mlp trains one flat MLP)")


def default_out(cfg, hp, seed):
    tag = f"{path_part(cfg.env)}-{cfg.policy}" + (f"-K{hp['K']}" if cfg.policy == MIXTURE else "")
    tag += f"-{cfg.subpolicy}" if cfg.policy == MIXTURE and cfg.subpolicy != subpolicies.DEFAULT else ""
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
    has_run = any(os.path.exists(os.path.join(out, n)) for n in ("state.npz", "state.prev.npz", "DONE"))
    if has_run and not resume:
        raise UsageError(f"--out {out!r} already holds a run; pass --resume to continue it or choose another --out")


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.resume:
            args = resume_args(parser, argv, args.out)
        envs.check_task(args.env)
        check_policy_options(args, argv)
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


if __name__ == "__main__":
    sys.exit(main())
