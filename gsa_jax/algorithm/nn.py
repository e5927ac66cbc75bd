"""Multilayer perceptrons as plain pytrees: a list of {'w': [d_in, d_out], 'b': [d_out]} layers."""

import math
from typing import Callable, Sequence

import jax
import jax.numpy as jnp


def orthogonal(key: jax.Array, shape: tuple, scale: float = 1.0, iterations: int = 60) -> jax.Array:
    """A random (semi-)orthogonal matrix [d_in, d_out] times `scale`: the orthogonal polar factor of a
    Gaussian matrix, by Newton-Schulz iteration (matmuls only).

    Why not jax.nn.initializers.orthogonal: it calls LAPACK QR, and vmapped over runs that is a batched
    QR whose kernel waits on XLA:CPU's own thread pool from inside it; two at once on a 2-core machine
    deadlock the process (all threads waiting, no CPU). Seen here in vmapped sweeps.
    """
    d_in, d_out = shape
    a = jax.random.normal(key, (max(d_in, d_out), min(d_in, d_out)), jnp.float32)
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
    layers = []
    for i, (k, d_in, d_out) in enumerate(zip(keys, sizes[:-1], sizes[1:])):
        last = i == len(sizes) - 2
        scale = out_scale if last else hidden_scale
        if scale == 0.0:
            w = jnp.zeros((d_in, d_out), jnp.float32)
        else:
            w = orthogonal(k, (d_in, d_out), scale)
        layers.append({"w": w, "b": jnp.zeros((d_out,), jnp.float32)})
    return layers


def apply_mlp(layers: list, x: jax.Array, activation: Callable = jnp.tanh) -> jax.Array:
    """x: [..., d_in] -> [..., d_out]; activation between layers, none after the last."""
    for layer in layers[:-1]:
        x = activation(x @ layer["w"] + layer["b"])
    last = layers[-1]
    return x @ last["w"] + last["b"]
