"""A Config and its task: the running layer's one way from a Config's env name to the task's record (envs.resolve,
resolved and checked once per process), and the trainer built on that task's environments (ppo.make_train, handed
them as Brax's train is). The algorithm below never looks a name up."""

from typing import Any

import envs
from envs.families.record import TaskRecord
from gsa_jax.algorithm.config import Config, for_task
from gsa_jax.algorithm.ppo import make_envs, make_train
from gsa_jax.algorithm.run_parts import Trainer


def task_of(cfg: Config) -> TaskRecord:
    """The record of the task cfg.env names (ValueError in one line where it names none)."""
    return envs.resolve(cfg.env)


def config_for(cfg: Config, task: Any = None) -> Config:
    """cfg as it runs on `task` (a name, record or definition; default: cfg.env's): what it leaves to its task
    filled in (for_task), validated (ValueError naming the first bad field)."""
    record = task_of(cfg) if task is None else envs.resolve(task)
    return for_task(cfg, record).validate(record)


def trainer_for(cfg: Config, task: Any = None) -> Trainer:
    """The Trainer of a run of cfg on `task`: a task's name, record or definition (an envs.task.Task instance or
    subclass, named for its class; default: cfg.env's), with what cfg leaves to its task filled in (for_task:
    trainer.cfg is the Config run)."""
    record = task_of(cfg) if task is None else envs.resolve(task)
    cfg = for_task(cfg, record)
    return make_train(cfg, *make_envs(cfg, record))
