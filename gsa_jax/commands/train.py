"""Train one policy (`gsa train [--env NAME] [--policy mixture|mlp] [--clusters K] [--steps N] ...`).

Writes to --out (default runs/<env>-<policy>[-K<k>]-s<seed>-<time>/):
  config.json   resolved config, hyperparameters, versions, git commit (and timings once finished)
  metrics.csv   one row per PPO iteration (env_steps, episode_return, eval_return, epsilon, sigma_min, ...)
  params.npz    parameters (policy, value, observation-normalizer statistics), [1, ...]: updated after every chunk
  curve.png     the learning curve
and what makes it resumable, the same files as a sweep's group of runs (gsa_jax.running.store; the run is a
group of one): runs.csv, metrics.npz and state.npz (dropped once finished), failed.json and DONE at the end.
Training runs as compiled chunks of iterations; between chunks the command logs, evaluates and saves.
Exit status: 0 done (or stopped as asked), 1 stopped at a NaN/inf, 2 bad input, 4 disk full, 130 interrupted.
"""

import argparse
import math
import os
import re
import sys
import time
from typing import Any, Callable

import envs
from envs.physics import BACKENDS, Physics
from gsa_jax.algorithm.kinds import MIXTURE, MLP, POLICY_KINDS
from gsa_jax.algorithm.policies import SUBPOLICY_KINDS
from gsa_jax.algorithm.ppo import HPARAM_DEFAULTS, Config, config_record, make_hparams, validate_hparams
from gsa_jax.algorithm.retrace import VALUE_TARGETS
from gsa_jax.cli import command_parser, options_over_saved, run_command, whole_number
from gsa_jax.running.driver import duration, fmt
from gsa_jax.running.metrics import EVALUATIONS_PER_RUN
from gsa_jax.running.runinfo import resume_command
from gsa_jax.running.runlock import hold
from gsa_jax.running.single import RunOptions, RunPlan, UsageError, run
from gsa_jax.running.trained import path_part

_HP_FLAGS = {  # CLI flag -> hparam name
    "lr": "lr", "clip": "clip_eps", "gamma": "gamma", "gae_lambda": "gae_lambda", "vf_coef": "vf_coef",
    "max_grad_norm": "max_grad_norm", "eps_init": "eps_init", "eps_decay": "eps_decay",
    "sigma_min_init": "sigma_min_init", "sigma_min_decay": "sigma_min_decay", "sigma_init_scale": "sigma_init_scale",
    **{n: n for n in ("lr_scale_partition", "lr_scale_L", "lr_scale_b", "lr_scale_log_sigma", "lr_scale_log_std",
                      "lr_scale_critic", "init_log_std")},
}


def add_physics_flags(p: argparse.ArgumentParser) -> None:
    """The physics options (envs/physics.py): backend, its threads, and MJX's solver settings."""
    p.add_argument("--solver-iterations", type=int, default=None,
                   help="MJX constraint-solver iterations (default: the task's own; hopper 4). Fewer is faster but a "
                        "changed simulator -- see experiments/solver_hopper/")
    p.add_argument("--ls-iterations", type=int, default=None,
                   help="MJX line-search iterations per solver iteration (default: the task's own; hopper 50)")
    p.add_argument("--linesearch", default=Physics.linesearch, choices=("exact", "iterative"),
                   help="MJX solver line search: exact where the model allows it (default), or MJX's iterative one")
    p.add_argument("--cholesky", default=Physics.cholesky, choices=("unrolled", "lapack"),
                   help="MJX's small Cholesky factorizations: unrolled elementwise ops (default) or LAPACK")
    p.add_argument("--physics", default=Physics.backend, choices=BACKENDS,
                   help="physics backend: MJX (default; what accelerators run) or MuJoCo C stepped from inside the "
                        "compiled program (the CPU speed path; every task but Brax's inverted_double_pendulum)")
    p.add_argument("--physics-threads", type=int, default=Physics.threads,
                   help="--physics c: MuJoCo C threads in this process (default 0: its share of the cores)")
    p.add_argument("--randomize", default=Config.randomize, metavar="TEXT",
                   help="domain randomization of the training episodes, e.g. 'mass=0.9:1.1, friction=0.75:1.25, "
                        "gear=0.9:1.1, damping=0.8:1.2, obs_noise=0.01, delay=1, push=0.125' (docs/randomize.md), or "
                        "'task': the task's own `randomize`; default none")
    p.add_argument("--eval-randomized", action="store_true",
                   help="evaluate under the training randomization (default: the nominal task)")


