"""MJX's constraint-solver line search, made cheap in a batch: exact where the cost allows it, and
MJX's own iterative search as a while loop elsewhere.

Each Newton (or CG) iteration of MJX's solver (mujoco/mjx/_src/solver.py) minimises the solver's
cost along the search direction. MJX does this iteratively (`_linesearch`: a bracketing search of up
to opt.ls_iterations steps, hopper: 50, each evaluating the cost at three points over all
constraint rows) until the derivative is below tolerance * ls_tolerance or the bracket stops moving.

1. Exact line search (`exact_linesearch`, the default where it applies). With pyramidal friction
   cones and no friction loss the cost along the line, f(a), is a convex piecewise quadratic: the
   Gauss term plus 0.5 * D_i * (Jaref_i + a * jv_i)^2 for each row that is active (equality rows
   always, limit and contact rows while Jaref_i + a * jv_i < 0). Its minimiser is found directly: the
   derivative at every row's breakpoint a_i = -Jaref_i / jv_i gives the two neighbouring breakpoints
   between which it changes sign; on that piece the active set is fixed and the minimiser is the root
   of a linear function. No loop: O(nefc^2) elementwise work, the same for every env of a batch. MJX's
   iterative search approaches the same point and stops at a tolerance (or, in float32, when its
   bracket collapses: measured on hopper, ~20% of searches run 24-25 iterations); under jax.vmap its
   loop runs as long as the batch's slowest env, so every env pays for the slowest one. Same cost
   function, same acceptance rule (move only if the cost decreases), a different -- exact rather than
   tolerance-terminated -- answer to the same 1-D problem: results differ from MJX's by float32
   rounding and line-search tolerance; measured against MuJoCo C (float64) in
   experiments/linesearch_hopper/. The physics option linesearch='iterative' keeps MJX's search, and
   so does setting ls_iterations (a parameter of that search only): envs/physics.py.
2. MJX's iterative search as a while loop (`while_loop`, used for elliptic cones and friction loss,
   or when the iterative search is asked for). MJX runs the search as `_while_loop_scan`: a lax.scan
   of ls_iterations steps whose body is a lax.cond that turns into a no-op once the search has
   converged (written so reverse-mode autodiff works). Under jax.vmap a cond with a batched predicate
   becomes a select that evaluates both branches, so every env paid all ls_iterations steps. As a
   lax.while_loop the batch stops when its slowest env has converged; per env the iterates are the
   same, so results are bitwise equal (tests/test_solver.py). The physics option search_loop='scan'
   keeps MJX's scan.
"""

import contextlib

import jax
import jax.numpy as jnp

from mujoco.mjx._src import solver, support

_ORIGINAL = solver._while_loop_scan
_ORIGINAL_LINESEARCH = solver._linesearch


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


def line_minimum(jaref, jv, efc_d, always, g1, g2):
    """Exact minimiser a* of the convex piecewise quadratic
        f(a) = g1 a + g2 a^2 + sum_i act_i(a) 0.5 efc_d_i (jaref_i + a jv_i)^2,
        act_i(a) = always_i or jaref_i + a jv_i < 0,
    and f(a*) - f(0). jaref, jv, efc_d, always: [nefc]; g1, g2 scalars (g2 > 0 unless the direction is 0).

    f' is nondecreasing and linear between breakpoints b_i = -jaref_i / jv_i: lo is the largest
    breakpoint with f'(b) <= 0, hi the smallest with f'(b) > 0; no breakpoint lies strictly between,
    so the active set there is that of any interior point t, and a* = -(linear term)/(2 quadratic term)
    of that piece, clipped to [lo, hi] against rounding."""
    q1 = efc_d * jv * jaref
    q2 = 0.5 * efc_d * jv * jv

    def active(a):  # [..., nefc]
        return always | (jaref + a[..., None] * jv < 0)

    def slope(a):
        act = active(a)
        return 2 * a * (g2 + jnp.sum(act * q2, -1)) + g1 + jnp.sum(act * q1, -1)

    has_b = (jv != 0) & ~always
    b = jnp.where(has_b, -jaref / jnp.where(has_b, jv, 1.0), 0.0)
    left = has_b & (slope(b) <= 0)
    lo = jnp.max(jnp.where(left, b, -jnp.inf))
    hi = jnp.min(jnp.where(has_b & ~left, b, jnp.inf))
    lo_in, hi_in = jnp.isfinite(lo), jnp.isfinite(hi)
    safe_lo, safe_hi = jnp.where(lo_in, lo, 0.0), jnp.where(hi_in, hi, 0.0)
    t = jnp.where(lo_in & hi_in, 0.5 * (safe_lo + safe_hi),
                  jnp.where(hi_in, safe_hi - jnp.maximum(1.0, jnp.abs(safe_hi)),
                            jnp.where(lo_in, safe_lo + jnp.maximum(1.0, jnp.abs(safe_lo)), 0.0)))
    act = active(t)
    a2 = g2 + jnp.sum(act * q2)
    a1 = g1 + jnp.sum(act * q1)
    alpha = jnp.clip(-a1 / jnp.where(a2 > 0, 2 * a2, 1.0), lo, hi)
    alpha = jnp.where(a2 > 0, alpha, 0.0)
    act, act0 = active(alpha), active(jnp.zeros(()))
    change = (alpha * (g1 + jnp.sum(act * q1)) + alpha * alpha * (g2 + jnp.sum(act * q2))
              + jnp.sum((act.astype(jaref.dtype) - act0) * 0.5 * efc_d * jaref * jaref))
    return alpha, change


def exact_linesearch(m, d, ctx):
    """MJX's _linesearch with the exact minimiser along ctx.search (module docstring); same inputs,
    same outputs (qacc, Ma, Jaref moved by alpha * search when that lowers the cost)."""
    mv = support.mul_m(m, d, ctx.search)
    jv = d._impl.efc_J @ ctx.search
    g1 = jnp.dot(ctx.search, ctx.Ma) - jnp.dot(ctx.search, d.qfrc_smooth)
    g2 = 0.5 * jnp.dot(ctx.search, mv)
    always = jnp.arange(jv.shape[0]) < d._impl.ne + d._impl.nf
    alpha, change = line_minimum(ctx.Jaref, jv, d._impl.efc_D, always, g1, g2)
    step = jnp.where(change < 0, alpha, 0.0)
    return ctx.replace(qacc=ctx.qacc + ctx.search * step, Ma=ctx.Ma + mv * step, Jaref=ctx.Jaref + jv * step)


@contextlib.contextmanager
def routed(mode, loop="while"):
    """Inside this block MJX's solver searches with `mode` ('exact': exact_linesearch; 'iterative': MJX's
    own) and runs iterative searches as `loop` ('while': while_loop; 'scan': MJX's scan of conds); the
    previous routing is restored on exit. The caller checks that 'exact' applies (envs/physics.py)."""
    if mode not in ("exact", "iterative") or loop not in ("while", "scan"):
        raise ValueError(f"line search must be 'exact' or 'iterative' and its loop 'while' or 'scan', got {mode!r}, {loop!r}")
    previous = solver._linesearch, solver._while_loop_scan
    solver._linesearch = exact_linesearch if mode == "exact" else _ORIGINAL_LINESEARCH
    solver._while_loop_scan = while_loop if loop == "while" else _ORIGINAL
    try:
        yield
    finally:
        solver._linesearch, solver._while_loop_scan = previous
