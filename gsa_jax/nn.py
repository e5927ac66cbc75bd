"""Multilayer perceptrons as plain pytrees: a list of {'w': [d_in, d_out], 'b': [d_out]} layers."""

import math

import jax
import jax.numpy as jnp


def init_mlp(key, sizes, hidden_scale=math.sqrt(2.0), out_scale=1.0):
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
            w = jax.nn.initializers.orthogonal(scale)(k, (d_in, d_out), jnp.float32)
        layers.append({"w": w, "b": jnp.zeros((d_out,), jnp.float32)})
    return layers


def apply_mlp(layers, x, activation=jnp.tanh):
    """x: [..., d_in] -> [..., d_out]; activation between layers, none after the last."""
    for layer in layers[:-1]:
        x = activation(x @ layer["w"] + layer["b"])
    last = layers[-1]
    return x @ last["w"] + last["b"]
