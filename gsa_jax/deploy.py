"""Run an exported controller in plain MuJoCo C (no MJX, no JAX) on the MJCF it was trained on:

    python -m gsa_jax.deploy controller.npz [--episodes 20] [--compare-mjx RUN_DIR] [--out deploy.json]

The controller file comes from `python -m gsa_jax.export RUN --out controller.npz`; its task is read
from the file. Prints the mean return (and episode length) of the deterministic controller in
MuJoCo C; with --compare-mjx RUN_DIR it also rolls out the same deterministic controller in the MJX
environment it was trained in (this part uses JAX) for the same number of episodes, so a user sees
whether the controller transfers between the two simulators. Ported tasks: envs.mujoco_c.C_TASKS.
"""

import argparse
import json
import os
import sys

import numpy as np


class DeployError(Exception):
    pass


def summarize(returns, lengths):
    r = np.asarray(returns, np.float64)
    half = 1.96 * r.std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else float("nan")
    return {"episodes": int(len(r)), "return_mean": float(r.mean()), "return_ci95": float(half),
            "return_min": float(r.min()), "return_max": float(r.max()), "length_mean": float(np.mean(lengths)),
            "returns": [round(float(x), 3) for x in r]}


def run_mujoco_c(controller_path, episodes, episode_length=None, seed=0):
    """(env name, summary) of the controller's deterministic episodes in MuJoCo C."""
    from envs import default_episode_length
    from envs.mujoco_c import C_TASKS, make_c, run_episodes
    from gsa_jax import numpy_policy

    if not os.path.exists(controller_path):
        raise DeployError(f"{controller_path!r} does not exist (make one with python -m gsa_jax.export RUN --out FILE)")
    try:
        ctrl = numpy_policy.load(controller_path)
        with np.load(controller_path, allow_pickle=False) as f:
            meta = json.loads(str(f["config_json"]))
    except (OSError, KeyError, ValueError) as e:
        raise DeployError(f"{controller_path!r} is not an exported controller ({e})") from None
    env_name = meta["config"]["env"]
    if env_name not in C_TASKS:
        raise DeployError(f"the controller is for {env_name!r}; MuJoCo C ports exist for {', '.join(C_TASKS)}")
    length = episode_length or meta["config"].get("episode_length") or default_episode_length(env_name)
    task = make_c(env_name)
    returns, lengths = run_episodes(task, ctrl, episodes, int(length), seed)
    return env_name, {**summarize(returns, lengths), "episode_length_limit": int(length)}


def run_mjx(run_dir, episodes, seed=0):
    """Summary of the same deterministic controller in the run's MJX environment (JAX)."""
    import jax

    from gsa_jax.inspect import last_iteration, load_run, rollout

    trainer, params, obs_stats, hp, meta = load_run(run_dir, require_mixture=False)
    roll = rollout(trainer, params, obs_stats, hp, jax.random.PRNGKey(seed), episodes, True, last_iteration(meta))
    return trainer.cfg.env, summarize(roll["reward"].sum(0), roll["alive"].sum(0))


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.deploy", description=__doc__.split("\n")[0])
    p.add_argument("controller", help="an exported controller .npz (python -m gsa_jax.export)")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--episode-length", type=int, default=None, help="default: the run's time limit")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--compare-mjx", default=None, metavar="RUN_DIR", help="also roll out the run's controller in MJX")
    p.add_argument("--out", default=None, help="write the results as JSON")
    args = p.parse_args(argv)
    try:
        if args.episodes < 1:
            raise DeployError(f"--episodes must be >= 1, got {args.episodes}")
        env_name, c = run_mujoco_c(args.controller, args.episodes, args.episode_length, args.seed)
        result = {"env": env_name, "controller": args.controller, "mujoco_c": c}
        print(f"{env_name}: MuJoCo C, deterministic controller, {c['episodes']} episodes: return "
              f"{c['return_mean']:.1f} +- {c['return_ci95']:.1f} (95% CI), episode length {c['length_mean']:.0f}")
        if args.compare_mjx:
            from gsa_jax.inspect import InspectError

            try:
                mjx_env, j = run_mjx(args.compare_mjx, args.episodes, args.seed)
            except InspectError as e:
                raise DeployError(str(e)) from None
            if mjx_env != env_name:
                raise DeployError(f"{args.compare_mjx!r} is a {mjx_env!r} run, the controller is for {env_name!r}")
            result["mjx"] = j
            print(f"{env_name}: MJX,       deterministic controller, {j['episodes']} episodes: return "
                  f"{j['return_mean']:.1f} +- {j['return_ci95']:.1f} (95% CI), episode length {j['length_mean']:.0f}")
        if args.out:
            import mujoco

            result["versions"] = {"mujoco": mujoco.__version__}
            with open(args.out, "w") as f:
                json.dump(result, f, indent=1)
            print(f"wrote {args.out}")
    except DeployError as e:
        print(f"gsa_jax.deploy: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
