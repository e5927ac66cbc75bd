"""Whole episodes without auto-reset, as the deterministic evaluation, the scorers and the inspection
roll them out: the one rule for what an ended or failed episode adds.

An episode that ended keeps its last state and adds no reward. Stepping a task past its end is not
harmless: Brax's inverted_double_pendulum, stepped on after its poles fell, drives its cart off the
rail (|x| ~ 1e6 m after ~300 steps) until MJX returns NaN, and `alive * reward` with alive = 0 is
still NaN. An episode whose step gives a non-finite reward or observation while it is alive has
*failed*: it ends at its last finite step (that step adds nothing) and is counted, so a score says
how many of its episodes the physics lost instead of turning NaN or being skipped.
"""

from typing import Any

import jax
import jax.numpy as jnp


def step_episodes(env: Any, state: Any, action: jax.Array, alive: jax.Array) -> tuple:
    """One step of E episodes: (state, reward [E], alive [E], failed [E] bool).

    state: the env's batched state (leading axis E); action [E, d_a]; alive [E] float (1 while the
    episode runs). reward is 0 where the episode had ended or fails at this step; failed marks the
    episodes that failed at this step; ended and failed episodes keep their last finite state."""
    stepped = jax.vmap(env.step)(state, action)
    live = alive > 0
    finite = jnp.isfinite(stepped.reward) & jnp.all(jnp.isfinite(stepped.obs.reshape(live.shape[0], -1)), axis=-1)
    advance = live & finite
    kept = jax.tree.map(lambda new, old: jnp.where(advance.reshape(advance.shape + (1,) * (new.ndim - 1)), new, old),
                        stepped, state)
    reward = jnp.where(advance, stepped.reward, 0.0)
    still = jnp.where(advance, 1.0 - stepped.done, 0.0).astype(alive.dtype)
    return kept, reward, still, live & ~finite
