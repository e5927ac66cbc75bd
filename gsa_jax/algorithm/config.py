"""The configuration of a training run: the static `Config` (what changes shapes or program structure, one
compile each) and the traced `Hparams` (array scalars a sweep varies and vmaps over), with their defaults, allowed
ranges and checks, run before anything compiles."""

import dataclasses
import json
import math
from typing import Any, NamedTuple

import jax.numpy as jnp

import envs
from envs.physics import Physics, make_physics, nest_physics
from envs.randomize import parse as parse_randomize
from gsa_jax.algorithm.kinds import MIXTURE, POLICY_KINDS
from gsa_jax.algorithm.policies import SUBPOLICY_KINDS
from gsa_jax.algorithm.retrace import VALUE_TARGETS

@dataclasses.dataclass(frozen=True)
class Config:
    """Static configuration. Defaults: ~2048 samples per iteration (32 envs x 64 steps), 10 epochs,
    32 minibatches of 64 -- the PPO paper's MuJoCo setting, with the batch spread over envs."""

    env: str = "inverted_double_pendulum"
    policy: str = MIXTURE
    subpolicy: str = "linear"  # mixture sub-policy class: constant | linear | quadratic
    k_max: int = 8
    num_envs: int = 32
    unroll_length: int = 64
    num_epochs: int = 10
    num_minibatches: int = 32
    hidden: tuple = (64, 64)
    episode_length: int | None = None  # None: the task's own (envs.default_episode_length)
    # where an ended training episode restarts: "first" (the env's first start state, Brax's convention) or
    # "fresh" (a new draw of the task's start law, as gymnasium and dm_control reset; envs/wrappers.py)
    reset_mode: str = "first"
    normalize_obs: bool = True
    normalize_reward: bool = True
    b_init_scale: float = 1.0
    eval_envs: int = 16
    # the value function's targets: "gae" (GAE(lambda) on the iteration's own samples) or "retrace"
    # (the paper's critic: Retrace over the samples of the last retrace_iterations iterations, gsa_jax/algorithm/retrace.py)
    value_target: str = "gae"
    retrace_iterations: int = 4
    # the physics options, one record (envs/physics.py: backend 'mjx' or 'c', MuJoCo C threads, MJX's solver and
    # line-search settings); a dict of its fields is taken too (config.json, experiment files' [config.physics])
    physics: Physics = Physics()
    # domain randomization of the training episodes (envs/randomize.py's text, e.g. "mass=0.9:1.1, delay=1"; '':
    # none); evaluation runs the nominal task unless eval_randomized
    randomize: str = ""
    eval_randomized: bool = False

    def __post_init__(self):
        if isinstance(self.physics, dict):
            object.__setattr__(self, "physics", make_physics(self.physics))
        if self.episode_length is None and envs.is_name(self.env):
            object.__setattr__(self, "episode_length", envs.default_episode_length(self.env))
        if self.randomize == "task" and envs.is_name(self.env):  # the task's own declared randomization
            object.__setattr__(self, "randomize", envs.task_randomize(self.env))
        try:  # the canonical text of a text, a table ({name: value}) or a Randomize; validate() names a bad one
            object.__setattr__(self, "randomize", parse_randomize(self.randomize).text())
        except ValueError:
            if not isinstance(self.randomize, str):
                raise

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.unroll_length

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    def validate(self, task: Any = None) -> "Config":
        """Raise ValueError naming the first bad field (before anything is compiled). task: the task's record
        (envs/registry.py; default: self.env resolved), whose name must be self.env."""
        task = envs.task_record(self.env if task is None else task)
        if task.name != self.env:
            raise ValueError(f"the Config names env {self.env!r} but the task given is {task.name!r}: make the Config "
                             "with env=<the task's name>")
        envs.check_task(task)
        if self.policy not in POLICY_KINDS:
            raise ValueError(f"unknown policy {self.policy!r}; choose one of {', '.join(POLICY_KINDS)}")
        if self.subpolicy not in SUBPOLICY_KINDS:
            raise ValueError(f"unknown subpolicy {self.subpolicy!r}; choose one of {', '.join(SUBPOLICY_KINDS)}")
        if self.reset_mode not in envs.RESET_MODES:
            raise ValueError(f"unknown reset_mode {self.reset_mode!r}; choose one of {', '.join(envs.RESET_MODES)}")
        if self.value_target not in VALUE_TARGETS:
            raise ValueError(f"unknown value_target {self.value_target!r}; choose one of {', '.join(VALUE_TARGETS)}")
        for name in ("k_max", "num_envs", "unroll_length", "num_epochs", "num_minibatches", "episode_length", "eval_envs",
                     "retrace_iterations"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        envs.check_backend(task, self.physics)
        envs.check_randomize(task, self.randomize, self.episode_length, self.physics)
        if self.eval_randomized and not self.randomize:
            raise ValueError("eval_randomized evaluates under the training randomization; randomize is empty")
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"num_envs*unroll_length = {self.batch_size} is not divisible by num_minibatches = {self.num_minibatches}"
            )
        return self


def config_defaults() -> dict:
    """Config's field defaults as config.json holds them (JSON types; physics a dict)."""
    out = {}
    for f in dataclasses.fields(Config):
        out[f.name] = dataclasses.asdict(f.default) if dataclasses.is_dataclass(f.default) else f.default
    return json.loads(json.dumps(out))


def config_record(saved: dict) -> dict:
    """A saved config record (config.json's 'config', sweep.json's, an exported controller's) in this version's
    layout: the physics options one record (envs.physics.nest_physics moves the flat fields of records written
    before), and the fields it lacks (written before they existed) at their defaults, which is how it ran."""
    defaults, saved = config_defaults(), nest_physics(saved)
    return {**defaults, **saved, "physics": {**defaults["physics"], **saved.get("physics", {})}}


