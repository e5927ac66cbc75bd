"""envs/linalg.py: the LAPACK-free small Cholesky MJX uses, against NumPy and against LAPACK inside MJX."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs import linalg


@pytest.mark.parametrize("n", [1, 2, 6, 14])
def test_factor_and_solve_match_numpy(n):
    rng = np.random.default_rng(n)
    a = rng.normal(size=(4, n, n))
    a = (a @ a.transpose(0, 2, 1) + n * np.eye(n)).astype(np.float32)
    u = np.asarray(jax.jit(linalg.cholesky_upper)(jnp.asarray(a)))
    np.testing.assert_array_equal(u, np.triu(u))
    np.testing.assert_allclose(u, np.linalg.cholesky(a.astype(np.float64)).transpose(0, 2, 1), rtol=1e-5, atol=1e-5)
    b = rng.normal(size=(4, n)).astype(np.float32)
    bm = rng.normal(size=(4, n, 3)).astype(np.float32)
    ref = np.linalg.solve(a.astype(np.float64), b[..., None])[..., 0]
    # through the jax.scipy.linalg API that MJX calls
    solve = jax.jit(lambda a, b: linalg.cho_solve(linalg.cho_factor(a), b))
    np.testing.assert_allclose(np.asarray(solve(jnp.asarray(a), jnp.asarray(b))), ref, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(solve(jnp.asarray(a), jnp.asarray(bm))),
                               np.linalg.solve(a.astype(np.float64), bm), rtol=1e-4, atol=1e-5)


def test_large_or_lower_go_to_lapack():
    a = jnp.eye(40) * 2.0
    c, lower = linalg.cho_factor(a)
    np.testing.assert_allclose(np.asarray(c), np.sqrt(2.0) * np.eye(40), rtol=1e-6)
    c, lower = linalg.cho_factor(jnp.eye(3) * 4.0, lower=True)
    assert lower and np.allclose(np.asarray(c), 2.0 * np.eye(3))


def test_mjx_same_with_and_without_lapack():
    """cholesky='unrolled' (the default): no LAPACK custom call in a vmapped MJX step, the same trajectory
    as cholesky='lapack' (inverted_double_pendulum: the cheapest task to compile with a dense inertia
    and the Newton solver)."""
    import envs
    from envs.physics import Physics

    def roll_of(env):  # a new function per env: jit must not reuse the other's trace
        return jax.jit(lambda s: jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), s, acts)[0].pipeline_state.qpos)

    env = envs.make_base("inverted_double_pendulum")
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 8))  # eager MJX is op by op: slower
    acts = jax.random.uniform(jax.random.PRNGKey(1), (10, 8, env.action_size), minval=-1, maxval=1)
    ours, lapack = roll_of(env), roll_of(envs.make_base("inverted_double_pendulum", Physics(cholesky="lapack")))
    assert "lapack" in lapack.lower(s0).as_text().lower()  # the check below can see a LAPACK call
    assert "lapack" not in ours.lower(s0).as_text().lower()
    np.testing.assert_allclose(np.asarray(ours(s0)), np.asarray(lapack(s0)), atol=1e-4)
