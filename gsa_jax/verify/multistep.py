"""A switching hold's invariant set over k control steps, where no one-step quadratic V exists or the plant
falsifies its set (`gsa verify --certify`): sampled on the piecewise-affine linearization, tested on the plant
(proved on neither).

A hold kept by sliding across a partition boundary drifts along it at every step (each piece's drift a_i points
out of its own cell, and a piece can be open-loop unstable along the boundary): V(d') <= rho^2 V(d) + gamma over one
step can fail for every quadratic V even on a small box around the hold, while over k steps the switching
sequence brings the state back. The k-step map is one affine map per switching sequence (2^k of them at two
pieces), so the program asks the decrease on sampled k-step runs of the piecewise-affine model instead:

- The model (gsa_jax.verify.invariant's pieces and cells): d' = A_i d + a_i with i the active piece whose cell rows
  are all nonnegative at d (the one with the largest smallest row: the partition's argmax among the active pieces).
- Samples: SAMPLES offsets d_0 uniform in the box |d| <= scale x the hold's half-width (its excursion over the
  last tenth, at least EXTENT_FLOOR state-scale units per coordinate), each run k steps of the model to d_k.
- The program, for each k of K_STEPS (fewest first), box scale of BOX_SCALES (largest first) and rho_P of
  RHO_GAPS: the largest inscribed ball of E = {V <= 1} (minimize s with P <= s I) subject to
  V(d_k) <= rho_P^2 V(d_0) + gamma at every sample (linear in P and gamma), gamma <= INNER (1 - rho_P^2), E inside
  the box and the linearization's validity bounds (the Schur complement per row) and semi-axes at most
  certify.AXIS_CAP; the first k and box scale with a solution keep their grid's largest ball. Solved with cvxpy and
  Clarabel.
- Then certify's plant test over k control steps (invariant.tested_set): the level shrinks and is confirmed with
  room as for one step, and the set is certified at the k-step instants only (V may rise between them; the record's
  k says so).
"""

import numpy as np

from gsa_jax.verify import certify
from gsa_jax.verify.system import VerifyError

CLAIM = "sampled on the piecewise-affine linearization over k control steps, tested on the plant (proved on neither)"
K_STEPS = (5, 10, 20, 50)  # control steps
BOX_SCALES = (16.0, 8.0, 4.0, 2.0)  # x the hold's half-width
RHO_GAPS = (0.5, 0.3, 0.2, 0.1)  # 1 - rho_P
SAMPLES = 1000
EXTENT_FLOOR = 0.02  # state-scale units: the least half-width of the sampled box per coordinate
INNER = 0.25  # the inner level's largest share of E's, as invariant.INNER
RULE = (f"where no one-step set exists or the plant falsifies it: V(d_k) <= rho_P^2 V(d_0) + gamma on {SAMPLES} "
        "samples uniform in a box of "
        f"{list(BOX_SCALES)} x the hold's half-width (at least {EXTENT_FLOOR} state-scale units), each run k steps "
        f"of the piecewise-affine model, k in {list(K_STEPS)} (fewest first), 1 - rho_P in {list(RHO_GAPS)}, "
        f"gamma <= {INNER} (1 - rho_P^2), E inside the box and the validity bounds; then the plant test over k steps")


def piece_index(rows: list, d: np.ndarray) -> np.ndarray:
    """[N] the index (into the active pieces) of the cell each offset d [N, n] lies in: the piece whose smallest
    cell row g d + h is largest (rows [p] of [m, n + 1]; a piece without rows, the only one, everywhere)."""
    aug = np.concatenate([d, np.ones((len(d), 1))], axis=1)
    least = [np.min(aug @ r.reshape(-1, d.shape[1] + 1).T, axis=1) if r.size else np.full(len(d), np.inf)
             for r in rows]
    return np.argmax(np.stack(least, axis=1), axis=1)


def run_model(F: np.ndarray, rows: list, d: np.ndarray, k: int) -> np.ndarray:
    """[N, n] the piecewise-affine model's state after k steps from d [N, n] (F [p, n, n + 1]: piece i's [A_i a_i])."""
    for _ in range(k):
        i = piece_index(rows, d)
        d = np.einsum("bij,bj->bi", F[i, :, :-1], d) + F[i, :, -1]
    return d


def box_rows(half: np.ndarray) -> np.ndarray:
    """[n, n] the box |d_j| <= half_j as bound rows h (|h d| <= 1)."""
    return np.diag(1.0 / np.asarray(half, float))


def sampled_shape(d0: np.ndarray, dk: np.ndarray, H: np.ndarray, rho_p: float) -> "tuple | None":
    """The program (module docstring) at one rho_P on samples d0, dk [N, n], E inside the rows H [M, n] (the box's
    and the bounds'): (P [n, n], gamma, rho_p, E's inscribed radius at level 1), or None where Clarabel finds no
    solution."""
    import cvxpy as cp

    n = d0.shape[1]
    P, s, gamma, eye = cp.Variable((n, n), symmetric=True), cp.Variable(), cp.Variable(nonneg=True), np.eye(n)
    quad = lambda d: np.einsum("bi,bj->bij", d, d).reshape(len(d), n * n) @ cp.vec(P, order="F")
    cons = [P << s * eye, P >> eye / certify.AXIS_CAP ** 2, gamma <= INNER * (1.0 - rho_p ** 2),
            quad(dk) <= rho_p ** 2 * quad(d0) + gamma]
    cons += [cp.bmat([[P, h[:, None]], [h[None, :], np.ones((1, 1))]]) >> 0 for h in H]
    if not certify.solved(cp, cp.Minimize(s), cons) or P.value is None:
        return None
    Pv = 0.5 * (P.value + P.value.T)
    if not np.all(np.linalg.eigvalsh(Pv) > 0):
        return None
    return Pv, float(max(gamma.value, 0.0)), rho_p, float(1.0 / np.sqrt(np.linalg.eigvalsh(Pv)[-1]))


def half_width(excursion: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """[n] the sampled box's unit half-width: the hold's excursion, at least EXTENT_FLOOR state-scale units."""
    return np.maximum(np.asarray(excursion, float), EXTENT_FLOOR * np.asarray(scale, float))


def design(F: np.ndarray, rows: list, H: np.ndarray, names: list, half: np.ndarray, seed: int, why: str) -> tuple:
    """((P, gamma, rho_P, radius), k, the box's half-widths [n], the rows H with the box's [M + n, n], their names) of the first k and
    box scale whose grid has a solution (its largest inscribed ball); VerifyError (one line, with `why`: the
    one-step program's refusal) where none has."""
    rng = np.random.default_rng(seed)
    for k in K_STEPS:
        for scale in BOX_SCALES:
            box = scale * half
            d0 = rng.uniform(-box, box, (SAMPLES, len(box)))
            dk = run_model(F, rows, d0, k)
            rows_h = np.concatenate([H, box_rows(box)])
            shapes = [s for s in (sampled_shape(d0, dk, rows_h, 1.0 - gap) for gap in RHO_GAPS) if s is not None]
            if shapes:
                box_names = [f"the sampled box's coordinate {j}" for j in range(len(box))]
                return max(shapes, key=lambda s: s[3]), k, box, rows_h, list(names) + box_names
    raise VerifyError(f"{why}; over k = {list(K_STEPS)} steps no quadratic V falls on the piecewise-affine model's "
                      f"sampled runs from a box of {list(BOX_SCALES)} x the hold's half-width "
                      f"{np.round(half, 4).tolist()} at any rho_P of the grid")
