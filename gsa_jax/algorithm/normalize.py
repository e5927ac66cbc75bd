"""Running mean/variance statistics (Chan et al. parallel update) for observation and return normalization."""

import jax
import jax.numpy as jnp


def init_stats(size: int | None) -> dict:
    """Stats for vectors of length `size` (None: scalars). count starts tiny so the first batch dominates."""
    shape = () if size is None else (size,)
    return {
        "count": jnp.full((), 1e-4, jnp.float32),
        "mean": jnp.zeros(shape, jnp.float32),
        "var": jnp.ones(shape, jnp.float32),
    }


def update_stats(stats: dict, batch: jax.Array) -> dict:
    """Merge a batch [..., size] (all leading axes are samples) into the stats."""
    event_ndim = stats["mean"].ndim
    axes = tuple(range(batch.ndim - event_ndim))
    n = jnp.asarray(batch.size // max(1, stats["mean"].size), jnp.float32)
    b_mean = jnp.mean(batch, axis=axes)
    b_var = jnp.var(batch, axis=axes)
    count = stats["count"] + n
    delta = b_mean - stats["mean"]
    mean = stats["mean"] + delta * n / count
    m2 = stats["var"] * stats["count"] + b_var * n + jnp.square(delta) * stats["count"] * n / count
    return {"count": count, "mean": mean, "var": m2 / count}


def normalize(stats: dict, x: jax.Array, clip: float = 10.0) -> jax.Array:
    """(x - mean) / std, clipped to [-clip, clip]."""
    return jnp.clip((x - stats["mean"]) / jnp.sqrt(stats["var"] + 1e-8), -clip, clip)
