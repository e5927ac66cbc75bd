"""What the pieces of a PPO run share (gsa_jax.algorithm.ppo builds them, gsa_jax.algorithm.ppo_update updates with
them): Parts (the static Config, the tasks, the policy's vmapped methods), TrainState (what a run carries), Trainer
(a run's compiled-to-be functions), and the critic V."""

from typing import Any, Callable, NamedTuple

import jax

from gsa_jax.algorithm.config import Config
from gsa_jax.algorithm.nn import apply_mlp
from gsa_jax.algorithm.normalize import normalize


class Trainer(NamedTuple):
    cfg: Config
    env: object
    policy: object
    init: Callable
    iteration: Callable
    run_chunk: Callable
    evaluate: Callable
    parts: "Parts"


class Parts(NamedTuple):
    """What the pieces of a training run share: the static Config, the tasks and the policy with its vmapped methods."""
    cfg: Config
    env: object
    eval_env: object
    policy: object
    obs_size: int
    v_sample: Callable
    v_log_prob: Callable
    v_mode: Callable
    v_probs: Callable


def value(params: Any, obs: jax.Array) -> jax.Array:
    """V(obs) of the value MLP: [..., d_s] -> [...]."""
    return apply_mlp(params, obs)[..., 0]


def norm_obs(cfg: Config, stats: dict, obs: jax.Array) -> jax.Array:
    return normalize(stats, obs) if cfg.normalize_obs else obs


class TrainState(NamedTuple):
    """Everything one run carries from iteration to iteration (a pytree; a sweep vmaps it over runs)."""

    params: dict  # {'policy': the policy's parameters, 'value': the value MLP}
    opt: dict  # Adam's moments and step count
    obs_stats: dict  # running mean / variance of observations (normalization)
    ret_stats: dict  # running statistics of discounted returns (reward scaling)
    env_state: object  # the num_envs tasks' states
    ep_return: jax.Array  # [num_envs] return of each env's current episode
    disc_return: jax.Array  # [num_envs] its discounted return
    key: jax.Array
    iteration: jax.Array  # int32 scalar: iterations done
    failed_at: jax.Array  # int32 scalar: the iteration whose loss or parameters were non-finite; -1 while healthy
    buffer: dict | None = None  # value_target "retrace": the last iterations' samples (gsa_jax/algorithm/retrace.py); else None
