"""Run an exported controller in plain MuJoCo C (no MJX, no JAX) and in gymnasium's own tasks.

    gsa deploy controller.npz [--episodes 10] [--start-seed 10000] [--gymnasium Hopper-v5] [--compare-mjx RUN_DIR] [--out F]

The controller file comes from `gsa export RUN --out controller.npz`; its task is read
from the file, and a controller that no longer fits it (its observation size, or its definition's sha256: a task file
edited since) is refused in one line (--force runs it where the sizes agree). Prints the mean return (95% CI over
episodes) and episode length of the deterministic controller in MuJoCo C (the MJCF it was trained on: our port of
Brax's task, or the task's own definition; every task with a MuJoCo C version, envs/registry.py);
with --gymnasium ENV_ID also in gymnasium's own task (its MJCF, reward, termination and time limit;
refused with the reason where its observation layout is not ours, gsa_jax.deployment.gymnasium_rollout); with
--compare-mjx RUN_DIR also in the MJX environment it was trained in (this part uses JAX).
"""

import argparse
import json

from gsa_jax.deployment.evaluation import (DeployError, compare_mjx, load_controller, open_gymnasium, report_line,
                                           run_gymnasium, run_mujoco_c)
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.deployment import starts


def deploy(args: argparse.Namespace) -> dict:
    """Every requested simulator's summary, printed as it completes; a request that cannot run (no gymnasium
    counterpart) is refused before any episode."""
    if args.episodes < 1:
        raise DeployError(f"--episodes must be >= 1, got {args.episodes}")
    ctrl, task, config = load_controller(args.controller, args.force)
    env_name = task.name
    gym = open_gymnasium(ctrl, env_name, args.gymnasium, args.seed) if args.gymnasium else None
    result = {"env": env_name, "controller": args.controller}
    if task.has_c or not (args.gymnasium or args.compare_mjx):  # else: the others only
        result["mujoco_c"] = run_mujoco_c(ctrl, task, config, args.episodes, args.episode_length, args.seed)
        print(report_line(env_name, task.mujoco_c_label() + ",", result["mujoco_c"]))
    if gym:
        result["gymnasium"] = run_gymnasium(ctrl, gym, args.gymnasium, args.episodes, args.seed)
        print(report_line(env_name, f"gymnasium {args.gymnasium},", result["gymnasium"]))
    if args.compare_mjx:
        result["mjx"] = compare_mjx(args.compare_mjx, env_name, args.episodes, args.seed)
        print(report_line(env_name, "MJX,", result["mjx"]))
    return result


def build_parser() -> argparse.ArgumentParser:
    """`gsa deploy`'s options."""
    p = command_parser("deploy", __doc__)
    p.add_argument("controller", help="an exported controller .npz (gsa export)")
    p.add_argument("--episodes", type=int, default=starts.SELECTION_EPISODES,
                   help="deterministic episodes per simulator (default %(default)s: with the default --start-seed, "
                        "the selection starts `gsa score` scores)")
    p.add_argument("--episode-length", type=int, default=None, help="steps per episode (default: the run's time limit)")
    p.add_argument("--start-seed", "--seed", dest="seed", type=int, default=starts.SELECTION_SEED,
                   help=f"episode i starts from the task's start law drawn with seed START_SEED + i (default "
                        f"%(default)s: the selection starts, as `gsa score`; {starts.FRESH_SEED}: the fresh starts an "
                        "answer reports; gsa_jax.deployment.starts)")
    p.add_argument("--gymnasium", default=None, metavar="ENV_ID",
                   help="also run it in gymnasium's own task, e.g. Hopper-v5 (needs the deploy extra)")
    p.add_argument("--compare-mjx", default=None, metavar="RUN_DIR", help="also roll out the run's controller in MJX")
    p.add_argument("--out", default=None, help="write the results as JSON to this file (default: printed only)")
    p.add_argument("--force", action="store_true",
                   help="run a controller whose task's definition changed since it was trained, or that names another "
                        "task, where the observation sizes agree")
    return p


def deploy_controller(argv: list | None) -> int:
    """Run the controller and write its results as JSON where --out asks."""
    args = build_parser().parse_args(argv)
    result = deploy(args)
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


def main(argv: list | None = None) -> int:
    """`gsa deploy`: exit status 0, or 2 on bad input."""
    return run_command("deploy", lambda: deploy_controller(argv))