def build_parser() -> argparse.ArgumentParser:
    """`gsa train`'s options."""
    p = command_parser("train", __doc__)
    p.add_argument("--env", default="inverted_double_pendulum",
                   help=f"one of: {', '.join(envs.NAMES)}; a task definition of yours, 'module:Class' or "
                        "'path/file.py:Class'; or another library's environment: 'brax:<name>' (Brax's registry) or "
                        "'playground:<Name>' (MuJoCo Playground's registry) (docs/your_task.md)")
    p.add_argument("--policy", default="mixture", help="mixture (of linear controllers) or mlp (flat PPO baseline)")
    p.add_argument("--clusters", "-K", type=int, default=4, help="K, number of linear controllers (mixture)")
    p.add_argument("--subpolicy", default="linear",
                   help="sub-policy class of a mixture: constant (one action per cluster), linear (default), quadratic")
    p.add_argument("--k-max", type=int, default=None, help="pad the cluster axis to this size (default: K)")
    p.add_argument("--steps", type=whole_number, default=1_000_000, help="environment steps (rounded up to whole chunks)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="output directory (default: runs/<env>-<policy>-...)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run saved in --out with its saved settings; an option given with it must "
                        "match the saved run's (or --force)")
    p.add_argument("--force", action="store_true", help="with --resume: continue with the options given even where they differ from the saved run's")
    p.add_argument("--num-envs", type=int, default=Config.num_envs)
    p.add_argument("--unroll-length", type=int, default=Config.unroll_length)
    p.add_argument("--epochs", type=int, default=Config.num_epochs)
    p.add_argument("--minibatches", type=int, default=Config.num_minibatches)
    p.add_argument("--episode-length", type=int, default=None, help="time limit in steps (default: the task's own)")
    add_physics_flags(p)
    p.add_argument("--reset-mode", default=Config.reset_mode, choices=envs.RESET_MODES,
                   help="first: an ended episode restarts from its env's first start (Brax's); fresh: a new draw")
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
    p.add_argument("--stop-after", type=whole_number, default=None,
                   help="stop (resumably) after this many iterations in this invocation; continue with --resume")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/, open with tensorboard --logdir OUT)")
    return p


# The Config fields (physics.<name>: its physics record's) a command-line option sets, with the option's dest: one
# table for the Config of a command line, the options that give back a saved run, and the flags named in errors.
# normalize_reward (--no-normalize-reward) is the one inverted; env and k_max are set by resolve.
CONFIG_OPTIONS = {"policy": "policy", "subpolicy": "subpolicy", "num_envs": "num_envs", "unroll_length": "unroll_length",
                  "num_epochs": "epochs", "num_minibatches": "minibatches", "episode_length": "episode_length",
                  "b_init_scale": "b_init_scale", "eval_envs": "eval_envs", "value_target": "value_target",
                  "retrace_iterations": "retrace_iterations", "reset_mode": "reset_mode", "randomize": "randomize",
                  "eval_randomized": "eval_randomized", "physics.solver_iterations": "solver_iterations",
                  "physics.ls_iterations": "ls_iterations", "physics.linesearch": "linesearch",
                  "physics.cholesky": "cholesky", "physics.backend": "physics", "physics.threads": "physics_threads"}
UNFLAGGED = ("hidden", "normalize_obs", "physics.search_loop")  # Config fields without a command-line option


def config_fields(values: dict) -> dict:
    """Config keyword arguments of {field or physics.<name>: value}."""
    physics = {k.split(".", 1)[1]: v for k, v in values.items() if k.startswith("physics.")}
    return {**{k: v for k, v in values.items() if not k.startswith("physics.")}, "physics": Physics(**physics)}


def flag_names(msg: str) -> str:
    """A Config error with each field an option sets named by its flag (where the two differ)."""
    for field, dest in CONFIG_OPTIONS.items():
        name = field.split(".")[-1]
        if name != dest or "_" in name:
            msg = re.sub(rf"\b{name}\b", "--" + dest.replace("_", "-"), msg)
    return msg


