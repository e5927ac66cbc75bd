"""Tasks in plain MuJoCo C (the `mujoco` package: no MJX, no JAX) on the same MJCF as their MJX
versions, for running an exported controller outside the simulator it was trained in.

    task = make_c("hopper")          # any task whose record has a MuJoCo C version (envs/registry.py)
    obs = task.reset(seed)
    obs, reward, done = task.step(action)

Each task ports its MJX environment's reset distribution, observation, reward and termination to
NumPy: hopper, walker2d, halfcheetah, ant (Brax's tasks with their defaults on backend 'mjx') as task
definitions (envs/brax_ports.py, BRAX_PORTS: stepped by envs.task.TaskC, in the program by the C backend as every
task definition is); allegro_cylinder (envs/allegro.py) as envs/allegro_task.py's AllegroC. Their names are
re-exported here. Nothing here imports JAX; tests/test_mujoco_c.py checks the ports step for step against the MJX
environments.
"""

from typing import Any

import numpy as np

from envs.allegro_task import AllegroC, allegro_layout  # noqa: F401 - re-exported
from envs.brax_ports import (  # noqa: F401 - re-exported
    BRAX_PORTS, IDP_LAYOUT, AntC, BraxTask, HalfCheetahC, HopperC, Walker2dC, brax_asset,
)
from envs.registry import TaskLike, resolve

C_TASKS = ("hopper", "walker2d", "halfcheetah", "ant", "allegro_cylinder")  # the MuJoCo C ports


def make_c(name: TaskLike) -> Any:
    """The task in plain MuJoCo C: reset(seed) -> obs, step(action) -> (obs, reward, done) (the task's record,
    envs/registry.py: a Brax port, AllegroC, or envs.task.TaskC over a task definition)."""
    return resolve(name).make_c()


def observation_layout(name: TaskLike) -> list:
    """One short description per observation entry of task `name` (for exported controllers' docs)."""
    return resolve(name).observation_layout()


def run_episodes(task: Any, controller: Any, episodes: int, episode_length: int,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic controller (gsa_jax.deployment.numpy_policy) in the C task: returns [episodes], lengths [episodes].
    Its act() keeps actions inside the task's bounds, as training clips them (envs.ACTION_RANGE)."""
    returns, lengths = [], []
    for e in range(episodes):
        obs = task.reset(seed + e)
        total, t = 0.0, 0
        for t in range(1, episode_length + 1):
            obs, r, done = task.step(controller.act(obs))
            total += r
            if done:
                break
        returns.append(total)
        lengths.append(t)
    return np.array(returns), np.array(lengths)
