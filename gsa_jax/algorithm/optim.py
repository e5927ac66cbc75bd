"""Adam and global-norm gradient clipping as pure functions on pytrees."""

from typing import Any

import jax
import jax.numpy as jnp


def init_adam(params: Any) -> dict:
    """Adam state: first/second moment pytrees shaped like params, and a step count."""
    zeros = jax.tree.map(jnp.zeros_like, params)
    return {"m": zeros, "v": jax.tree.map(jnp.zeros_like, params), "count": jnp.zeros((), jnp.int32)}


def global_norm(tree: Any) -> jax.Array:
    return jnp.sqrt(sum(jnp.sum(jnp.square(x)) for x in jax.tree.leaves(tree)))


def clip_by_global_norm(grads: Any, max_norm: float | jax.Array) -> tuple:
    """Scale grads so their global L2 norm is at most max_norm. Returns (grads, norm before clipping)."""
    norm = global_norm(grads)
    scale = jnp.minimum(1.0, max_norm / jnp.maximum(norm, 1e-12))
    return jax.tree.map(lambda g: g * scale, grads), norm


def adam_step(params: Any, grads: Any, state: dict, lr: Any, b1: float = 0.9, b2: float = 0.999,
              eps: float = 1e-8) -> tuple:
    """One bias-corrected Adam step (Kingma & Ba, Alg. 1). lr: a (traced) scalar, or a pytree like params
    of one per leaf (per-group learning rates)."""
    count = state["count"] + 1
    m = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state["m"], grads)
    v = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * jnp.square(g), state["v"], grads)
    t = count.astype(jnp.float32)
    c1 = 1.0 - b1 ** t
    c2 = 1.0 - b2 ** t
    lrs = lr if isinstance(lr, dict) else jax.tree.map(lambda _: lr, params)
    new_params = jax.tree.map(
        lambda p, m, v, lr: p - lr * (m / c1) / (jnp.sqrt(v / c2) + eps), params, m, v, lrs
    )
    return new_params, {"m": m, "v": v, "count": count}
