"""Small dense Cholesky factor/solve in plain JAX ops, used by MJX in place of LAPACK.

MJX factors the joint-space inertia (dense models: every step) and, with the Newton solver, the
nv x nv Hessian (every solver iteration) with jax.scipy.linalg.cho_factor/cho_solve. Inside a
vmapped training program these become jaxlib's *batched* LAPACK kernels, which on XLA:CPU with few
cores (a) have deadlocked here: the kernel splits its batch over XLA's intra-op thread pool from a
thread of that same pool and waits for work that no free thread can run (seen with gdb at 0% CPU,
2 cores, 256 vmapped hopper runs); and (b) pay a per-matrix call for 6x6 ... 30x30 matrices.

`routed()` swaps jax.scipy.linalg.cho_factor / cho_solve, for the duration of a block, for versions that, for matrices up to
MAX_N, compute the same factorization column by column with batched elementwise/matmul ops (no
custom call, so nothing to deadlock, and vectorized over the run and env axes); larger or other
inputs go to the originals. The result equals LAPACK's to float rounding: a change of arithmetic
order, not of the model or solver. The physics option cholesky='lapack' keeps LAPACK (envs/physics.py).
"""

import contextlib

import jax.numpy as jnp
import jax.scipy.linalg as jsl

MAX_N = 32
_ORIGINAL = {"cho_factor": jsl.cho_factor, "cho_solve": jsl.cho_solve}


def cholesky_upper(a):
    """U [..., n, n] upper triangular with a = U^T U, for symmetric positive definite a [..., n, n].
    Column j of the lower factor L = U^T: v = a[:, j] - L[:, :j] L[j, :j]; L[j, j] = sqrt(v[j]);
    L[i, j] = v[i] / L[j, j] below the diagonal, 0 above."""
    n = a.shape[-1]
    rows = jnp.arange(n)
    cols = []
    for j in range(n):
        v = a[..., :, j]
        if j:
            prev = jnp.stack(cols, axis=-1)  # [..., n, j]
            v = v - jnp.sum(prev * prev[..., j:j + 1, :], axis=-1)  # elementwise: no tiny batched dots
        d = jnp.sqrt(v[..., j])[..., None]
        cols.append(jnp.where(rows > j, v / d, jnp.where(rows == j, d, 0.0)))
    return jnp.swapaxes(jnp.stack(cols, axis=-1), -1, -2)


def solve_upper_factor(u, b):
    """x with (U^T U) x = b: forward substitution with U^T, then back substitution with U.
    u [..., n, n], b [..., n] or [..., n, m]."""
    vec = b.ndim == u.ndim - 1
    if vec:
        b = b[..., None]
    n = u.shape[-1]
    y = []
    for i in range(n):  # U^T y = b  (U^T is lower triangular; row i of U^T is column i of U)
        acc = b[..., i, :]
        if i:
            acc = acc - jnp.sum(u[..., :i, i, None] * jnp.stack(y, axis=-2), axis=-2)
        y.append(acc / u[..., i, i][..., None])
    y = jnp.stack(y, axis=-2)
    x = [None] * n
    for i in reversed(range(n)):  # U x = y
        acc = y[..., i, :]
        if i < n - 1:
            acc = acc - jnp.sum(u[..., i, i + 1:, None] * jnp.stack(x[i + 1:], axis=-2), axis=-2)
        x[i] = acc / u[..., i, i][..., None]
    x = jnp.stack(x, axis=-2)
    return x[..., 0] if vec else x


def _small(a):
    return a.ndim >= 2 and a.shape[-1] == a.shape[-2] and 1 <= a.shape[-1] <= MAX_N and jnp.issubdtype(a.dtype, jnp.floating)


def cho_factor(a, lower=False, overwrite_a=False, check_finite=True):
    a = jnp.asarray(a)
    if lower or not _small(a):
        return _ORIGINAL["cho_factor"](a, lower=lower, overwrite_a=overwrite_a, check_finite=check_finite)
    return cholesky_upper(a), False


def cho_solve(c_and_lower, b, overwrite_b=False, check_finite=True):
    c, lower = c_and_lower
    c = jnp.asarray(c)
    if lower or not _small(c):
        return _ORIGINAL["cho_solve"](c_and_lower, b, overwrite_b=overwrite_b, check_finite=check_finite)
    return solve_upper_factor(c, jnp.asarray(b))


@contextlib.contextmanager
def routed(unrolled=True):
    """Inside this block jax.scipy.linalg.cho_factor/cho_solve (as MJX calls them) take the small-matrix
    path (unrolled=True) or LAPACK's (False); the previous functions are restored on exit."""
    previous = jsl.cho_factor, jsl.cho_solve
    chosen = (cho_factor, cho_solve) if unrolled else (_ORIGINAL["cho_factor"], _ORIGINAL["cho_solve"])
    jsl.cho_factor, jsl.cho_solve = chosen  # jsl is the module MJX reaches as jax.scipy.linalg
    try:
        yield
    finally:
        jsl.cho_factor, jsl.cho_solve = previous
