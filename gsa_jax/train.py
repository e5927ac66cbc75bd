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
import functools
import io
import json
import math
import os
import sys
import time

from gsa_jax.checkpoint import write_atomic
from gsa_jax.policies import SUBPOLICY_KINDS
from gsa_jax.ppo import HPARAM_DEFAULTS, Config

METRIC_COLUMNS = (
    "iteration", "env_steps", "episode_return", "eval_return", "episodes", "epsilon", "sigma_min", "lr",
    "policy_loss", "value_loss", "approx_kl", "clip_fraction", "grad_norm", "partition_entropy",
    "clusters_used", "wall_s",
)
_HP_FLAGS = {  # CLI flag -> hparam name
    "lr": "lr", "clip": "clip_eps", "gamma": "gamma", "gae_lambda": "gae_lambda", "vf_coef": "vf_coef",
    "max_grad_norm": "max_grad_norm", "eps_init": "eps_init", "eps_decay": "eps_decay",
    "sigma_min_init": "sigma_min_init", "sigma_min_decay": "sigma_min_decay", "sigma_init_scale": "sigma_init_scale",
}


class UsageError(Exception):
    pass


def build_parser():
    import envs

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
                        "changed simulator -- see experiments/README.md (solver)")
    p.add_argument("--ls-iterations", type=int, default=None,
                   help="MJX line-search iterations per solver iteration (default: the task's own; hopper 50)")
    p.add_argument("--b-init-scale", type=float, default=Config.b_init_scale, help="initial biases spread over [-s, s]^d_a")
    for flag, name in _HP_FLAGS.items():
        p.add_argument("--" + flag.replace("_", "-"), type=float, default=HPARAM_DEFAULTS[name], dest=flag)
    p.add_argument("--no-anneal-lr", action="store_true", help="keep the learning rate constant")
    p.add_argument("--no-normalize-reward", action="store_true", help="train on raw rewards")
    p.add_argument("--eval-every", type=int, default=None, help="iterations between deterministic evaluations (0: none; default ~10 per run)")
    p.add_argument("--eval-envs", type=int, default=Config.eval_envs)
    p.add_argument("--chunk", type=int, default=None, help="PPO iterations per compiled chunk (default: auto)")
    p.add_argument("--stop-after", type=int, default=None,
                   help="stop (resumably) after this many iterations in this invocation; continue with --resume")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def resolve(args):
    """Check every argument and return (Config, hparam dict of python numbers, iterations, chunk). No compiling."""
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
    cfg = Config(
        env=args.env, policy=args.policy, subpolicy=args.subpolicy, k_max=max(k_max, 1), num_envs=args.num_envs,
        unroll_length=args.unroll_length, num_epochs=args.epochs, num_minibatches=args.minibatches,
        episode_length=args.episode_length, normalize_reward=not args.no_normalize_reward,
        b_init_scale=args.b_init_scale, eval_envs=args.eval_envs,
        solver_iterations=args.solver_iterations, ls_iterations=args.ls_iterations,
    )
    try:
        cfg.validate()
    except ValueError as e:
        msg = str(e).replace("num_envs", "--num-envs").replace("num_minibatches", "--minibatches")
        raise UsageError(msg.replace("solver_iterations", "--solver-iterations").replace("ls_iterations", "--ls-iterations")) from None
    iterations = math.ceil(args.steps / cfg.batch_size)
    chunk = args.chunk if args.chunk is not None else max(1, min(10, iterations // 20))
    if chunk < 1:
        raise UsageError(f"--chunk must be >= 1, got {chunk}")
    iterations = math.ceil(iterations / chunk) * chunk
    hp = {name: getattr(args, flag) for flag, name in _HP_FLAGS.items()}
    hp.update(K=k, total_iterations=iterations, anneal_lr=0.0 if args.no_anneal_lr else 1.0)
    from gsa_jax.ppo import make_hparams, validate_hparams

    try:
        validate_hparams(cfg, make_hparams(**hp))
    except ValueError as e:
        raise UsageError(str(e).replace("clusters K", "--clusters")) from None
    eval_every = args.eval_every if args.eval_every is not None else max(chunk, iterations // 10)
    if eval_every < 0:
        raise UsageError(f"--eval-every must be >= 0, got {eval_every}")
    if args.stop_after is not None and args.stop_after < 1:
        raise UsageError(f"--stop-after must be >= 1, got {args.stop_after}")
    return cfg, hp, iterations, chunk, eval_every


def default_out(cfg, hp, seed):
    tag = f"{cfg.env}-{cfg.policy}" + (f"-K{hp['K']}" if cfg.policy == "mixture" else "")
    tag += f"-{cfg.subpolicy}" if cfg.policy == "mixture" and cfg.subpolicy != "linear" else ""
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


def _fmt(x, spec):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def _duration(s):
    s = int(max(0, s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        import envs

        envs.check_name(args.env)
        cfg, hp, iterations, chunk, eval_every = resolve(args)
        out = args.out or default_out(cfg, hp, args.seed)
        prepare_out(out, args.resume)
    except (UsageError, ValueError) as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2
    from gsa_jax.runlock import LockError, hold

    try:
        with hold(out, "gsa_jax.train", log=lambda m: print(m, file=sys.stderr)):
            return run(cfg, hp, iterations, chunk, eval_every, args.seed, out, args.resume, args.quiet, argv,
                       args.stop_after, args.force)
    except LockError as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2


RESUME_KEYS = ("config", "hparams", "seed", "iterations", "chunk")


def check_resume_config(old, config, force):
    """Raise UsageError with a one-line diff if the saved run's config differs (unless force)."""
    mine = {k: json.loads(json.dumps(config[k])) for k in RESUME_KEYS}
    # runs saved before a config field existed hold its default (None) implicitly
    mine["config"] = {k: v for k, v in mine["config"].items() if v is not None or k in old.get("config", {})}
    from gsa_jax.runinfo import describe_changes

    diff = describe_changes({k: old.get(k) for k in RESUME_KEYS}, mine)
    if diff and not force:
        raise UsageError(f"--resume with a different run than the one in the output directory ({diff}); "
                         "pass --force to continue it with the new settings")


def resume_state(state, out, log):
    """(state, metrics rows, iteration) of the run saved in out: state.npz, or state.prev.npz if that is
    unreadable; metrics.csv (or its previous version) cut to the state's iteration."""
    from gsa_jax.checkpoint import load_pytree, read_with_fallback

    def warn(msg):  # seen even with --quiet
        print(msg, file=sys.stderr, flush=True)

    state, path = read_with_fallback(os.path.join(out, "state.npz"), lambda p: load_pytree(p, state), warn)
    done_it = int(state["iteration"])
    rows, _ = read_with_fallback(os.path.join(out, "metrics.csv"), read_rows_checked, warn)
    if int(state["failed_at"]) >= 0:
        raise UsageError(f"the run in {out} stopped at a NaN/inf at iteration {int(state['failed_at'])}; nothing to resume")
    rows = [r for r in rows if int(r["iteration"]) <= done_it]
    if len(rows) < done_it:
        raise UsageError(f"{out}: metrics.csv holds {len(rows)} iterations but {os.path.basename(path)} is at "
                         f"iteration {done_it}; delete the directory to start over")
    log(f"resumed at iteration {done_it} from {path}")
    return state, rows, done_it


def read_rows_checked(path):
    rows = read_rows(path) if os.path.exists(path) else None
    if rows is None:
        raise OSError("missing")
    if rows and set(METRIC_COLUMNS) - set(rows[0]):
        raise ValueError("not a metrics table")
    return rows


def save_chunk(out, state, rows, config):
    """Metrics, parameters and state after a chunk; the checkpoint files keep their previous version."""
    import numpy as np

    from gsa_jax.checkpoint import save_pytree

    write_atomic(os.path.join(out, "metrics.csv"), rows_to_csv(rows), keep_previous=True)
    save_pytree(os.path.join(out, "params.npz"), {k: state[k] for k in ("params", "obs_stats")},
                **{"meta/config_json": np.array(json.dumps(config))})
    save_pytree(os.path.join(out, "state.npz"), state, keep_previous=True)


def chunk_rows(metrics, count, eval_ret, wall):
    """The first `count` iterations of a chunk's metrics as CSV rows (eval_return on the last)."""
    rows = []
    for i in range(count):
        row = {k: (v[i].item() if hasattr(v[i], "item") else v[i]) for k, v in metrics.items() if k in METRIC_COLUMNS}
        row["eval_return"] = eval_ret if i == count - 1 else math.nan
        row["wall_s"] = round(wall, 3)
        rows.append({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})
    return rows


def progress_line(cfg, rows, metrics, it, iterations, chunk, eval_ret, sps, t_chunk):
    import numpy as np

    eta = (iterations - it) * cfg.batch_size / max(sps, 1e-9)
    recent = [float(r["episode_return"]) for r in rows[-chunk:] if r["episode_return"] != ""]
    line = (f"it {it}/{iterations} | steps {it * cfg.batch_size:,} | return {_fmt(np.mean(recent) if recent else None, '.1f')}"
            + (f" | eval {eval_ret:.1f}" if not math.isnan(eval_ret) else "")
            + f" | {sps:,.0f} steps/s | ETA {_duration(eta)}")
    if cfg.policy == "mixture":
        line += (f" | eps {float(metrics['epsilon'][-1]):.3f} sigma_min {float(metrics['sigma_min'][-1]):.4f}"
                 f" | clusters used {int(metrics['clusters_used'][-1])}")
    return line + f" | chunk {time.perf_counter() - t_chunk:.1f}s"


def run(cfg, hp_py, iterations, chunk, eval_every, seed, out, resume, quiet=False, argv=None, stop_after=None, force=False):
    """Train (or resume) one run into `out`. Returns the exit status: 0, 1 (NaN/inf), 2 (bad resume),
    4 (disk full), 130 (interrupted)."""
    from gsa_jax.checkpoint import CheckpointError, DiskFullError

    def log(msg):
        if not quiet:
            print(msg, flush=True)

    config = {
        "config": dataclasses.asdict(cfg), "hparams": hp_py, "seed": seed, "iterations": iterations,
        "chunk": chunk, "eval_every": eval_every, "env_steps": iterations * cfg.batch_size,
        "argv": list(sys.argv[1:] if argv is None else argv),
    }
    loop = {"done_it": 0, "intact_it": 0}
    try:
        config_path = os.path.join(out, "config.json")
        if resume and os.path.exists(config_path):
            with open(config_path) as f:
                check_resume_config(json.load(f), config, force)
        from gsa_jax.runinfo import run_metadata

        config.update(run_metadata())
        write_atomic(config_path, json.dumps(config, indent=2))
        return train_loop(cfg, hp_py, iterations, chunk, eval_every, seed, out, resume, config, log, stop_after, loop)
    except (UsageError, CheckpointError) as e:
        print(f"gsa_jax.train: error: {e}", file=sys.stderr)
        return 2
    except DiskFullError as e:
        intact = "iteration {}".format(loop["intact_it"])
        print(f"gsa_jax.train: error: {e.describe(intact)}", file=sys.stderr)
        return 4


@functools.lru_cache(maxsize=8)
def compiled_program(cfg, chunk):
    """(trainer, jitted init, compiled run_chunk of `chunk` iterations, jitted evaluate) of a Config,
    built once per process (a second run of the same shapes in this process, e.g. a test, reuses it)."""
    import jax

    from gsa_jax.ppo import make_hparams, make_train

    trainer = make_train(cfg)
    init = jax.jit(trainer.init)
    hp = make_hparams(**{"K": 1})  # shapes only: every hyperparameter is a scalar
    state = jax.eval_shape(init, jax.random.PRNGKey(0), hp)
    run_chunk = jax.jit(trainer.run_chunk, static_argnums=2, donate_argnums=0).lower(state, hp, chunk).compile()
    return trainer, init, run_chunk, jax.jit(trainer.evaluate)


def train_loop(cfg, hp_py, iterations, chunk, eval_every, seed, out, resume, config, log, stop_after, loop):
    import jax
    import numpy as np

    from gsa_jax.checkpoint import save_pytree

    from gsa_jax.ppo import make_hparams

    t0 = time.perf_counter()
    trainer, init, run_chunk, evaluate = compiled_program(cfg, chunk)
    hp = make_hparams(**hp_py)
    state = init(jax.random.PRNGKey(seed), hp)
    log_start(cfg, trainer, hp_py, iterations, out, log)
    compile_s = time.perf_counter() - t0
    log(f"compiled in {compile_s:.1f}s")
    rows, params_path = [], os.path.join(out, "params.npz")
    if resume and (os.path.exists(os.path.join(out, "state.npz")) or os.path.exists(os.path.join(out, "state.prev.npz"))):
        state, rows, _ = resume_state(state, out, log)
    start_it = loop["done_it"] = loop["intact_it"] = int(state["iteration"])  # host copy: `state` is donated
    if not os.path.exists(params_path):  # the initial parameters: "last good" even if chunk 1 diverges
        save_pytree(params_path, {k: state[k] for k in ("params", "obs_stats")},
                    **{"meta/config_json": np.array(json.dumps(config))})
    stop_at = iterations if stop_after is None else min(iterations, start_it + stop_after)
    eval_key = jax.random.PRNGKey(seed + 1_000_003)
    t_train, clock = time.perf_counter(), {"eval_s": 0.0, "steps_run": 0}
    status = 0
    try:
        while loop["done_it"] < stop_at:
            t_chunk = time.perf_counter()
            state, metrics = run_chunk(state, hp)
            metrics = jax.device_get(metrics)
            failed_at = int(state["failed_at"])
            it = int(state["iteration"])
            good = chunk if failed_at < 0 else failed_at - 1 - loop["done_it"]
            eval_ret = math.nan
            if failed_at < 0 and eval_every and (it % eval_every < chunk or it == iterations):
                te = time.perf_counter()
                eval_ret = float(evaluate(state["params"], state["obs_stats"], hp, jax.random.fold_in(eval_key, it)))
                clock["eval_s"] += time.perf_counter() - te
            rows.extend(chunk_rows(metrics, good, eval_ret, time.perf_counter() - t0))
            loop["done_it"] = it
            clock["steps_run"] += good * cfg.batch_size
            save_chunk(out, state, rows, config)
            loop["intact_it"] = it
            if failed_at >= 0:
                print(f"gsa_jax.train: error: NaN/inf in the loss or parameters at iteration {failed_at}; stopped. "
                      f"Last good parameters (iteration {failed_at - 1}) are in {params_path}", file=sys.stderr)
                status = 1
                break
            sps = clock["steps_run"] / max(time.perf_counter() - t_train - clock["eval_s"], 1e-9)
            log(progress_line(cfg, rows, metrics, it, iterations, chunk, eval_ret, sps, t_chunk))
    except KeyboardInterrupt:
        status = 130
        print(f"\ninterrupted; everything up to iteration {loop['intact_it']} is saved in {out} "
              f"(continue with --resume --out {out})", file=sys.stderr)
    finish(cfg, hp_py, seed, out, config, rows, status, loop["done_it"], iterations, start_it,
           {"compile_s": compile_s, "t0": t0, "t_train": t_train, **clock}, log)
    return status


def log_start(cfg, trainer, hp_py, iterations, out, log):
    log(f"gsa_jax: {cfg.env} ({trainer.env.observation_size} obs, {trainer.env.action_size} actions), "
        f"{cfg.policy}" + (f" K={hp_py['K']} (k_max {cfg.k_max}, {cfg.subpolicy} sub-policies)" if cfg.policy == "mixture" else "")
        + f", {iterations} iterations x {cfg.batch_size} steps = {iterations * cfg.batch_size:,} env steps -> {out}")
    if cfg.solver_iterations is not None or cfg.ls_iterations is not None:
        from envs import solver_settings

        sol = solver_settings(trainer.env.unwrapped)
        ls = "exact line search" if sol["linesearch"] == "exact" else f"{sol['ls_iterations']} line-search iterations"
        log(f"MJX solver: {sol['iterations']} iterations, {ls} (the task's own: "
            f"{sol['task_iterations']}, {sol['task_ls_iterations']}) -- a changed simulator, see experiments/README.md (solver)")


def finish(cfg, hp_py, seed, out, config, rows, status, done_it, iterations, start_it, clock, log):
    """Curve, timings and result into config.json; the closing line."""
    from gsa_jax.plotting import plot_curve

    total = time.perf_counter() - clock["t0"]
    train_time = time.perf_counter() - clock["t_train"] - clock["eval_s"]
    if rows:
        title = f"{cfg.env} - {cfg.policy}" + (f" K={hp_py['K']}" if cfg.policy == "mixture" else "") + f" - seed {seed}"
        try:
            plot_curve(rows, os.path.join(out, "curve.png"), title)
        except OSError as e:  # a figure is not worth failing a run for (e.g. a full disk)
            print(f"gsa_jax.train: warning: curve.png not written ({e.strerror or e})", file=sys.stderr)
    config["timing"] = {
        "compile_s": round(clock["compile_s"], 2), "train_s": round(train_time, 2), "eval_s": round(clock["eval_s"], 2),
        "wall_s": round(total, 2), "env_steps_run": clock["steps_run"], "start_iteration": start_it,
        "env_steps_per_s": round(clock["steps_run"] / max(train_time, 1e-9), 1),
    }
    last = [r for r in rows if r["episode_return"] != ""]
    config["result"] = {
        "iterations_done": done_it,
        "final_episode_return": float(last[-1]["episode_return"]) if last else None,
        "final_eval_return": next((float(r["eval_return"]) for r in reversed(rows) if r["eval_return"] != ""), None),
        "status": "nan" if status == 1 else "interrupted" if status == 130 or done_it < iterations else "finished",
    }
    write_atomic(os.path.join(out, "config.json"), json.dumps(config, indent=2))
    if status == 0 and done_it < iterations:
        log(f"stopped at iteration {done_it}/{iterations} as asked; continue with --resume --out {out}")
    elif status == 0:
        log(f"done: {clock['steps_run']:,} steps in {_duration(total)} (compile {clock['compile_s']:.1f}s, "
            f"{config['timing']['env_steps_per_s']:,.0f} steps/s); final return "
            f"{_fmt(config['result']['final_episode_return'], '.1f')}, eval {_fmt(config['result']['final_eval_return'], '.1f')}; "
            f"results in {out}")


if __name__ == "__main__":
    sys.exit(main())
