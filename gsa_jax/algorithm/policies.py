"""Policies: the mixture of linear-Gaussian controllers (paper Sec. III-C, IV) and the flat Gaussian MLP baseline.

Both are given as a `Policy` of pure functions on one observation (vmap for batches):

    init(key, hp)                          -> params
    sample(params, obs, noise, sched)      -> (action [d_a], cluster int32, log_prob); noise: draw_noise's
                                              draws for one observation, drawn ahead for a whole rollout
    log_prob(params, obs, action, cluster, sched) -> log pi(c, a | s)
    mode(params, obs, sched)               -> (action [d_a], cluster): the deterministic controller
    partition_probs(params, obs, sched)    -> [K_max] (mixture) or [1] (mlp)

`sched` is a dict of traced scalars: K (active clusters, int32), epsilon (uniform
exploration of the partition), sigma_min (floor of every sub-policy std).

Mixture: pi(c, a | s) = pi_p(c | s) N(a | L_c phi(s) + b_c, diag(max(sigma_c, sigma_min)^2)),
pi_p = (1 - eps) softmax(logits(s))[active] + eps / K on the K active clusters.
The logits are the partition class's (gsa_jax/algorithm/partitions.py, one entry each): mlp (the paper's tanh MLP,
the default) or linear (W s + c: polyhedral cells).
phi is the sub-policy class (the paper's second complexity knob; gsa_jax/algorithm/subpolicies.py, one entry
each): constant (phi = [], one action per cluster: classic state abstraction), linear (phi = s, the default),
quadratic (phi = [s, upper-triangular s (x) s]).
Params: partition (layers d_s -> ... -> K_max, its last zero at init), L [K_max, d_a, d_phi], b [K_max, d_a],
log_sigma [K_max, d_a]. Clusters c >= K are masked: probability exactly 0, excluded from
the uniform part, never sampled; every quantity (init, samples, log-probs, modes) is the
same for a K inside any K_max >= K.
"""

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.kinds import MIXTURE, MLP, POLICY_KINDS
from gsa_jax.algorithm.nn import apply_mlp, init_mlp

_LOG_2PI = float(np.log(2.0 * np.pi))
_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71, 73, 79, 83, 89, 97)


class Policy(NamedTuple):
    """A policy's pure functions (make_mixture_policy / make_mlp_policy say what each takes)."""

    init: Callable
    sample: Callable
    log_prob: Callable
    mode: Callable
    partition_probs: Callable


def halton(n: int, dim: int) -> np.ndarray:
    """First n points of the Halton sequence in [0, 1)^dim (row i depends on i only). [n, dim]."""
    if dim > len(_PRIMES):
        raise ValueError(f"halton: dim {dim} > {len(_PRIMES)}")
    out = np.zeros((n, dim))
    for j in range(dim):
        base = _PRIMES[j]
        for i in range(n):
            f, r, k = 1.0, 0.0, i
            while k > 0:
                f /= base
                r += f * (k % base)
                k //= base
            out[i, j] = r
    return out


def bias_spread(n: int, action_size: int, scale: float = 1.0) -> np.ndarray:
    """Diverse initial biases b_c in [-scale, scale)^d_a: a Halton set shifted by 1/2, so cluster 0 sits
    at the centre of the action box and the first K points spread over it for every K. [n, d_a]."""
    return (scale * (2.0 * np.mod(halton(n, action_size) + 0.5, 1.0) - 1.0)).astype(np.float32)


def draw_noise(key: jax.Array, shape: tuple, action_size: int) -> dict:
    """The random draws `sample` turns into actions, for a batch `shape` of observations at once (one
    generator call for a whole rollout instead of several per step): {"u": uniform [0, 1) [*shape] (the
    cluster), "z": standard normal [*shape, d_a] (the action)}."""
    k_c, k_a = jax.random.split(key)
    return {"u": jax.random.uniform(k_c, shape), "z": jax.random.normal(k_a, (*shape, action_size))}


def gaussian_log_prob(x: jax.Array, mean: jax.Array, sigma: jax.Array) -> jax.Array:
    """Sum over the last axis of log N(x | mean, diag sigma^2)."""
    z = (x - mean) / sigma
    return jnp.sum(-0.5 * jnp.square(z) - jnp.log(sigma) - 0.5 * _LOG_2PI, axis=-1)


def feature_size(subpolicy: str, obs_size: int) -> int:
    """d_phi: length of the sub-policy features of a d_s observation (gsa_jax.algorithm.subpolicies)."""
    return subpolicies.get(subpolicy).size(obs_size)


def subpolicy_features(subpolicy: str, obs: jax.Array) -> jax.Array:
    """phi(s) [d_phi] for one observation [d_s] (gsa_jax.algorithm.subpolicies): [] | s | [s, s_i s_j for i <= j]."""
    return subpolicies.get(subpolicy).features(obs, jnp)


def component(params: dict, phi: jax.Array, c: jax.Array, sigma_min: jax.Array) -> tuple:
    """Cluster c's Gaussian of the mixture's params for features phi [d_phi]: mean [d_a] and std [d_a]
    (exp(log_sigma) floored at sigma_min). Every cluster's mean L phi + b [K_max, d_a], then c's by a one-hot
    product (the same value): the batched gradient is then dense products instead of a scatter into L, which
    is faster on XLA:CPU (measured in experiments/bench_c_backend/)."""
    means = params["L"] @ phi + params["b"]
    mean = jax.nn.one_hot(c, means.shape[0], dtype=means.dtype) @ means
    return mean, jnp.maximum(jnp.exp(params["log_sigma"][c]), sigma_min)


