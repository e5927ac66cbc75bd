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
    has_run = os.path.exists(os.path.join(out, "state.npz"))
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
    return run(cfg, hp, iterations, chunk, eval_every, args.seed, out, args.resume, args.quiet, argv, args.stop_after)


def run(cfg, hp_py, iterations, chunk, eval_every, seed, out, resume, quiet=False, argv=None, stop_after=None):
    import jax
    import numpy as np

    from gsa_jax.checkpoint import load_pytree, save_pytree
    from gsa_jax.plotting import plot_curve
    from gsa_jax.ppo import make_hparams, make_train
    from gsa_jax.runinfo import run_metadata

    def log(msg):
        if not quiet:
            print(msg, flush=True)

    config = {
        "config": dataclasses.asdict(cfg), "hparams": hp_py, "seed": seed, "iterations": iterations,
        "chunk": chunk, "eval_every": eval_every, "env_steps": iterations * cfg.batch_size,
        "argv": list(sys.argv[1:] if argv is None else argv),
    }
    config_path = os.path.join(out, "config.json")
    state_path, params_path, metrics_path = (os.path.join(out, n) for n in ("state.npz", "params.npz", "metrics.csv"))
    if resume and os.path.exists(config_path):
        with open(config_path) as f:
            old = json.load(f)
        for key in ("config", "hparams", "seed", "iterations", "chunk"):
            mine = json.loads(json.dumps(config[key]))
            if key == "config":  # runs saved before a field existed hold its default (None) implicitly
                mine = {k: v for k, v in mine.items() if v is not None or k in old.get(key, {})}
            if mine != old.get(key):
                print(f"gsa_jax.train: error: --resume with a different {key} than the run in {out}", file=sys.stderr)
                return 2
    config.update(run_metadata())
    write_atomic(config_path, json.dumps(config, indent=2))

    hp = make_hparams(**hp_py)
    trainer = make_train(cfg)
    log(f"gsa_jax: {cfg.env} ({trainer.env.observation_size} obs, {trainer.env.action_size} actions), "
        f"{cfg.policy}" + (f" K={hp_py['K']} (k_max {cfg.k_max}, {cfg.subpolicy} sub-policies)" if cfg.policy == "mixture" else "")
        + f", {iterations} iterations x {cfg.batch_size} steps = {iterations * cfg.batch_size:,} env steps -> {out}")
    if cfg.solver_iterations is not None or cfg.ls_iterations is not None:
        from envs import solver_settings

        sol = solver_settings(trainer.env.unwrapped)
        ls = "exact line search" if sol["linesearch"] == "exact" else f"{sol['ls_iterations']} line-search iterations"
        log(f"MJX solver: {sol['iterations']} iterations, {ls} (the task's own: "
            f"{sol['task_iterations']}, {sol['task_ls_iterations']}) -- a changed simulator, see experiments/README.md (solver)")

    t0 = time.perf_counter()
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed), hp)
    run_chunk = jax.jit(trainer.run_chunk, static_argnums=2, donate_argnums=0).lower(state, hp, chunk).compile()
    evaluate = jax.jit(trainer.evaluate)
    compile_s = time.perf_counter() - t0
    log(f"compiled in {compile_s:.1f}s")

    rows = []
    if resume and os.path.exists(state_path):
        state = load_pytree(state_path, state)
        done_its = int(state["iteration"])
        rows = [r for r in read_rows(metrics_path) if int(r["iteration"]) <= done_its]
        log(f"resumed at iteration {done_its} from {state_path}")
    start_it = done_it = int(state["iteration"])  # host copy: `state` is donated to each chunk
    if not os.path.exists(params_path):  # the initial parameters: "last good" even if chunk 1 diverges
        save_pytree(params_path, {k: state[k] for k in ("params", "obs_stats")},
                    **{"meta/config_json": np.array(json.dumps(config))})
    stop_at = iterations if stop_after is None else min(iterations, start_it + stop_after)
    eval_key = jax.random.PRNGKey(seed + 1_000_003)
    t_train, eval_s, steps_run = time.perf_counter(), 0.0, 0
    status = 0
    interrupted = False
    try:
        while done_it < stop_at:
            t_chunk = time.perf_counter()
            new_state, metrics = run_chunk(state, hp)
            metrics = jax.device_get(metrics)
            it = int(new_state["iteration"])
            leaves_ok = all(bool(np.all(np.isfinite(x))) for x in jax.tree.leaves(new_state["params"]))
            loss_ok = bool(np.all(np.isfinite(metrics["policy_loss"])) and np.all(np.isfinite(metrics["value_loss"])))
            if not (leaves_ok and loss_ok):
                print(f"gsa_jax.train: error: NaN/inf in {'parameters' if not leaves_ok else 'loss'} during iterations "
                      f"{it - chunk + 1}..{it}; stopped. Last good parameters (iteration {it - chunk}) are in {params_path}",
                      file=sys.stderr)
                status = 1
                break
            state, done_it = new_state, it
            steps_run += chunk * cfg.batch_size
            eval_ret = math.nan
            if eval_every and (it % eval_every < chunk or it == iterations):
                te = time.perf_counter()
                eval_ret = float(evaluate(state["params"], state["obs_stats"], hp, jax.random.fold_in(eval_key, it)))
                eval_s += time.perf_counter() - te
            wall = time.perf_counter() - t0
            for i in range(chunk):
                row = {k: (v[i].item() if hasattr(v[i], "item") else v[i]) for k, v in metrics.items() if k in METRIC_COLUMNS}
                row["eval_return"] = eval_ret if i == chunk - 1 else math.nan
                row["wall_s"] = round(wall, 3)
                rows.append({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})
            write_atomic(metrics_path, rows_to_csv(rows))
            save_pytree(params_path, {k: state[k] for k in ("params", "obs_stats")},
                        **{"meta/config_json": np.array(json.dumps(config))})
            save_pytree(state_path, state)
            train_time = time.perf_counter() - t_train - eval_s
            sps = steps_run / max(train_time, 1e-9)
            eta = (iterations - it) * cfg.batch_size / max(sps, 1e-9)
            recent = [float(r["episode_return"]) for r in rows[-chunk:] if r["episode_return"] != ""]
            line = (f"it {it}/{iterations} | steps {it * cfg.batch_size:,} | return {_fmt(np.mean(recent) if recent else None, '.1f')}"
                    + (f" | eval {eval_ret:.1f}" if not math.isnan(eval_ret) else "")
                    + f" | {sps:,.0f} steps/s | ETA {_duration(eta)}")
            if cfg.policy == "mixture":
                line += (f" | eps {float(metrics['epsilon'][-1]):.3f} sigma_min {float(metrics['sigma_min'][-1]):.4f}"
                         f" | clusters used {int(metrics['clusters_used'][-1])}")
            log(line + f" | chunk {time.perf_counter() - t_chunk:.1f}s")
    except KeyboardInterrupt:
        interrupted = True
        status = 130
        print(f"\ninterrupted; everything up to iteration {done_it} is saved in {out} "
              f"(continue with --resume --out {out})", file=sys.stderr)

    total = time.perf_counter() - t0
    train_time = time.perf_counter() - t_train - eval_s
    if rows:
        title = f"{cfg.env} - {cfg.policy}" + (f" K={hp_py['K']}" if cfg.policy == "mixture" else "") + f" - seed {seed}"
        plot_curve(rows, os.path.join(out, "curve.png"), title)
    config["timing"] = {
        "compile_s": round(compile_s, 2), "train_s": round(train_time, 2), "eval_s": round(eval_s, 2),
        "wall_s": round(total, 2), "env_steps_run": steps_run, "start_iteration": start_it,
        "env_steps_per_s": round(steps_run / max(train_time, 1e-9), 1),
    }
    last = [r for r in rows if r["episode_return"] != ""]
    config["result"] = {
        "iterations_done": done_it,
        "final_episode_return": float(last[-1]["episode_return"]) if last else None,
        "final_eval_return": next((float(r["eval_return"]) for r in reversed(rows) if r["eval_return"] != ""), None),
        "status": "nan" if status == 1 else "interrupted" if interrupted or done_it < iterations else "finished",
    }
    write_atomic(config_path, json.dumps(config, indent=2))
    if status == 0 and done_it < iterations:
        log(f"stopped at iteration {done_it}/{iterations} as asked; continue with --resume --out {out}")
    elif status == 0:
        log(f"done: {steps_run:,} steps in {_duration(total)} (compile {compile_s:.1f}s, "
            f"{config['timing']['env_steps_per_s']:,.0f} steps/s); final return "
            f"{_fmt(config['result']['final_episode_return'], '.1f')}, eval {_fmt(config['result']['final_eval_return'], '.1f')}; "
            f"results in {out}")
    return status


if __name__ == "__main__":
    sys.exit(main())
