"""Time limit and auto-reset for single (unbatched) Brax environments.

Like Brax's EpisodeWrapper + AutoResetWrapper (an ended episode restarts from the state
its env was first reset to; `info['truncation']` tells a time-limit end from a
termination), with one addition the value bootstrap needs: `info['final_obs']` holds the
true last observation of the step, before the reset replaced it.
"""

import jax
import jax.numpy as jnp
from brax.envs.base import Wrapper


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
    """On done, swap in the first state of this env (Brax's convention); keep the true last obs in info['final_obs']."""

    def reset(self, rng):
        state = self.env.reset(rng)
        state.info["first_pipeline_state"] = state.pipeline_state
        state.info["first_obs"] = state.obs
        state.info["final_obs"] = state.obs
        return state

    def step(self, state, action):
        # the previous step may have ended an episode and already been reset: start the new one clean
        state = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
        done = state.done > 0.5

        def pick(first, current):
            return jnp.where(done, first, current)

        pipeline_state = jax.tree.map(pick, state.info["first_pipeline_state"], state.pipeline_state)
        state.info["final_obs"] = state.obs
        state.info["steps"] = jnp.where(done, 0, state.info["steps"])
        return state.replace(pipeline_state=pipeline_state, obs=pick(state.info["first_obs"], state.obs))
