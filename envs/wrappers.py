"""Time limit and auto-reset for single (unbatched) environments with Brax's interface (envs/interface.py).

Like Brax's EpisodeWrapper + AutoResetWrapper (by default an ended episode restarts from the state its env
was first reset to; `info['truncation']` tells a time-limit end from a termination), with two additions:
`info['final_obs']` holds the true last observation of the step, before the reset replaced it (the value
bootstrap needs it), and reset mode 'fresh', where every episode starts from a new draw of the task's
start-state law (as gymnasium's and dm_control's resets do): with 'first', a run of n envs sees n start
states in all, which matters for a task that draws its goal at reset.
"""

import jax
import jax.numpy as jnp

from envs.interface import Wrapper
from envs.names import RESET_MODES


class EpisodeLimit(Wrapper):
    """Ends episodes after `episode_length` steps; sets info['steps'], info['truncation']."""

    def __init__(self, env, episode_length):
        super().__init__(env)
        self.episode_length = int(episode_length)
        self._obs_size = None

    @property
    def observation_size(self):
        # Brax computes this by running reset() eagerly, op by op (~20 s of tiny compiles for MJX
        # hopper on a CPU); tracing it with eval_shape costs milliseconds.
        if self._obs_size is None:
            self._obs_size = int(jax.eval_shape(self.env.reset, jax.random.PRNGKey(0)).obs.shape[-1])
        return self._obs_size

    def reset(self, rng):
        state = self.env.reset(rng)
        state.info["steps"] = jnp.zeros((), jnp.int32)
        state.info["truncation"] = jnp.zeros((), jnp.float32)
        return state.replace(reward=state.reward.astype(jnp.float32), done=state.done.astype(jnp.float32))

    def step(self, state, action):
        if action.shape[-1:] != (self.action_size,):
            raise ValueError(f"action has shape {action.shape}; this environment takes ({self.action_size},)")
        steps = state.info["steps"] + 1
        state = self.env.step(state, action)
        terminated = state.done.astype(jnp.float32)
        timeout = (steps >= self.episode_length).astype(jnp.float32)
        state.info["steps"] = steps
        state.info["truncation"] = timeout * (1.0 - terminated)
        return state.replace(reward=state.reward.astype(jnp.float32), done=jnp.maximum(terminated, timeout))


class AutoReset(Wrapper):
    """On done, swap in a start state: the env's first (mode 'first', Brax's convention) or a new draw of the
    task's reset from the env's own key sequence (mode 'fresh'; one reset is computed per step and kept where
    an episode ended). The true last obs stays in info['final_obs']. A restart takes the new start's
    pipeline_state and obs only: a task that keeps its goal in state.info (not in pipeline_state) keeps the old
    goal in mode 'fresh'."""

    def __init__(self, env, mode="first"):
        super().__init__(env)
        if mode not in RESET_MODES:
            raise ValueError(f"reset mode must be one of {', '.join(RESET_MODES)}, got {mode!r}")
        self.mode = mode

    def reset(self, rng):
        if self.mode == "first":
            return self.started(self.env.reset(rng))
        key, rng = jax.random.split(rng)
        state = self.env.reset(rng)
        state.info["reset_key"] = key
        state.info["final_obs"] = state.obs
        return state

    def started(self, state):
        """A start state of the wrapped env as this env's start state in mode 'first' (reset(rng) is
        started(self.env.reset(rng))): its episodes restart there. Lets a reset of the wrapped env computed
        elsewhere (one compiled reset shared with the evaluation: gsa_jax.running.programs) start training."""
        if self.mode != "first":
            raise ValueError(f"started() is reset mode 'first''s; this env resets in mode {self.mode!r}")
        state.info["first_pipeline_state"] = state.pipeline_state
        state.info["first_obs"] = state.obs
        state.info["final_obs"] = state.obs
        return state

    def _start(self, state, done):
        """(pipeline_state, obs) an episode ended in `state` restarts from; advances the env's reset key. An env with
        reset_where(rng, needed) (a start law run on the host: envs/c_backend.py, envs/task_mjx.py) computes the
        reset only where `done`."""
        if self.mode == "first":
            return state.info["first_pipeline_state"], state.info["first_obs"], state.info
        key, sub = jax.random.split(state.info["reset_key"])
        reset_where = getattr(self.env, "reset_where", None)
        new = reset_where(sub, done) if reset_where else self.env.reset(sub)
        return new.pipeline_state, new.obs, {**state.info, "reset_key": key}

    def step(self, state, action):
        # the previous step may have ended an episode and already been reset: start the new one clean
        state = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
        done = state.done > 0.5

        def pick(first, current):
            return jnp.where(done, first, current)

        start, start_obs, info = self._start(state, done)
        pipeline_state = jax.tree.map(pick, start, state.pipeline_state)
        info["final_obs"] = state.obs
        info["steps"] = jnp.where(done, 0, state.info["steps"])
        return state.replace(pipeline_state=pipeline_state, obs=pick(start_obs, state.obs), info=info)
