"""The single-env interface every backend's environment follows, without importing Brax.

It is Brax's (brax.envs.base): `reset(rng) -> State`, `step(state, action) -> State`, `observation_size`,
`action_size`, `backend`, `unwrapped`; a State with the fields pipeline_state, obs, reward, done, metrics, info and
`replace(**fields)`; a Wrapper that forwards what it does not define to the env it wraps. Backend 'c'
(envs/c_backend.py), the time limit and auto-reset (envs/wrappers.py) and the randomization wrapper
(envs/randomized_env.py) are built on these, so a process that trains on 'c' imports neither Brax nor MJX (several
seconds of imports per worker process). MJX's tasks stay Brax PipelineEnvs with Brax's State: the wrappers use only
what both States have (fields, `replace`), and a State's leaves flatten in the same order as Brax's.
"""

import abc
import dataclasses
from typing import Any

import jax


@dataclasses.dataclass
class State:
    """An environment's state: what the physics carries (pipeline_state), the observation [obs_size], reward [],
    done [] (float: 1 where the episode ended) and dicts of metrics and of what wrappers carry (info)."""

    pipeline_state: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict = dataclasses.field(default_factory=dict)
    info: dict = dataclasses.field(default_factory=dict)

    def replace(self, **fields) -> "State":
        return dataclasses.replace(self, **fields)


jax.tree_util.register_dataclass(State, data_fields=[f.name for f in dataclasses.fields(State)], meta_fields=[])


class Env(abc.ABC):
    """A single (unbatched) environment; batch it with jax.vmap."""

    @abc.abstractmethod
    def reset(self, rng: jax.Array) -> State:
        """A start state drawn from rng."""

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State:
        """One env step from `state` with `action` [action_size]."""

    @property
    @abc.abstractmethod
    def observation_size(self) -> int:
        """The length of obs."""

    @property
    @abc.abstractmethod
    def action_size(self) -> int:
        """The length of an action."""

    @property
    @abc.abstractmethod
    def backend(self) -> str:
        """The physics backend that steps the env."""

    @property
    def unwrapped(self) -> "Env":
        return self


class Wrapper(Env):
    """An env around another (which may be a Brax env): what it does not define is the wrapped env's."""

    def __init__(self, env):
        self.env = env

    def reset(self, rng: jax.Array) -> State:
        return self.env.reset(rng)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    @property
    def unwrapped(self):
        return self.env.unwrapped

    @property
    def backend(self) -> str:
        return self.unwrapped.backend

    def __getattr__(self, name):
        if name == "__setstate__":  # unpickling looks it up before __init__ has set self.env
            raise AttributeError(name)
        return getattr(self.env, name)
