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


FALLBACK = """
import jax, jax.numpy as jnp, numpy as np
from envs.host_call import host_call
out = jax.ShapeDtypeStruct((3,), jnp.float32)
f = jax.jit(jax.vmap(lambda x: host_call(lambda a: (np.cumsum(a, -1, dtype=np.float32),), (out,), x)[0]))
x = np.arange(12, dtype=np.float32).reshape(4, 3)
print("python callback" if "python_cpu_callback" in f.lower(x).as_text() else "ffi")
np.testing.assert_array_equal(np.asarray(f(x)), np.cumsum(x, -1))
"""


@pytest.mark.parametrize("compiler", ["cc", "/nonexistent/cc"])
def test_ffi_target_or_python_callback_without_a_compiler(tmp_path, compiler):
    """On CPU a host call is the FFI target, built with the C compiler on first use; without one it is jax's
    python callback, said in one line on stderr, with the same results."""
    env = {**os.environ, "CC": compiler, "XDG_CACHE_HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", FALLBACK], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    notes = [ln for ln in out.stderr.splitlines() if "python callback" in ln]
    if compiler == "cc":
        assert out.stdout.split() == ["ffi"] and not notes
        assert [p.suffix for p in (tmp_path / "gsa_jax" / "ffi").iterdir()] == [".so"]
    else:
        assert out.stdout.strip() == "python callback" and len(notes) == 1 and "/nonexistent/cc" in notes[0]


class Host:
    def step(self, x):
        return (x,)


def test_keys_name_each_host_function_once_and_repeat_across_processes():
    """key_of: a bound method keeps its key; another object's method gets the next key under the same name; the
    n-th key under a name is the same in every process (a hash of the name and n)."""
    import hashlib

    from envs.host_call import _ISSUED, describe, key_of

    a, b = Host(), Host()
    name = describe(a.step)
    assert name.endswith("test_host_call.Host.step")
    ka = key_of(a.step)
    assert key_of(a.step) == ka and key_of(b.step) != ka
    n = _ISSUED[name].index(ka)
    assert ka == int.from_bytes(hashlib.sha256(f"{name}#{n}".encode()).digest()[:8], "little", signed=True)


def test_a_program_whose_env_is_dropped_before_it_runs_still_runs():
    """An env dropped, with the jitted functions holding its programs, right after they were called and before
    they ran (`roll(envs.make(...))` returning unread arrays) still runs: the recently used host functions are held
    (without that, this program's host calls found no host function, and the error XLA passed on was unreadable:
    the message lived in a Python thread state that ctypes drops when a call from XLA's thread returns)."""
    import envs
    from envs.physics import Physics

    def roll(env, steps=30):
        s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 3))
        step = lambda s, _: (jax.vmap(env.step)(s, jnp.zeros((3, env.action_size))), s.obs)  # noqa: E731
        return jax.jit(lambda s: jax.lax.scan(step, s, None, steps)[1])(s)

    obs = np.asarray(roll(envs.make("Hopper-v5", physics=Physics(backend="c", threads=1), randomize="mass=2")))
    assert obs.shape == (30, 3, 11) and np.all(np.isfinite(obs))


def test_a_host_function_is_held_until_others_were_used_or_released():
    """The host function of a key is held after its owner is dropped, until RECENT other host functions were
    keyed or called after it, or release_recent(); then its key finds nothing, and says why."""
    import gc

    from envs import host_call as hc

    class Host:
        def step(self):
            return ()

    def key_of_dropped():
        return hc.key_of(Host().step)  # the Host is dropped on return

    key = key_of_dropped()
    gc.collect()
    hc._handle(key, [], [])  # held
    others = [Host() for _ in range(hc.RECENT)]
    for host in others:
        hc.key_of(host.step)
    del host
    gc.collect()
    with pytest.raises(RuntimeError, match="dropped before the program ran"):
        hc._handle(key, [], [])
    key = hc.key_of(others.pop().step)
    others.clear()
    hc.release_recent()
    gc.collect()
    with pytest.raises(RuntimeError, match=f"no host function with key {key}"):
        hc._handle(key, [], [])
