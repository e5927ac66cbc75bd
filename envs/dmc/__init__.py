"""The DeepMind Control Suite's tasks as task definitions (envs/task.py), named `dmc:<domain>-<task>`: dm_control's
own MJCFs, control timesteps, reset laws, observations (its dict flattened in its key order), rewards and
1000-step episodes, checked step for step against dm_control (tests/test_dmc.py). One module per domain;
envs/dmc/base.py holds what they share. dm_control is an optional extra (envs.dmc.base.INSTALL)."""

import importlib

PREFIX = "dmc:"

# name -> "module:Class" of envs/dmc
TASKS = {
    "cartpole-balance": "cartpole:Balance",
    "cartpole-swingup": "cartpole:Swingup",
    "pendulum-swingup": "pendulum:Swingup",
    "acrobot-swingup": "acrobot:Swingup",
    "point_mass-easy": "point_mass:Easy",
    "walker-stand": "walker:Stand",
    "walker-walk": "walker:Walk",
    "walker-run": "walker:Run",
    "hopper-stand": "hopper:Stand",
    "hopper-hop": "hopper:Hop",
    "cheetah-run": "cheetah:Run",
    "reacher-easy": "reacher:Easy",
    "reacher-hard": "reacher:Hard",
    "finger-spin": "finger:Spin",
    "ball_in_cup-catch": "ball_in_cup:Catch",
    "fish-swim": "fish:Swim",
    "quadruped-walk": "quadruped:Walk",
}
NAMES = tuple(PREFIX + name for name in TASKS)


def task_class(name: str) -> type:
    """The Task subclass of 'dmc:<domain>-<task>' (ValueError listing the available ones in one line)."""
    key = name[len(PREFIX):] if name.startswith(PREFIX) else name
    if key not in TASKS:
        raise ValueError(f"unknown DeepMind Control Suite task {name!r}; choose one of {', '.join(NAMES)}")
    module, _, cls = TASKS[key].partition(":")
    return getattr(importlib.import_module(f"envs.dmc.{module}"), cls)
