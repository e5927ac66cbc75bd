"""gsa_jax.algorithm.episodes: what an ended or failed episode adds to a deterministic evaluation, against a NumPy
reference, on a toy task whose physics turns NaN after its episodes end (as Brax's inverted double
pendulum does) or, for chosen episodes, while they are alive."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm.episodes import step_episodes


class ToyState(NamedTuple):
    t: jax.Array  # steps taken
    obs: jax.Array  # [2]
    reward: jax.Array
    done: jax.Array


class Toy:
    """Reward t + seed per step; the episode ends after `seed` steps; stepped past its end its
    observation and reward are NaN; an episode with seed == fail_seed gives NaN at its step 3."""

    def __init__(self, fail_seed):
        self.fail_seed = fail_seed

    def reset(self, seed):
        return ToyState(jnp.zeros((), jnp.int32), jnp.stack([seed, 0.0]), jnp.zeros(()), jnp.zeros(()))

    def step(self, s, action):
        t = s.t + 1
        seed = s.obs[0]
        bad = (t > seed) | ((seed == self.fail_seed) & (t == 3))
        r = jnp.where(bad, jnp.nan, t + seed + 0.0 * action[0])
        return ToyState(t, jnp.stack([seed, jnp.where(bad, jnp.nan, t * 1.0)]), r, (t >= seed).astype(jnp.float32))


def run(env, seeds, steps):
    s = jax.vmap(env.reset)(jnp.asarray(seeds, jnp.float32))
    alive, ret, failed = jnp.ones(len(seeds)), jnp.zeros(len(seeds)), jnp.zeros(len(seeds), bool)
    for _ in range(steps):
        s, r, alive, f = step_episodes(env, s, jnp.zeros((len(seeds), 1)), alive)
        ret, failed = ret + r, failed | f
    return np.asarray(ret), np.asarray(failed), s


def test_ended_episodes_add_nothing_and_keep_their_state():
    """Stepping on past an episode's end would give NaN; its return is the NumPy sum up to its end."""
    seeds = [1.0, 2.0, 5.0]
    ret, failed, s = run(Toy(fail_seed=-1), seeds, 8)
    expect = [sum(t + sd for t in range(1, int(sd) + 1)) for sd in seeds]
    np.testing.assert_array_equal(ret, expect)
    assert not failed.any()
    np.testing.assert_array_equal(np.asarray(s.t), [1, 2, 5])  # frozen at its last step
    assert np.isfinite(np.asarray(s.obs)).all()


def test_an_episode_that_turns_non_finite_while_alive_fails_and_ends_at_its_last_finite_step():
    seeds = [2.0, 5.0, 6.0]
    ret, failed, s = run(Toy(fail_seed=5.0), seeds, 8)
    expect = [3 + 4, (1 + 5) + (2 + 5), sum(t + 6 for t in range(1, 7))]  # seed 5: steps 1-2 only
    np.testing.assert_array_equal(ret, expect)
    assert failed.tolist() == [False, True, False]
    assert int(s.t[1]) == 2 and np.isfinite(np.asarray(s.obs)).all()
