"""Retrace value targets over the samples of the last N iterations (Config.value_target = "retrace").

The paper fits its value function with Retrace (Munos et al. 2016), whose point is to reuse samples
that older policies collected. For a state-value function, Retrace's truncated traces give the
recursion (the state-value form also used by V-trace, Espeholt et al. 2018, with both truncations at 1)

    v_t - V(x_t) = rho_t delta_t + gamma c_t (1 - done_t) (v_{t+1} - V(x_{t+1})),
    delta_t = r_t + gamma (1 - term_t) V(x'_t) - V(x_t),
    rho_t = min(1, pi(c_t, a_t | x_t) / mu(c_t, a_t | x_t)),   c_t = lambda rho_t,

with pi the current mixture's joint probability of (cluster, action) -- its epsilon-uniform part and
sigma_min floor at the current iteration included -- and mu the probability under which the sample was
collected. With pi = mu (the current iteration's own samples) it is GAE(lambda)'s target exactly.

The buffer keeps the raw samples of the last N iterations inside the training state (so runs stay pure,
vmappable and resumable): observations are normalized, rewards scaled and both probabilities compared
with the statistics and policy of the iteration that uses them. Each iteration's slot is a [T, E]
block; the recursion runs within a block and bootstraps from V at its end, as GAE does.
"""

from typing import Callable

import jax
import jax.numpy as jnp

FIELDS = ("raw_obs", "raw_next_obs", "action", "cluster", "logp", "reward", "term", "done")


def retrace_targets(rewards: jax.Array, values: jax.Array, next_values: jax.Array, terminations: jax.Array,
                    dones: jax.Array, ratios: jax.Array, gamma: float, lam: float) -> jax.Array:
    """Retrace value targets over time-major arrays [T, ...]; ratios = pi/mu of each sample. -> [T, ...]."""
    rho = jnp.minimum(1.0, ratios)
    deltas = rho * (rewards + gamma * (1.0 - terminations) * next_values - values)
    traces = gamma * lam * rho * (1.0 - dones)

    def back(acc, x):
        delta, trace = x
        acc = delta + trace * acc
        return acc, acc

    _, corrections = jax.lax.scan(back, jnp.zeros_like(values[0]), (deltas, traces), reverse=True)
    return values + corrections


def init_buffer(iterations: int, unroll_length: int, num_envs: int, obs_size: int, action_size: int) -> dict:
    """An empty buffer of `iterations` slots [N, T, E, ...]; filled[N] = 1 where a slot holds samples."""
    shape = (iterations, unroll_length, num_envs)
    zeros = lambda *tail, dtype=jnp.float32: jnp.zeros(shape + tail, dtype)  # noqa: E731
    return {"raw_obs": zeros(obs_size), "raw_next_obs": zeros(obs_size), "action": zeros(action_size),
            "cluster": zeros(dtype=jnp.int32), "logp": zeros(), "reward": zeros(), "term": zeros(), "done": zeros(),
            "filled": jnp.zeros((iterations,), jnp.float32)}


def store(buffer: dict, traj: dict, iteration: jax.Array) -> dict:
    """The buffer with this iteration's trajectory (dict of [T, E, ...]) in slot iteration mod N (the oldest)."""
    slot = iteration % buffer["filled"].shape[0]
    out = {f: buffer[f].at[slot].set(traj[f]) for f in FIELDS}
    out["filled"] = buffer["filled"].at[slot].set(1.0)
    return out


def buffer_bytes(buffer: dict) -> int:
    """Bytes one run's buffer holds."""
    return sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(buffer))


def buffer_targets(buffer: dict, normalize_obs: Callable, value_fn: Callable, log_prob_fn: Callable, ret_scale: jax.Array,
                   gamma: float, lam: float) -> tuple:
    """Retrace targets of every slot with today's normalization, value and policy.

    normalize_obs: raw [..., d_s] -> network input; value_fn: inputs [..., d_s] -> [...];
    log_prob_fn(obs [B, d_s], action [B, d_a], cluster [B]) -> [B] under the current policy.
    Returns (normalized observations [N, T, E, d_s], targets [N, T, E], ratios pi/mu [N, T, E])."""
    obs = normalize_obs(buffer["raw_obs"])
    values, next_values = value_fn(obs), value_fn(normalize_obs(buffer["raw_next_obs"]))
    flat = lambda x: x.reshape((-1,) + x.shape[3:])  # noqa: E731
    logp = log_prob_fn(flat(obs), flat(buffer["action"]), flat(buffer["cluster"])).reshape(buffer["logp"].shape)
    ratios = jnp.exp(jnp.minimum(logp - buffer["logp"], 30.0))  # capped: min(1, .) follows anyway
    targets = jax.vmap(retrace_targets, in_axes=(0, 0, 0, 0, 0, 0, None, None))(
        buffer["reward"] / ret_scale, values, next_values, buffer["term"], buffer["done"], ratios, gamma, lam)
    return obs, targets, ratios
