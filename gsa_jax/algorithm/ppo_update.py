"""PPO's update: the clipped surrogate on the joint probability of (cluster, action) plus the value loss, the
minibatch shuffle, and num_epochs of shuffled minibatch Adam steps with global-norm clipping, each parameter group at
its own learning rate."""

from typing import Any

import jax
import jax.numpy as jnp

from gsa_jax.algorithm.config import LR_GROUPS, Hparams
from gsa_jax.algorithm.optim import adam_step, clip_by_global_norm
from gsa_jax.algorithm.run_parts import Parts, value


def ppo_loss(p: Parts, params: dict, mb: dict, hp: Hparams, sched: dict) -> tuple:
    """Clipped surrogate on the joint log-probability of (cluster, action) + vf_coef x value loss; (loss, aux)."""
    logp = p.v_log_prob(params["policy"], mb["obs"], mb["action"], mb["cluster"], sched)
    log_ratio = logp - mb["logp"]
    ratio = jnp.exp(log_ratio)
    adv = (mb["adv"] - jnp.mean(mb["adv"])) / (jnp.std(mb["adv"]) + 1e-8)
    clipped = jnp.clip(ratio, 1.0 - hp.clip_eps, 1.0 + hp.clip_eps)
    pg_loss = -jnp.mean(jnp.minimum(ratio * adv, clipped * adv))
    v_loss = value_loss(params["value"], mb)
    aux = {
        "policy_loss": pg_loss,
        "value_loss": v_loss,
        "approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
        "clip_fraction": jnp.mean((jnp.abs(ratio - 1.0) > hp.clip_eps).astype(jnp.float32)),
    }
    return pg_loss + hp.vf_coef * v_loss, aux


def value_loss(params: Any, mb: dict) -> jax.Array:
    """Half the mean squared error of V: on the minibatch's own samples (GAE targets), or, with Retrace,
    on v_obs [mb, N, d_s] / v_target [mb, N] of the buffer's slots, weighted by v_weight [mb, N] (0: empty)."""
    if "v_obs" not in mb:
        return 0.5 * jnp.mean(jnp.square(value(params, mb["obs"]) - mb["target"]))
    sq = jnp.square(value(params, mb["v_obs"]) - mb["v_target"])
    return 0.5 * jnp.sum(mb["v_weight"] * sq) / jnp.maximum(jnp.sum(mb["v_weight"]), 1.0)


def shuffle(key: jax.Array, n: int) -> jax.Array:
    """A random permutation of range(n) [n] (int32): shuffle_by_sorts with the random bits that fit above
    the index bits of a uint32 key and enough rounds that a pair ties in every round with probability
    below 2^-10 / (n^2 / 2); beyond 2^24 items, jax.random.permutation."""
    index_bits = max(1, (n - 1).bit_length())
    random_bits = 32 - index_bits
    if random_bits < 8:
        return jax.random.permutation(key, n)
    return shuffle_by_sorts(key, n, random_bits, -(-(2 * index_bits + 10) // random_bits))


def shuffle_by_sorts(key: jax.Array, n: int, random_bits: int, rounds: int) -> jax.Array:
    """A random permutation of range(n) [n] (int32) from `rounds` sorts of uint32 keys, each `random_bits`
    random bits above an item's position: XLA:CPU sorts one integer operand several times faster than
    argsort's (key, index) pairs. Items whose random bits tie keep the previous
    round's order, itself random after the first round."""
    index_bits = 32 - random_bits
    if n > 1 << index_bits:
        raise ValueError(f"{n} items do not fit {index_bits} index bits")
    low = jnp.uint32((1 << index_bits) - 1)
    position = jnp.arange(n, dtype=jnp.uint32)
    perm = position
    for k in jax.random.split(key, rounds):
        keys = (jax.random.bits(k, (n,), jnp.uint32) & ~low) | position
        perm = perm[jax.lax.sort(keys) & low]
    return perm.astype(jnp.int32)


def group_learning_rates(params: dict, hp: Hparams, lr: jax.Array) -> dict:
    """A pytree like params of each leaf's learning rate: lr x the lr_scale_* of its group (LR_GROUPS; the
    critic lr_scale_critic; flat PPO's MLP lr itself). A scale of 1 gives lr bit for bit."""
    policy = {name: jax.tree.map(lambda _, n=name: lr * getattr(hp, LR_GROUPS[n]) if n in LR_GROUPS else lr, sub)
              for name, sub in params["policy"].items()}
    return {"policy": policy, "value": jax.tree.map(lambda _: lr * hp.lr_scale_critic, params["value"])}


def minibatch_gradients(p: Parts, params: dict, mb: dict, hp: Hparams, sched: dict) -> tuple:
    """(gradients of ppo_loss like params, its aux metrics) on one minibatch."""
    return jax.grad(lambda prm: ppo_loss(p, prm, mb, hp, sched), has_aux=True)(params)


def apply_gradients(params: dict, opt: dict, grads: dict, hp: Hparams, lrs: dict) -> tuple:
    """Global-norm clipping and one Adam step -> (params, opt, norm before clipping)."""
    grads, gnorm = clip_by_global_norm(grads, hp.max_grad_norm)
    params, opt = adam_step(params, grads, opt, lrs)
    return params, opt, gnorm


def epoch_minibatches(p: Parts, batch: dict, key: jax.Array) -> dict:
    """One epoch's minibatches: the batch [B, ...] shuffled (key) into [num_minibatches, minibatch_size, ...]."""
    perm = shuffle(key, p.cfg.batch_size)
    return jax.tree.map(lambda x: x[perm].reshape((p.cfg.num_minibatches, p.cfg.minibatch_size) + x.shape[1:]), batch)


def sgd_update(p: Parts, params: dict, opt: dict, batch: dict, hp: Hparams, sched: dict, lr: jax.Array,
               key: jax.Array) -> tuple:
    """cfg.num_epochs epochs of shuffled minibatch Adam steps (each parameter group at its own rate,
    group_learning_rates) -> (params, opt, mean stats)."""
    lrs = group_learning_rates(params, hp, lr)

    def minibatch(carry, mb):
        params, opt = carry
        grads, aux = minibatch_gradients(p, params, mb, hp, sched)
        params, opt, gnorm = apply_gradients(params, opt, grads, hp, lrs)
        return (params, opt), dict(aux, grad_norm=gnorm)

    def epoch(carry, k):
        return jax.lax.scan(minibatch, carry, epoch_minibatches(p, batch, k))

    (params, opt), stats = jax.lax.scan(epoch, (params, opt), jax.random.split(key, p.cfg.num_epochs))
    return params, opt, jax.tree.map(jnp.mean, stats)
