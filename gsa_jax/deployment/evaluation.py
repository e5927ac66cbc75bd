"""An exported controller run outside training: in MuJoCo C (our ports), in gymnasium's own task, and the
run's own controller in MJX for comparison; `gsa deploy` is its command."""

import json
import os
import zipfile

from typing import TYPE_CHECKING

import numpy as np

from gsa_jax.deployment import numpy_policy
from gsa_jax.errors import UserError
from gsa_jax.running.formats import read_controller

if TYPE_CHECKING:
    from envs.families.record import TaskRecord


class DeployError(UserError):
    pass


def summarize(returns: np.ndarray, lengths: np.ndarray) -> dict:
    r = np.asarray(returns, np.float64)
    half = 1.96 * r.std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else float("nan")
    return {"episodes": int(len(r)), "return_mean": float(r.mean()), "return_ci95": float(half),
            "return_min": float(r.min()), "return_max": float(r.max()), "length_mean": float(np.mean(lengths)),
            "returns": [round(float(x), 3) for x in r]}


def load_controller(controller_path: str, force: bool = False) -> tuple:
    """(NumPy controller, its task's record, its config) of an exported controller file, acting in [-1, 1] as our
    MuJoCo C tasks' step() takes (Controller.unit_actions); DeployError (one line) where its task does not resolve
    here or it does not fit its task's definition as it is now (numpy_policy.check_task; force: only its observation
    size)."""
    if not os.path.exists(controller_path):
        raise DeployError(f"{controller_path!r} does not exist (make one with gsa export RUN --out FILE)")
    if not zipfile.is_zipfile(controller_path):
        raise DeployError(f"{controller_path!r} is not an exported controller (not an .npz archive)")
    try:
        arrays = read_controller(controller_path)  # an older file in the current layout (running.formats)
        ctrl = numpy_policy.Controller(arrays, name=str(controller_path))
        config = json.loads(str(arrays["config_json"]))["config"]
    except (OSError, KeyError, ValueError) as e:
        raise DeployError(f"{controller_path!r} is not an exported controller ({e})") from None
    task = controller_record(arrays, config["env"])
    if task.has_c:  # a task MuJoCo C steps: its definition is read without JAX
        try:
            numpy_policy.check_task(arrays, task, force, name=str(controller_path))
        except numpy_policy.TaskMismatch as e:
            raise DeployError(str(e)) from None
    return ctrl.unit_actions(), task, config


def controller_record(arrays: dict, env_name: str) -> "TaskRecord":
    """The record of the task a controller's arrays name (numpy_policy.controller_task); DeployError, one line, where
    the name does not resolve here."""
    try:
        return numpy_policy.controller_task(arrays)
    except (ValueError, ImportError) as e:  # a name that does not resolve, or a library this machine lacks
        raise DeployError(f"the controller is for {env_name!r}: {' '.join(str(e).split())}") from None


def mujoco_c_episodes(ctrl: numpy_policy.Controller, task: "TaskRecord", config: dict, episodes: int,
                      episode_length: int | None = None, seed: int = 0) -> tuple:
    """The controller's deterministic episodes in our MuJoCo C port of its task (task: its record, load_controller's)
    from seeds seed .. seed + episodes - 1 -> (returns [episodes] float64, lengths [episodes], the length limit)."""
    from envs.mujoco_c import run_episodes

    try:  # a task defined outside the package is imported here: its errors in one line
        twin = task.make_c()
        length = episode_length or config.get("episode_length") or task.episode_length()
    except ValueError as e:
        raise DeployError(f"the controller is for {task.name!r}: {e}") from None
    returns, lengths = run_episodes(twin, ctrl, episodes, int(length), seed)
    return np.asarray(returns, np.float64), np.asarray(lengths), int(length)


def run_mujoco_c(ctrl: numpy_policy.Controller, task: "TaskRecord", config: dict, episodes: int,
                 episode_length: int | None = None, seed: int = 0) -> dict:
    """Summary of the controller's deterministic episodes in MuJoCo C (mujoco_c_episodes)."""
    returns, lengths, length = mujoco_c_episodes(ctrl, task, config, episodes, episode_length, seed)
    return {**summarize(returns, lengths), "episode_length_limit": length}


def open_gymnasium(ctrl: numpy_policy.Controller, env_name: str, env_id: str, seed: int = 0) -> tuple:
    """(gymnasium's env `env_id` for the controller, its options), checked (DeployError, one line, where there is no
    counterpart of the task or its layout or action space is not the controller's)."""
    from gsa_jax.deployment.gymnasium_rollout import GymnasiumError, check_bounds, make_gym

    try:
        env, options = make_gym(env_name, env_id, seed=seed)
        check_bounds(ctrl, env, env_id)
    except (GymnasiumError, ValueError) as e:
        raise DeployError(str(e)) from None
    return env, options


def run_gymnasium(ctrl: numpy_policy.Controller, gym: tuple, env_id: str, episodes: int, seed: int = 0) -> dict:
    """Summary of the controller in gymnasium's own task (its MJCF, reward, termination, time limit); gym: (env,
    options) of open_gymnasium."""
    from gsa_jax.deployment.gymnasium_rollout import run_episodes

    env, options = gym
    returns, lengths = run_episodes(env, ctrl, episodes, seed)
    return {**summarize(returns, lengths), "env_id": env_id, "options": options,
            "episode_length_limit": int(env.spec.max_episode_steps or 0)}


def run_mjx(run_dir: str, episodes: int, seed: int = 0) -> tuple:
    """Summary of the same deterministic controller in the run's MJX environment (JAX)."""
    import jax

    from gsa_jax.deployment.inspection import last_iteration, load_run, rollout

    trainer, params, obs_stats, hp, meta = load_run(run_dir, require_mixture=False)
    roll = rollout(trainer, params, obs_stats, hp, jax.random.PRNGKey(seed), episodes, True, last_iteration(meta))
    return trainer.cfg.env, summarize(roll["reward"].sum(0), roll["alive"].sum(0))


def report_line(env_name: str, where: str, s: dict) -> str:
    return (f"{env_name}: {where:<22} deterministic controller, {s['episodes']} episodes: return "
            f"{s['return_mean']:.1f} +- {s['return_ci95']:.1f} (95% CI), episode length {s['length_mean']:.0f}")


def compare_mjx(run_dir: str, env_name: str, episodes: int, seed: int) -> dict:
    from gsa_jax.deployment.inspection import InspectError

    try:
        mjx_env, summary = run_mjx(run_dir, episodes, seed)
    except InspectError as e:
        raise DeployError(str(e)) from None
    if mjx_env != env_name:
        raise DeployError(f"{run_dir!r} is a {mjx_env!r} run, the controller is for {env_name!r}")
    return summary