def make_mixture_policy(obs_size: int, action_size: int, k_max: int, hidden: tuple = (64, 64), b_init_scale: float = 1.0,
                        subpolicy: str = subpolicies.DEFAULT, partition: str = partitions.DEFAULT) -> Policy:
    bias_init = jnp.asarray(bias_spread(k_max, action_size, b_init_scale))
    d_phi = feature_size(subpolicy, obs_size)
    partition_sizes = partitions.get(partition).sizes(obs_size, hidden, k_max)

    def init(key, hp):
        k = jnp.asarray(hp.K, jnp.float32)
        return {
            # zero last layer: uniform partition at init, independent of K_max
            "partition": init_mlp(key, partition_sizes, out_scale=0.0),
            "L": jnp.zeros((k_max, action_size, d_phi), jnp.float32),
            "b": bias_init,
            "log_sigma": jnp.full((k_max, action_size), 1.0, jnp.float32)
            * jnp.log(hp.sigma_init_scale / k),
        }

    def _log_softmax(params, obs, sched):
        """Masked logits and their log-softmax: [K_max] each, -inf on masked clusters."""
        active = jnp.arange(k_max) < sched["K"]
        logits = jnp.where(active, apply_mlp(params["partition"], obs), -jnp.inf)
        return jax.nn.log_softmax(logits), logits

    def _log_uniform(sched):
        return jnp.log(sched["epsilon"]) - jnp.log(sched["K"].astype(jnp.float32))

    def _component(params, obs, c, sched):
        return component(params, subpolicy_features(subpolicy, obs), c, sched["sigma_min"])

    def partition_probs(params, obs, sched):
        log_soft, _ = _log_softmax(params, obs, sched)
        active = jnp.arange(k_max) < sched["K"]
        uniform = jnp.where(active, sched["epsilon"] / sched["K"].astype(jnp.float32), 0.0)
        return (1.0 - sched["epsilon"]) * jnp.exp(log_soft) + uniform

    def sample(params, obs, noise, sched):
        probs = partition_probs(params, obs, sched)
        # inverse-CDF draw: masked clusters add exact zeros to the CDF, so the draw is K_max-independent
        cdf = jnp.cumsum(probs)
        c = jnp.minimum(jnp.sum(cdf < noise["u"] * cdf[-1]), sched["K"] - 1).astype(jnp.int32)
        mean, sigma = _component(params, obs, c, sched)
        a = mean + sigma * noise["z"]
        return a, c, log_prob(params, obs, a, c, sched)

    def log_prob(params, obs, action, cluster, sched):
        # log-space mix of the chosen (always active) cluster only: no -inf - -inf anywhere, so no NaN
        # can leak into gradients through masked clusters
        log_soft, _ = _log_softmax(params, obs, sched)
        log_pc = jnp.logaddexp(jnp.log1p(-sched["epsilon"]) + log_soft[cluster], _log_uniform(sched))
        mean, sigma = _component(params, obs, cluster, sched)
        return log_pc + gaussian_log_prob(action, mean, sigma)

    def mode(params, obs, sched):
        _, logits = _log_softmax(params, obs, sched)
        c = jnp.argmax(logits).astype(jnp.int32)
        return _component(params, obs, c, sched)[0], c

    return Policy(init, sample, log_prob, mode, partition_probs)


def make_mlp_policy(obs_size: int, action_size: int, hidden: tuple = (64, 64)) -> Policy:
    """Flat baseline: mean = tanh-MLP(s), state-independent log-std initialised to 0."""

    def init(key, hp):
        return {
            "mlp": init_mlp(key, (obs_size, *hidden, action_size), out_scale=0.01),
            "log_std": jnp.full((action_size,), 1.0, jnp.float32) * hp.init_log_std,
        }

    def sample(params, obs, noise, sched):
        mean = apply_mlp(params["mlp"], obs)
        sigma = jnp.exp(params["log_std"])
        a = mean + sigma * noise["z"]
        return a, jnp.zeros((), jnp.int32), gaussian_log_prob(a, mean, sigma)

    def log_prob(params, obs, action, cluster, sched):
        return gaussian_log_prob(action, apply_mlp(params["mlp"], obs), jnp.exp(params["log_std"]))

    def mode(params, obs, sched):
        return apply_mlp(params["mlp"], obs), jnp.zeros((), jnp.int32)

    def partition_probs(params, obs, sched):
        return jnp.ones((1,), jnp.float32)

    return Policy(init, sample, log_prob, mode, partition_probs)


def make_policy(kind: str, obs_size: int, action_size: int, k_max: int = 1, hidden: tuple = (64, 64),
                b_init_scale: float = 1.0, subpolicy: str = subpolicies.DEFAULT,
                partition: str = partitions.DEFAULT) -> Policy:
    if kind == MIXTURE:
        return make_mixture_policy(obs_size, action_size, k_max, hidden, b_init_scale, subpolicy, partition)
    if kind == MLP:
        return make_mlp_policy(obs_size, action_size, hidden)
    raise ValueError(f"unknown policy {kind!r}; choose one of {', '.join(POLICY_KINDS)}")


def partition_entropy(probs: jax.Array) -> jax.Array:
    """Entropy of a categorical distribution [..., K] in nats (0 log 0 = 0)."""
    h = -jnp.sum(jnp.where(probs > 0, probs * jnp.log(jnp.where(probs > 0, probs, 1.0)), 0.0), axis=-1)
    return jnp.maximum(h, 0.0)  # no "-0.0" for a single cluster