class Hparams(NamedTuple):
    """Per-run hyperparameters: everything a sweep may vary, as array scalars inside the programs (float32;
    K and total_iterations int32), so runs vmap over them. Defaults: the paper's PPO settings."""

    K: int = 4  # active clusters (mixture); must be <= Config.k_max
    lr: float = 3e-4
    anneal_lr: float = 1.0  # 1: lr decays linearly to 0 over total_iterations; 0: constant
    total_iterations: int = 1000
    clip_eps: float = 0.2
    gamma: float = 0.99
    gae_lambda: float = 0.95
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    eps_init: float = 0.2  # uniform exploration of the partition policy ...
    eps_decay: float = 0.995  # ... times this every iteration
    sigma_min_init: float = 0.1  # floor of every sub-policy std ...
    sigma_min_decay: float = 0.995  # ... times this every iteration
    sigma_init_scale: float = 1.0  # initial sub-policy std = sigma_init_scale / K
    # per-group learning rates, each lr x its scale (1: the one lr of the PPO paper's settings):
    lr_scale_partition: float = 1.0  # mixture: the partition network
    lr_scale_L: float = 1.0  # mixture: the linear pieces' gains L
    lr_scale_b: float = 1.0  # mixture: their offsets b
    lr_scale_log_sigma: float = 1.0  # mixture: their log std
    lr_scale_log_std: float = 1.0  # flat PPO: its state-independent log std (its MLP takes lr itself)
    lr_scale_critic: float = 1.0  # both: the value network
    init_log_std: float = 0.0  # flat PPO: the initial log std of its actions


HPARAM_DEFAULTS = Hparams()._asdict()
_INT_HPARAMS = ("K", "total_iterations")


def make_hparams(**overrides: Any) -> Hparams:
    """Hparams of array scalars (float32; K and total_iterations int32): the defaults with `overrides` (names of
    Hparams' fields; an unknown name is a ValueError)."""
    unknown = set(overrides) - set(HPARAM_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown hyperparameter(s) {sorted(unknown)}; known: {', '.join(HPARAM_DEFAULTS)}")
    hp = dict(HPARAM_DEFAULTS, **overrides)
    return Hparams(**{k: jnp.asarray(v, jnp.int32 if k in _INT_HPARAMS else jnp.float32) for k, v in hp.items()})


# Allowed range of every hyperparameter: (low, high, low included, high included). K is checked against k_max.
HPARAM_RANGES = {
    "K": (1, None, True, True),
    "lr": (0.0, None, False, True),
    "anneal_lr": (0.0, 1.0, True, True),
    "total_iterations": (1, None, True, True),
    "clip_eps": (0.0, None, False, True),
    "gamma": (0.0, 1.0, True, True),
    "gae_lambda": (0.0, 1.0, True, True),
    "vf_coef": (0.0, None, True, True),
    "max_grad_norm": (0.0, None, False, True),
    "eps_init": (0.0, 1.0, True, False),
    "eps_decay": (0.0, 1.0, True, True),
    "sigma_min_init": (0.0, None, True, True),
    "sigma_min_decay": (0.0, 1.0, True, True),
    "sigma_init_scale": (0.0, None, False, True),
    **{f"lr_scale_{g}": (0.0, None, False, True) for g in ("partition", "L", "b", "log_sigma", "log_std", "critic")},
    "init_log_std": (-5.0, 2.0, True, True),
}
# which lr_scale_* sets each parameter group's learning rate (a group absent here takes lr itself)
LR_GROUPS = {"partition": "lr_scale_partition", "L": "lr_scale_L", "b": "lr_scale_b", "log_sigma": "lr_scale_log_sigma",
             "log_std": "lr_scale_log_std"}


def allowed_range(name: str) -> str:
    lo, hi, lo_in, hi_in = HPARAM_RANGES[name]
    if hi is None:
        return f">= {lo:g}" if lo_in else f"> {lo:g}"
    return f"in {'[' if lo_in else '('}{lo:g}, {hi:g}{']' if hi_in else ')'}"


def check_hparam(name: str, value: Any) -> None:
    """Raise ValueError '<name> must be <range>, got <value>' unless value is a finite number in range."""
    if name not in HPARAM_RANGES:
        raise ValueError(f"unknown hyperparameter {name!r}; known: {', '.join(HPARAM_RANGES)}")
    lo, hi, lo_in, hi_in = HPARAM_RANGES[name]
    v = float(value)
    ok = math.isfinite(v) and (v >= lo if lo_in else v > lo) and (hi is None or (v <= hi if hi_in else v < hi))
    if name in _INT_HPARAMS and ok:
        ok = v == int(v)
    if not ok:
        kind = "an integer " if name in _INT_HPARAMS else ""
        raise ValueError(f"{name} must be {kind}{allowed_range(name)}, got {value!r}")


def validate_hparams(cfg: Config | None, hp: Hparams | dict) -> None:
    """Every hyperparameter of an Hparams (or a dict of some of them) in range (HPARAM_RANGES) and K <= k_max:
    the one check of train, sweep and bench."""
    values = hp._asdict() if isinstance(hp, Hparams) else hp
    for name in HPARAM_RANGES:
        if name in values:
            check_hparam(name, float(values[name]))
    k = int(values["K"]) if "K" in values else 1
    if cfg is not None and cfg.policy == MIXTURE and not 1 <= k <= cfg.k_max:
        raise ValueError(f"clusters K must be in 1..k_max={cfg.k_max}, got {k}")
