"""Run an exported controller in plain MuJoCo C (no MJX, no JAX) and in gymnasium's own tasks:

    python -m gsa_jax.deploy controller.npz [--episodes 20] [--gymnasium Hopper-v5] [--compare-mjx RUN_DIR] [--out F]

The controller file comes from `python -m gsa_jax.export RUN --out controller.npz`; its task is read
from the file. Prints the mean return (95% CI over episodes) and episode length of the deterministic
controller in our MuJoCo C port of the task (the MJCF it was trained on; ported: envs.mujoco_c.C_TASKS);
with --gymnasium ENV_ID also in gymnasium's own task (its MJCF, reward, termination and time limit;
refused with the reason where its observation layout is not ours, gsa_jax.gymnasium_task); with
--compare-mjx RUN_DIR also in the MJX environment it was trained in (this part uses JAX).
"""

import argparse
import json
import os
import sys
import zipfile

import numpy as np

from envs import C_BACKEND_TASKS, default_episode_length
from gsa_jax import numpy_policy


class DeployError(Exception):
    pass


def summarize(returns, lengths):
    r = np.asarray(returns, np.float64)
    half = 1.96 * r.std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else float("nan")
    return {"episodes": int(len(r)), "return_mean": float(r.mean()), "return_ci95": float(half),
            "return_min": float(r.min()), "return_max": float(r.max()), "length_mean": float(np.mean(lengths)),
            "returns": [round(float(x), 3) for x in r]}


def load_controller(controller_path):
    """(NumPy controller, its task name, its config) of an exported controller file."""
    if not os.path.exists(controller_path):
        raise DeployError(f"{controller_path!r} does not exist (make one with python -m gsa_jax.export RUN --out FILE)")
    if not zipfile.is_zipfile(controller_path):
        raise DeployError(f"{controller_path!r} is not an exported controller (not an .npz archive)")
    try:
        ctrl = numpy_policy.load(controller_path)
        with np.load(controller_path, allow_pickle=False) as f:
            meta = json.loads(str(f["config_json"]))
    except (OSError, KeyError, ValueError) as e:
        raise DeployError(f"{controller_path!r} is not an exported controller ({e})") from None
    return ctrl, meta["config"]["env"], meta["config"]


def run_mujoco_c(ctrl, env_name, config, episodes, episode_length=None, seed=0):
    """Summary of the controller's deterministic episodes in our MuJoCo C port of its task."""
    from envs.mujoco_c import make_c, run_episodes

    if env_name not in C_BACKEND_TASKS:
        raise DeployError(f"the controller is for {env_name!r}; MuJoCo C versions exist for {', '.join(C_BACKEND_TASKS)}")
    length = episode_length or config.get("episode_length") or default_episode_length(env_name)
    returns, lengths = run_episodes(make_c(env_name), ctrl, episodes, int(length), seed)
    return {**summarize(returns, lengths), "episode_length_limit": int(length)}


def run_gymnasium(ctrl, env_name, env_id, episodes, seed=0):
    """Summary of the controller in gymnasium's own task `env_id` (its MJCF, reward, termination, time limit)."""
    from gsa_jax.gymnasium_task import GymnasiumError, make_gym, run_episodes

    try:
        env, options = make_gym(env_name, env_id, seed=seed)
    except GymnasiumError as e:
        raise DeployError(str(e)) from None
    returns, lengths = run_episodes(env, ctrl, episodes, seed)
    return {**summarize(returns, lengths), "env_id": env_id, "options": options,
            "episode_length_limit": int(env.spec.max_episode_steps or 0)}


def run_mjx(run_dir, episodes, seed=0):
    """Summary of the same deterministic controller in the run's MJX environment (JAX)."""
    import jax

    from gsa_jax.inspection import last_iteration, load_run, rollout

    trainer, params, obs_stats, hp, meta = load_run(run_dir, require_mixture=False)
    roll = rollout(trainer, params, obs_stats, hp, jax.random.PRNGKey(seed), episodes, True, last_iteration(meta))
    return trainer.cfg.env, summarize(roll["reward"].sum(0), roll["alive"].sum(0))


def report_line(env_name, where, s):
    return (f"{env_name}: {where:<22} deterministic controller, {s['episodes']} episodes: return "
            f"{s['return_mean']:.1f} +- {s['return_ci95']:.1f} (95% CI), episode length {s['length_mean']:.0f}")


def compare_mjx(run_dir, env_name, episodes, seed):
    from gsa_jax.inspection import InspectError

    try:
        mjx_env, summary = run_mjx(run_dir, episodes, seed)
    except InspectError as e:
        raise DeployError(str(e)) from None
    if mjx_env != env_name:
        raise DeployError(f"{run_dir!r} is a {mjx_env!r} run, the controller is for {env_name!r}")
    return summary


def deploy(args):
    """Every requested simulator's summary, printed as it completes."""
    if args.episodes < 1:
        raise DeployError(f"--episodes must be >= 1, got {args.episodes}")
    ctrl, env_name, config = load_controller(args.controller)
    result = {"env": env_name, "controller": args.controller}
    if env_name in C_BACKEND_TASKS or not args.gymnasium:
        result["mujoco_c"] = run_mujoco_c(ctrl, env_name, config, args.episodes, args.episode_length, args.seed)
        print(report_line(env_name, "MuJoCo C (our port),", result["mujoco_c"]))
    if args.gymnasium:
        result["gymnasium"] = run_gymnasium(ctrl, env_name, args.gymnasium, args.episodes, args.seed)
        print(report_line(env_name, f"gymnasium {args.gymnasium},", result["gymnasium"]))
    if args.compare_mjx:
        result["mjx"] = compare_mjx(args.compare_mjx, env_name, args.episodes, args.seed)
        print(report_line(env_name, "MJX,", result["mjx"]))
    return result


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.deploy", description=__doc__.split("\n")[0])
    p.add_argument("controller", help="an exported controller .npz (python -m gsa_jax.export)")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--episode-length", type=int, default=None, help="default: the run's time limit")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gymnasium", default=None, metavar="ENV_ID",
                   help="also run it in gymnasium's own task, e.g. Hopper-v5 (needs the deploy extra)")
    p.add_argument("--compare-mjx", default=None, metavar="RUN_DIR", help="also roll out the run's controller in MJX")
    p.add_argument("--out", default=None, help="write the results as JSON")
    args = p.parse_args(argv)
    try:
        result = deploy(args)
    except DeployError as e:
        print(f"gsa_jax.deploy: error: {e}", file=sys.stderr)
        return 2
    if args.out:
        import mujoco

        result["versions"] = {"mujoco": mujoco.__version__}
        if args.gymnasium:
            import gymnasium

            result["versions"]["gymnasium"] = gymnasium.__version__
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