def make_config(args: argparse.Namespace, k_max: int) -> Config:
    """The run's validated Config; a bad field is a UsageError naming its flag."""
    values = {field: getattr(args, dest) for field, dest in CONFIG_OPTIONS.items()}
    values.update(getattr(args, "unflagged", {}))
    cfg = Config(env=args.env, k_max=max(k_max, 1), normalize_reward=not args.no_normalize_reward,
                 **config_fields(values))
    try:
        return cfg.validate()
    except ValueError as e:
        raise UsageError(flag_names(str(e))) from None


def resolve(args: argparse.Namespace) -> RunPlan:
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
    if args.policy != MIXTURE and args.subpolicy != "linear":
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


def saved_options(saved: dict) -> dict:
    """Option values (dest -> value) that give back a saved run's settings (its config.json): what
    `--resume --out DIR` continues with. Config fields a config.json written before they existed lacks ran at
    their defaults."""
    c = config_record(saved["config"])
    hp = saved["hparams"]

    def field(name):
        v = c["physics"][name.split(".", 1)[1]] if name.startswith("physics.") else c[name]
        return tuple(v) if isinstance(v, list) else v

    opts = {dest: field(name) for name, dest in CONFIG_OPTIONS.items()}
    opts.update({"env": c["env"], "clusters": hp["K"], "k_max": c["k_max"], "seed": saved["seed"],
                 "steps": saved["iterations"] * c["num_envs"] * c["unroll_length"],
                 "no_anneal_lr": hp.get("anneal_lr", 1.0) == 0, "no_normalize_reward": not c["normalize_reward"],
                 "eval_every": saved.get("eval_every"), "eval_seed": saved.get("eval_seed", 0),
                 "chunk": saved["chunk"], "tensorboard": saved.get("tensorboard", True),
                 "unflagged": {name: field(name) for name in UNFLAGGED}})
    opts.update({flag: hp[name] for flag, name in _HP_FLAGS.items() if name in hp})
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
    return options_over_saved(parser, argv, path, saved_options, UsageError)[0]


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
    """runs/<env>-<policy>[-K<k>][-<subpolicy>]-s<seed>-<time>: a new run's directory when --out is not given."""
    tag = f"{path_part(cfg.env)}-{cfg.policy}" + (f"-K{hp['K']}" if cfg.policy == MIXTURE else "")
    tag += f"-{cfg.subpolicy}" if cfg.policy == MIXTURE and cfg.subpolicy != "linear" else ""
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


def train(argv: list | None) -> int:
    """Check the command line, then train (or resume) the run in its locked output directory."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.resume:
            args = resume_args(parser, argv, args.out)
        envs.check_task(args.env)
        check_policy_options(args, argv)
        plan = resolve(args)
    except ValueError as e:
        raise UsageError(e) from None
    out = args.out or default_out(plan.cfg, plan.hp, plan.seed)
    prepare_out(out, args.resume)
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    warn = lambda msg: print(f"gsa train: warning: {msg}", file=sys.stderr)  # noqa: E731
    with hold(out, "gsa_jax.train", log=lambda m: print(m, file=sys.stderr)):
        options = RunOptions(out, args.resume, args.force, args.stop_after, argv, args.quiet, args.tensorboard)
        end = run(plan, options, log, warn)
    return 0 if end.result is None else report_end(end.result, end.config, out, log)


def report_end(result: Any, config: dict, out: str, log: Callable) -> int:
    """The closing lines of this invocation. Returns the exit status: 0, 1 (NaN/inf), 130 (interrupted)."""
    timing, res = config["timing"], config["result"]
    if result.status == "failed":
        print(f"gsa train: error: {failure_line(result.metrics, result.done, out)}", file=sys.stderr)
        return 1
    if result.status == "interrupted":
        print(f"\ninterrupted; everything up to iteration {result.intact} is saved in {out} "
              f"(continue with: {resume_command('gsa_jax.train', '--resume', '--out', out)})", file=sys.stderr)
        return 130
    if result.done < result.iterations:
        again = resume_command("gsa_jax.train", "--resume", "--out", out)
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
