"""envs/host_call.py: a host function inside the compiled program sees NumPy batches (vmapped as
broadcast_all), returns exactly its declared shapes, works eagerly, under jit and under shard_map, and
refuses derivatives."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs.host_call import host_call

SCRIPT = """
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, PartitionSpec as P
from envs.host_call import host_call
assert len(jax.devices()) == 2
out = jax.ShapeDtypeStruct((3,), jnp.float32)
f = jax.vmap(lambda x: host_call(lambda a: (np.cumsum(a, -1, dtype=np.float32),), (out,), x)[0])
mesh = Mesh(np.array(jax.devices()), ("runs",))
g = jax.jit(jax.shard_map(f, mesh=mesh, in_specs=P("runs"), out_specs=P("runs"), check_vma=False))
x = np.arange(12, dtype=np.float32).reshape(4, 3)
np.testing.assert_array_equal(np.asarray(g(x)), np.cumsum(x, -1))
print("ok")
"""


def affine(seen):
    """A host function that records the shapes it is called with: (x [..., 3], w [..., 3]) -> (x * w + 1, sum x)."""

    def fn(x, w):
        seen.append((type(x), x.shape, w.shape))
        return (x * w + 1).astype(np.float32), np.sum(x, -1).astype(np.int32)

    return fn


SHAPES = (jax.ShapeDtypeStruct((3,), jnp.float32), jax.ShapeDtypeStruct((), jnp.int32))


def test_nested_vmap_is_one_call_on_the_whole_batch():
    seen = []
    fn = affine(seen)
    call = jax.jit(jax.vmap(jax.vmap(lambda x, w: host_call(fn, SHAPES, x, w), in_axes=(0, None)), in_axes=(0, None)))
    x = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    w = np.array([1.0, -2.0, 0.5], np.float32)
    y, s = call(x, w)
    np.testing.assert_array_equal(np.asarray(y), x * w + 1)
    np.testing.assert_array_equal(np.asarray(s), np.sum(x, -1).astype(np.int32))
    assert seen == [(np.ndarray, (2, 4, 3), (2, 4, 3))]  # NumPy arrays; the unbatched w broadcast


def test_eager_call_equals_jitted():
    x = np.ones(3, np.float32)
    eager = host_call(affine([]), SHAPES, x, x)
    jitted = jax.jit(lambda a: host_call(affine([]), SHAPES, a, a))(x)
    for a, b in zip(eager, jitted):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_wrong_result_shape_is_an_error():
    bad = (jax.ShapeDtypeStruct((4,), jnp.float32), jax.ShapeDtypeStruct((), jnp.int32))
    with pytest.raises(Exception, match="Incorrect output shape"):
        jax.block_until_ready(jax.jit(lambda a: host_call(affine([]), bad, a, a))(np.ones(3, np.float32)))


def test_no_derivatives():
    with pytest.raises(ValueError, match="no derivatives"):
        jax.grad(lambda a: host_call(affine([]), SHAPES, a, a)[0].sum())(np.ones(3, np.float32))


def test_shard_map_over_two_devices():
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}

    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env={**os.environ, **env},
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("ok")
