"""Multilayer perceptrons as plain pytrees: a list of {'w': [d_in, d_out], 'b': [d_out]} layers."""

import math
from typing import Callable, Sequence

import jax
import jax.numpy as jnp


def gaussians(keys: jax.Array, shapes: Sequence[tuple]) -> list:
    """[jax.random.normal(keys[i], shapes[i]) for each i] (float32), drawn as one batched draw of the largest size.

    Why: XLA:CPU compiles each draw's threefry and inverse-erf code anew; with a draw per layer, a sweep worker's init
    program compiled for longer than its training chunk (experiments/compile_time/README.md, "One draw for a network's
    Gaussians"). With JAX's partitionable threefry keys (its default) an element's bits depend only on its key and flat
    index, so each slice of the larger draw holds the very numbers of its own draw (tests/test_math.py); with other
    keys or threefry settings, each shape is drawn alone."""
    if not (jax.config.jax_threefry_partitionable and jax.config.jax_default_prng_impl == "threefry2x32"):
        return [jax.random.normal(k, s, jnp.float32) for k, s in zip(keys, shapes)]
    n = max(math.prod(s) for s in shapes)
    flat = jax.vmap(lambda k: jax.random.normal(k, (n,), jnp.float32))(keys)
    return [flat[i, :math.prod(s)].reshape(s) for i, s in enumerate(shapes)]


def orthogonal(key: jax.Array, shape: tuple, scale: float = 1.0, iterations: int = 60) -> jax.Array:
    """A random (semi-)orthogonal matrix [d_in, d_out] times `scale`: orthogonal_from a Gaussian matrix."""
    d_in, d_out = shape
    return orthogonal_from(jax.random.normal(key, (max(d_in, d_out), min(d_in, d_out)), jnp.float32), shape, scale,
                           iterations)


def orthogonal_from(a: jax.Array, shape: tuple, scale: float = 1.0, iterations: int = 60) -> jax.Array:
    """The orthogonal polar factor of a Gaussian matrix a [max(d_in, d_out), min(d_in, d_out)], as [d_in, d_out],
    times `scale`, by Newton-Schulz iteration (matmuls only).

    Why not jax.nn.initializers.orthogonal: it calls LAPACK QR, and vmapped over runs that is a batched
    QR whose kernel waits on XLA:CPU's own thread pool from inside it; two at once on a 2-core machine
    deadlock the process (all threads waiting, no CPU). Seen here in vmapped sweeps.
    """
    d_in, d_out = shape
    x = a / jnp.linalg.norm(a)  # all singular values in (0, 1]
    # X <- X (3 I - X^T X) / 2 drives every singular value to 1; a loop, not unrolled: XLA compiles one body
    # instead of 2 x iterations matmuls per layer (equal to the unrolled iterations up to float rounding)
    x = jax.lax.fori_loop(0, iterations, lambda _, x: 1.5 * x - 0.5 * x @ (x.T @ x), x)
    x = x if d_in >= d_out else x.T
    return scale * x


def init_mlp(key: jax.Array, sizes: Sequence[int], hidden_scale: float = math.sqrt(2.0),
             out_scale: float = 1.0) -> list:
    """Orthogonal init (the usual PPO choice); biases zero.

    sizes: (d_in, h1, ..., d_out). out_scale=0 gives a zero last layer, whose
    outputs then do not depend on the random key nor on d_out (used by the
    partition head so that padding K to K_max does not change the init).
    """
    keys = jax.random.split(key, len(sizes) - 1)
    shapes = list(zip(sizes[:-1], sizes[1:]))
    scales = [hidden_scale] * (len(shapes) - 1) + [out_scale]
    drawn = [i for i, scale in enumerate(scales) if scale != 0.0]  # a zero last layer draws nothing
    normals = dict(zip(drawn, gaussians(keys[jnp.array(drawn)], [(max(shapes[i]), min(shapes[i])) for i in drawn])
                                     if drawn else []))
    layers = []
    for i, ((d_in, d_out), scale) in enumerate(zip(shapes, scales)):
        w = orthogonal_from(normals[i], (d_in, d_out), scale) if i in normals else jnp.zeros((d_in, d_out), jnp.float32)
        layers.append({"w": w, "b": jnp.zeros((d_out,), jnp.float32)})
    return layers


def apply_mlp(layers: list, x: jax.Array, activation: Callable = jnp.tanh) -> jax.Array:
    """x: [..., d_in] -> [..., d_out]; activation between layers, none after the last."""
    for layer in layers[:-1]:
        x = activation(x @ layer["w"] + layer["b"])
    last = layers[-1]
    return x @ last["w"] + last["b"]
