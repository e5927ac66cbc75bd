"""The one-step decrease of a polyhedral Lyapunov function over a polytope, exactly for a piecewise-affine (PWA)
closed loop, as mixed-integer linear programs solved with HiGHS (scipy.optimize.milp).

The PWA loop d' = A_i d + a_i on cell i = {d : g_ij d + h_ij >= 0} (gsa_jax.verify.pwa), the function
W(d) = ||T d||_inf (T [r, n] of full column rank) and the set S = {W <= 1}. The bound is
    max over d in S of  W(A_i(d) d + a_i(d)) - lam W(d)         (lam >= 0; i(d) a piece whose cell holds d)
one program per row and sign of T (W's max, s T_q d'): the pieces as a disjunction in its convex-hull form (Balas:
d = sum_i d_i, sum_i delta_i = 1, delta_i binary, ||T d_i||_inf <= delta_i, g_i d_i + h_i delta_i >= 0), W(d) as
t >= +-T d. No big-M: exact up to HiGHS's tolerances. A bound below 0 with lam = 1 says W falls on S; with lam = 0 the
bound is the one-step image's size (S invariant where it is at most 1). Where cells share a boundary the program may
take either piece (the controller takes the lower): the bound is then over both, never below the loop's.
"""

from typing import NamedTuple

import numpy as np

from gsa_jax.verify.system import VerifyError


class Bound(NamedTuple):
    value: float  # the max (module docstring)
    d: np.ndarray  # [n] where it is attained
    piece: int  # the piece the program took there
    row: int  # T's row whose |.| is W(d') there
    programs: int  # mixed-integer programs solved


def _program(A: np.ndarray, a: np.ndarray, cells: list, T: np.ndarray, lam: float, q: int, sign: float) -> tuple:
    """(c, constraints, integrality, bounds) of the program for T's row q and a sign: variables
    [d (n), d_1..d_K (K n), delta (K), t]."""
    from scipy.optimize import Bounds as Box, LinearConstraint

    K, n = A.shape[0], A.shape[1]
    r, nx = T.shape[0], n + K * n + K + 1
    c = np.zeros(nx)
    for i in range(K):  # maximize sign T_q (A_i d_i + a_i delta_i) - lam t: minimize its negative
        c[n + i * n: n + (i + 1) * n] = -sign * T[q] @ A[i]
        c[n + K * n + i] = -sign * T[q] @ a[i]
    c[-1] = lam
    rows, lo, hi = [], [], []

    def add(row, low, high):
        rows.append(row)
        lo.append(low)
        hi.append(high)

    for j in range(n):  # d = sum_i d_i
        row = np.zeros(nx)
        row[j] = 1.0
        row[n + j: n + K * n: n] = -1.0
        add(row, 0.0, 0.0)
    row = np.zeros(nx)
    row[n + K * n: n + K * n + K] = 1.0
    add(row, 1.0, 1.0)
    for i in range(K):
        cols, di = slice(n + i * n, n + (i + 1) * n), n + K * n + i
        for q2 in range(r):
            for s in (1.0, -1.0):  # s T d_i - delta_i <= 0
                row = np.zeros(nx)
                row[cols], row[di] = s * T[q2], -1.0
                add(row, -np.inf, 0.0)
        for g in cells[i]:  # g d_i + h delta_i >= 0
            row = np.zeros(nx)
            row[cols], row[di] = g[:-1], g[-1]
            add(row, 0.0, np.inf)
    for q2 in range(r):
        for s in (1.0, -1.0):  # s T d - t <= 0
            row = np.zeros(nx)
            row[:n], row[-1] = s * T[q2], -1.0
            add(row, -np.inf, 0.0)
    integrality = np.zeros(nx)
    integrality[n + K * n: n + K * n + K] = 1
    low = np.full(nx, -np.inf)
    low[n + K * n:] = 0.0
    high = np.full(nx, np.inf)
    high[n + K * n: n + K * n + K] = 1.0
    return c, LinearConstraint(np.array(rows), lo, hi), integrality, Box(low, high)


def check_inputs(A: np.ndarray, a: np.ndarray, cells: list, T: np.ndarray, lam: float) -> None:
    """VerifyError (one line) for shapes that disagree, lam < 0 or a T whose set S is unbounded."""
    K, n = A.shape[0], A.shape[1]
    if A.shape != (K, n, n) or a.shape != (K, n) or len(cells) != K or T.ndim != 2 or T.shape[1] != n:
        raise VerifyError(f"a PWA model of {K} pieces needs A [K, n, n], a [K, n], K cells and T [r, n]; got A "
                          f"{A.shape}, a {a.shape}, {len(cells)} cells, T {T.shape}")
    if lam < 0:
        raise VerifyError(f"lam must be >= 0 (got {lam})")
    if np.linalg.matrix_rank(T) < n:
        raise VerifyError(f"T has rank {np.linalg.matrix_rank(T)} < n = {n}: the set ||T d||_inf <= 1 is unbounded")


def decrease_bound(A: np.ndarray, a: np.ndarray, cells: list, T: np.ndarray, lam: float = 0.0) -> Bound:
    """The exact max of ||T d'||_inf - lam ||T d||_inf over ||T d||_inf <= 1 for the PWA loop (module docstring):
    A [K, n, n], a [K, n], cells [K] of rows [m_i, n + 1] (g, h), T [r, n]."""
    from scipy.optimize import milp

    A, a, T = (np.asarray(v, np.float64) for v in (A, a, T))
    check_inputs(A, a, cells, T, lam)
    K, n = A.shape[0], A.shape[1]
    best, programs = None, 0
    for q in range(T.shape[0]):
        for sign in (1.0, -1.0):
            c, cons, integrality, bounds = _program(A, a, [np.atleast_2d(r) for r in cells], T, lam, q, sign)
            res = milp(c, constraints=cons, integrality=integrality, bounds=bounds)
            programs += 1
            if res.status == 2:  # infeasible: every piece's cell misses S
                continue
            if res.status != 0:
                raise VerifyError(f"HiGHS did not solve the program of row {q}: {res.message}")
            if best is None or -res.fun > best[0]:
                delta = res.x[n + K * n: n + K * n + K]
                best = (-float(res.fun), res.x[:n].copy(), int(np.argmax(delta)), q)
    if best is None:
        raise VerifyError("no piece's cell meets the set: nothing to bound")
    return Bound(*best, programs)


def box_rows(extent: np.ndarray) -> np.ndarray:
    """T [n, n] of the box |d_i| <= extent_i: diag(1 / extent)."""
    return np.diag(1.0 / np.asarray(extent, np.float64))
