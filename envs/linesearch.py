"""MJX's line search as a while loop: same iterates, less work in a batch.

MJX (mujoco/mjx/_src/solver.py) runs each Newton/CG iteration's line search as
`_while_loop_scan`: a lax.scan of opt.ls_iterations steps (hopper: 50) whose body is a lax.cond
that turns into a no-op once the search has converged -- written so reverse-mode autodiff works.
Under jax.vmap a cond with a batched predicate becomes a select that evaluates *both* branches,
so every env pays all ls_iterations line-search steps (each three cost evaluations over the
constraint rows), converged or not. We never differentiate through the simulator; as a
lax.while_loop the batch stops when its slowest env has converged (a batched while runs the body
for all envs while any is unfinished and keeps the finished ones' values unchanged).
Per env the sequence of iterates is the same as the scan's, so results are bitwise equal
(tests/test_solver.py); what changes is the work: measured in experiments/README.md (speed).
Set GSA_JAX_SCAN_LINESEARCH=1 to keep MJX's scan.
"""

import os

import jax

from mujoco.mjx._src import solver

_ORIGINAL = solver._while_loop_scan


def while_loop(cond_fun, body_fun, init_val, max_iter):
    """body_fun applied while cond_fun holds, at most max_iter times -- the contract of MJX's
    _while_loop_scan (which also stops applying body_fun at the first false cond)."""

    def cond(carry):
        val, i = carry
        return cond_fun(val) & (i < max_iter)

    def body(carry):
        val, i = carry
        return body_fun(val), i + 1

    return jax.lax.while_loop(cond, body, (init_val, 0))[0]


def install():
    """Route MJX's line search through while_loop. Idempotent; a no-op (MJX's scan restored) with
    GSA_JAX_SCAN_LINESEARCH=1. Returns True when installed. Affects programs traced afterwards."""
    if os.environ.get("GSA_JAX_SCAN_LINESEARCH", "") not in ("", "0"):
        solver._while_loop_scan = _ORIGINAL
        return False
    solver._while_loop_scan = while_loop
    return True
