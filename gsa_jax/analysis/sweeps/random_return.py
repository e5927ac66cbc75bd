"""The return of a uniformly random policy in a task, stepped by the physics backend its sweep trained with: the
score a normalized score calls 0 (gsa_jax.analysis.sweeps.results.random_returns_of)."""

import jax
import jax.numpy as jnp

import envs
from envs.families.record import TaskRecord
from envs.physics import Physics
from gsa_jax.algorithm.episodes import step_episodes


def random_policy_return(task: TaskRecord, episodes: int = 16, seed: int = 0, episode_length: int | None = None,
                         backend: str = "mjx") -> float:
    """Mean return of uniformly random actions in [-1, 1] over `episodes` full episodes of a task (the
    score that normalizes to 0; task: its record), from the start states of PRNGKey(seed), stepped by `backend` ('mjx' or 'c':
    the one the sweep trained with, since MJX cannot step every task)."""
    env = envs.make(task, episode_length, auto_reset=False, physics=Physics(backend=backend))
    length = episode_length or task.episode_length()

    def run(key):
        k_reset, k_act = jax.random.split(key)
        s0 = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

        def step(carry, k):
            s, ret, alive = carry
            a = jax.random.uniform(k, (episodes, env.action_size), minval=-1.0, maxval=1.0)
            s, reward, alive, _ = step_episodes(env, s, a, alive)
            return (s, ret + reward, alive), None

        zeros = jnp.zeros((episodes,))
        (_, ret, _), _ = jax.lax.scan(step, (s0, zeros, zeros + 1.0), jax.random.split(k_act, length))
        return jnp.mean(ret)

    return float(jax.jit(run)(jax.random.PRNGKey(seed)))
