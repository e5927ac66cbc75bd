"""An invariant set of a hold the closed loop keeps by switching between pieces (`gsa verify --certify`): exact on
the linearization, tested on the plant (not proved on it).

A hold kept by switching has no fixed point inside one piece's cell (gsa_jax.verify.certify certifies a fixed
point): the state chatters across the partition's boundaries. States are verify's tangent coordinates in SI units
(gsa_jax.verify.system), d = x - x_c around the hold's mean state x_c (roa.find_hold).

- Pieces: those the partition picks over the hold's last tenth (the active ones, at least two), each linearized at
  x_c as an affine map d' = A_i d + a_i: A_i its closed loop's Jacobian there (gsa_jax.verify.linearize), a_i =
  f_i(x_c) - x_c its one-step drift (x_c is a fixed point of none of them).
- Cells: piece i acts where l_ij(d) = (logit_i - logit_j)(x_c) + grad(logit_i - logit_j) C d >= 0 for each other
  active piece j (C = d obs / dx). For a linear partition the logits are its own W and c with the normalization
  folded in (linearize.logit_rows: exactly affine in the observation, so exact in the state where the observation
  is linear in it, and to first order where it is not); for an MLP partition, the network's linearization at x_c.
- Formulation: an invariant ellipsoid around the orbit's centre with decrease outside an inner one. V(d) = d' P d;
  for each active piece i and each active cell j it may step into, on {d in cell i, A_i d + a_i in cell j},
      V(A_i d + a_i) <= rho_P^2 V(d) + gamma,
  an S-procedure in the augmented state (d, 1) (the piecewise-affine systems' form of Johansson and Rantzer): with
  F_i = [A_i a_i] and R the rows of cell i, of cell j at the next state, and (0, 1),
      F_i' P F_i - diag(rho_P^2 P, gamma) + R' U R <= 0,  U >= 0 elementwise with a zero diagonal
  (a product of two rows nonnegative there is nonnegative; the row (0, 1) brings the rows themselves). The active
  pieces' cells cover the state space, so the inequality holds at every state of each cell. Then every
  {V <= c} with c >= c_in = gamma / (1 - rho_P^2) is invariant and V falls wherever it exceeds c_in: every start in
  the set enters the inner set {V <= c_in}, which holds the orbit, and stays there.
- The program: for each rho_P of a grid, the largest inscribed ball of E = {V <= 1} (minimize s with P <= s I)
  subject to the pieces' inequalities, gamma <= INNER (1 - rho_P^2) (the inner level at most INNER of E's), E
  inside the linearization's validity bounds (certify's: each observation's normalizer clip, each active piece's
  action clips, the cell of each piece not active against the active piece farthest from it, each joint's range
  or +-pi; the Schur complement [[P, h], [h', 1]] >= 0 per row h = g / margin) and semi-axes at most
  certify.AXIS_CAP; the grid point with the largest ball is kept, its level raised to the largest the bounds allow
  (certify.largest_level). Solved with cvxpy and Clarabel.
- Over one control step: the pieces alternate from one step to the next, and a k-step map would be one affine map
  per switching sequence. A piece with a mode that grows (spectral radius above 1) along which it can stay in its
  own cell admits no such P over the whole cell: the inequality has to hold along that mode. Where no grid point
  solves so, the grid is solved again with the decrease asked inside the validity bounds only (grid_shapes: their
  slabs 1 -+ h d >= 0 among each transition's rows R; E lies inside them, so the conclusion above holds for E).
- The plant test is certify's (certify.check_on_plant): samples inside {V <= level} and on its boundary and the
  falsifier, each start stepped one control step in MuJoCo C with the exported controller; a violation is
  V(x_1) > rho^2 V(x_0) + gamma + DECREASE_TOL level (a start that leaves the set is one), rho = rho_P +
  (1 - rho_P) / 3 (certify's margin for the plant's nonlinearity); the level shrinks and is confirmed with room as
  certify's is, and nothing is certified where it would fall to the plant's inner level gamma / (1 - rho^2) or
  below.
"""

from typing import Any, NamedTuple

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment import numpy_policy  # noqa: F401 - annotations
from gsa_jax.verify import certify, margins, multistep, roa, switching
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.simulate import controller_policy
from gsa_jax.verify.system import System, VerifyError, state_scale, to_qpos, wrap

INNER = 0.25  # the inner level's largest share of E's in the program
RHO_GAPS = (0.5, 0.3, 0.2, 0.1, 0.05, 0.03, 0.02, 0.01, 5e-3, 3e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)  # 1 - rho_P
RULE = ("pieces: those picked over the hold's last tenth, each affine at its mean state x_c; V(d) = d' P d with "
        "V(A_i d + a_i) <= rho_P^2 V(d) + gamma wherever piece i acts and steps into an active piece's cell "
        f"(S-procedure in the augmented state), gamma <= {INNER} (1 - rho_P^2); P: the largest inscribed ball of "
        f"{{V <= 1}} over 1 - rho_P in {list(RHO_GAPS)}, inside the linearization's validity bounds (action clips, "
        "normalizer clips, inactive pieces' cells, joint ranges, +-pi on unlimited hinges; semi-axes at most "
        f"{certify.AXIS_CAP:g}); level: the largest those bounds allow, then tested on the plant over one control "
        f"step with rho = rho_P + (1 - rho_P) / 3: V(x_1) > rho^2 V(x_0) + gamma + {certify.DECREASE_TOL:g} level is "
        f"a violation, the level shrinking to {certify.SHRINK} x the smallest V(x_0) of one until a round finds none, "
        f"then {certify.ROOM} x that clean level (halfway to the inner level where that would reach it) confirmed "
        "by a round of fresh samples, "
        "nothing certified at or below the inner level gamma / (1 - rho^2)")


def hold_pieces(system: System, qref: np.ndarray) -> tuple:
    """(the pieces [sorted] the partition picks over the hold's last tenth, the switches per second there): the
    closed loop from the equilibrium at rest for one episode, as roa.find_hold runs it."""
    task, horizon = system.task, int(system.task.episode_length)
    ep = roa.run_from(task, controller_policy(system.ctrl), qref, np.zeros((1, 2 * task.model.nv)), horizon,
                      record=True)
    seq = switching.piece_sequence(system.ctrl, ep.obs[-max(1, horizon // 10):])[:, 0]
    return [int(p) for p in np.unique(seq)], float(np.sum(np.diff(seq) != 0) / (len(seq) * float(task.dt)))


class Pieces(NamedTuple):
    """The active pieces at the hold's centre x_c: their affine maps d' = A d + a, and the observation there."""

    pieces: list  # [p]
    A: np.ndarray  # [p, n, n]
    a: np.ndarray  # [p, n]
    obs: np.ndarray  # [d_s] at x_c
    C: np.ndarray  # [d_s, n] d obs / dx at x_c


def affine_pieces(system: System, qref: np.ndarray, x_c: np.ndarray, pieces: list) -> Pieces:
    """Each active piece's closed loop at x_c [n]: its Jacobian A_i and one-step drift a_i = f_i(x_c) - x_c."""
    task, ctrl = system.task, system.ctrl
    A, a = [], []
    for i in pieces:
        jac = lambda obs, i=i: lin.piece_jacobian(ctrl, obs, i)
        L = lin.linearize(task, jac, qref, x_c)
        A.append(L.closed)
        a.append(wrap(task.model, lin.closed_step(task, jac, qref, x_c) - x_c))
    nv = task.model.nv
    obs = lin.observe_at(task, to_qpos(task.model, qref, x_c[:nv])[0], x_c[nv:])
    return Pieces(list(pieces), np.array(A), np.array(a), obs, L.C)


def cell_rows(ctrl: "numpy_policy.Controller", p: Pieces) -> list:
    """[p] per active piece, its cell's rows [m, n + 1] (g, h): g d + h >= 0 on the cell, one per other active
    piece (linearize.logit_rows through C)."""
    logits, jl, _ = lin.logit_rows(ctrl, p.obs)
    return [np.array([np.append((jl[i] - jl[j]) @ p.C, logits[i] - logits[j]) for j in p.pieces if j != i])
            for i in p.pieces]


def inactive_bounds(ctrl: "numpy_policy.Controller", p: Pieces) -> certify.Bounds:
    """For each piece not active, its cell's boundary with the active piece whose linearized boundary is farthest
    from x_c (E on that piece's side: a sufficient condition for E to miss the cell); VerifyError (one line) where
    x_c lies in an inactive piece's cell."""
    logits, jl, _ = lin.logit_rows(ctrl, p.obs)
    parts = []
    for j in (j for j in range(ctrl.num_clusters) if j not in p.pieces):
        dist = [(logits[i] - logits[j]) / max(np.linalg.norm((jl[i] - jl[j]) @ p.C), 1e-300) for i in p.pieces]
        best = int(np.argmax(dist))
        if dist[best] <= 0:
            raise VerifyError(f"the hold's centre lies in the cell of piece {j}, which the hold does not pick")
        parts.append(certify.partition_bounds(ctrl, p.pieces[best], [j], p.obs, p.C))
    return certify.join_bounds(*parts) if parts else certify.Bounds(np.zeros((0, len(p.C[0]))), np.zeros(0), [])


def hold_bounds(system: System, qref: np.ndarray, x_c: np.ndarray, p: Pieces) -> certify.Bounds:
    """The linearization's validity bounds at x_c: normalizer clips, each active piece's action clips, the inactive
    pieces' cells, joint ranges."""
    ctrl = system.ctrl
    actions = [certify.action_bounds(ctrl, i, p.obs, p.C, f"piece {i}'s ") for i in p.pieces]
    return certify.join_bounds(certify.observation_bounds(ctrl, p.obs, p.C), *actions, inactive_bounds(ctrl, p),
                               certify.joint_bounds(system.task.model, qref, x_c))


def transition_constraint(cp: Any, P: Any, gamma: Any, F: np.ndarray, rows: np.ndarray, rho_p: float) -> list:
    """The S-procedure's constraints of one transition: F' P F - diag(rho_p^2 P, gamma) + R' U R <= 0 (F [n, n + 1];
    R: rows [m, n + 1], nonnegative where the transition happens, and (0, 1); U [m + 1, m + 1] >= 0 elementwise,
    zero diagonal)."""
    n = F.shape[0]
    R = np.concatenate([rows.reshape(-1, n + 1), np.eye(1, n + 1, n)])
    U = cp.Variable((len(R), len(R)), symmetric=True)
    lhs = F.T @ P @ F + R.T @ U @ R - cp.bmat([[rho_p ** 2 * P, np.zeros((n, 1))],
                                               [np.zeros((1, n)), cp.reshape(gamma, (1, 1), order="F")]])
    return [(lhs + lhs.T) / 2 << 0, U >= 0, cp.diag(U) == 0]


def slab_rows(H: np.ndarray) -> np.ndarray:
    """[2 M, n + 1] the validity bounds |h d| <= 1 (H [M, n]) as rows nonnegative inside them: 1 - h d, 1 + h d."""
    ones = np.ones((len(H), 1))
    return np.concatenate([np.hstack([-H, ones]), np.hstack([H, ones])])


def transitions(F: np.ndarray, rows: list, H: "np.ndarray | None" = None) -> list:
    """[(F_i [n, n + 1], rows [m, n + 1])] per active piece i and cell j it may step into: piece i's cell's rows and
    cell j's rows at i's next state (the active pieces' cells cover the state space, so every step is one of them),
    and where H [M, n] is given the slabs of the validity bounds (slab_rows: the transition inside them only)."""
    n = F.shape[1]
    extra = slab_rows(H) if H is not None else np.zeros((0, n + 1))
    out = []
    for f, r_i in zip(F, rows):
        step = np.concatenate([f, np.eye(1, n + 1, n)])  # (d, 1) -> (d', 1)
        out += [(f, np.concatenate([r_i.reshape(-1, n + 1), r_j.reshape(-1, n + 1) @ step, extra])) for r_j in rows]
    return out


class Shape(NamedTuple):
    P: np.ndarray  # [n, n]
    gamma: float
    rho_p: float
    radius: float  # E's inscribed radius (level 1)
    within: bool = False  # the decrease asked inside the validity bounds only (their slabs among the S-procedure's rows)


def invariant_shape(F: np.ndarray, rows: list, H: np.ndarray, rho_p: float, within: bool = False) -> "Shape | None":
    """The program (module docstring) at one rho_P: F [p, n, n + 1], rows [p] of [m, n + 1], H [M, n] the
    bounds' rows g / margin; within: the decrease asked inside the bounds only; None where Clarabel finds no
    solution."""
    import cvxpy as cp

    n = F.shape[1]
    P, s, gamma, eye = cp.Variable((n, n), symmetric=True), cp.Variable(), cp.Variable(nonneg=True), np.eye(n)
    cons = [P << s * eye, P >> eye / certify.AXIS_CAP ** 2, gamma <= INNER * (1.0 - rho_p ** 2)]
    cons += [cp.bmat([[P, h[:, None]], [h[None, :], np.ones((1, 1))]]) >> 0 for h in H]
    for f, r in transitions(F, rows, H if within else None):
        cons += transition_constraint(cp, P, gamma, f, r, rho_p)
    if not certify.solved(cp, cp.Minimize(s), cons) or P.value is None:
        return None
    Pv = 0.5 * (P.value + P.value.T)
    return Shape(Pv, float(max(gamma.value, 0.0)), rho_p, float(1.0 / np.sqrt(np.linalg.eigvalsh(Pv)[-1])), within)


def least_gamma(F: np.ndarray, rows: list, shape: Shape, H: np.ndarray) -> Shape:
    """shape with the least gamma its P and rho_P admit (the smallest inner set; unchanged where Clarabel finds
    none smaller)."""
    import cvxpy as cp

    gamma = cp.Variable(nonneg=True)
    cons = [c for f, r in transitions(F, rows, H if shape.within else None)
            for c in transition_constraint(cp, shape.P, gamma, f, r, shape.rho_p)]
    if not certify.solved(cp, cp.Minimize(gamma), cons) or gamma.value is None or gamma.value >= shape.gamma:
        return shape
    return shape._replace(gamma=float(max(gamma.value, 0.0)))


def grid_shapes(F: np.ndarray, rows: list, H: np.ndarray) -> list:
    """The program's solutions over the grid of rho_P, the decrease asked on every whole cell; only where none
    solves, inside the validity bounds only (where a piece may grow far from the hold, outside them)."""
    for within in (False, True):
        shapes = [invariant_shape(F, rows, H, 1.0 - gap, within) for gap in RHO_GAPS]
        shapes = [s for s in shapes if s is not None and np.all(np.linalg.eigvalsh(s.P) > 0)]
        if shapes:
            return shapes
    return []


def design(p: Pieces, rows: list, bounds: certify.Bounds) -> tuple:
    """(the grid's Shape with the largest inscribed ball, the bounds' rows h [M, n], their names); VerifyError (one
    line) where the program has no solution at any grid point."""
    H, names = certify.slab_rows(bounds, "the hold's centre")
    F = np.concatenate([p.A, p.a[:, :, None]], axis=2)
    shapes = grid_shapes(F, rows, H)
    if not shapes:
        radii = ", ".join(f"{r:.4f}" for r in spectral_radii(p))
        grow = "; ".join(f"piece {i} can stay in its own cell along a growing mode (eigenvalue {lam:.4f})"
                         for i, lam in growing_modes(p, rows))
        raise VerifyError(f"the invariant-set LMI has no solution Clarabel finds at any rho_P of the grid, over the "
                          f"whole cells or inside the validity bounds only (the active pieces' closed loops at the "
                          f"hold's centre have spectral radii {radii}{'; ' if grow else ''}{grow})")
    return least_gamma(F, rows, max(shapes, key=lambda s: s.radius), H), H, names


def growing_modes(p: Pieces, rows: list) -> list:
    """[(piece, eigenvalue)] of each active piece's real eigenvalue above 1 whose eigenvector (or its opposite) its
    own cell's rows do not decrease along: the piece can stay in its cell along that growing mode, where no
    quadratic V falls under it."""
    n, out = p.A.shape[1], []
    for piece, A, r in zip(p.pieces, p.A, rows):
        w, vecs = np.linalg.eig(A)
        for lam, v in zip(w, vecs.T):
            if abs(lam.imag) < 1e-12 and lam.real > 1.0:
                slopes = r.reshape(-1, n + 1)[:, :n] @ np.real(v)
                if np.all(slopes >= 0) or np.all(slopes <= 0):
                    out.append((piece, float(lam.real)))
    return out


def spectral_radii(p: Pieces) -> list:
    """[p] each active piece's closed loop's spectral radius at x_c."""
    return [float(np.max(np.abs(np.linalg.eigvals(A)))) for A in p.A]


def cells_kind(ctrl: "numpy_policy.Controller", obs: np.ndarray) -> str:
    """How the cells enter the S-procedure at obs [d_s], in words."""
    if lin.logit_rows(ctrl, obs)[2]:
        return "exact: the linear partition's W and c, the normalization folded in (affine in the observation)"
    return "linearized at the hold's centre (the partition's network)"


def state_fields(task: Any, qref: np.ndarray, x: np.ndarray) -> dict:
    """{qpos, qvel} of a tangent state x [2 nv] around qref."""
    nv = task.model.nv
    return {"qpos": to_qpos(task.model, qref, x[:nv])[0].tolist(), "qvel": x[nv:].tolist()}


def k_step_shape(system: System, p: Pieces, rows: list, bounds: certify.Bounds, excursion: np.ndarray, seed: int,
                 why: str) -> tuple:
    """(Shape, k, H, names, fields) of the k-step sampled program (gsa_jax.verify.multistep) from a box around the
    hold's excursion [n]; VerifyError (one line, with `why`: what the one-step program found) where it has none."""
    H, names = certify.slab_rows(bounds, "the hold's centre")
    F = np.concatenate([p.A, p.a[:, :, None]], axis=2)
    half = multistep.half_width(excursion, state_scale(system.task))
    (P, gamma, rho_p, radius), k, box, H, names = multistep.design(F, rows, H, names, half, seed, why)
    return Shape(P, gamma, rho_p, radius, True), k, H, names, {
        "program": "k steps, sampled on the piecewise-affine model", "claim": multistep.CLAIM,
        "rule": f"{RULE}; {multistep.RULE}",
        "one_step_refusal": why, "sampled_box": box.tolist(), "model_samples": multistep.SAMPLES}


def plant_tested(system: System, qref: np.ndarray, x_c: np.ndarray, shape: Shape, k: int, H: np.ndarray,
                 names: list, budget: certify.CertifyBudget) -> dict:
    """A program's set (shape, over k control steps, inside the rows H) tested on the plant: its record's fields."""
    level_lin, by = certify.largest_level(shape.P, H, names)
    rho = shape.rho_p + (1.0 - shape.rho_p) / 3.0
    inner = shape.gamma / (1.0 - rho ** 2)
    test = certify.PlantTest(certify.Plant(system, qref, x_c), shape.P, k, rho, shape.gamma)
    level, certified, rounds = certify.check_on_plant(test, level_lin, budget, floor=inner)
    return {"k": k, "k_seconds": k * float(system.task.dt),
            "certified": certified, "reason": None if certified else falsified(rounds, inner), "P": shape.P.tolist(),
            "rho": rho, "rho_linearization": shape.rho_p, "gamma": shape.gamma, "within_bounds": shape.within,
            "inner_level": inner, "inner_extent": np.sqrt(inner * np.diag(np.linalg.inv(shape.P))).tolist(),
            "level_linearization": float(level_lin), "bounded_by": by, "level": float(level),
            **certify.ellipsoid_fields(shape.P, level), **certify.plant_fields(rounds, budget, level)}


def tested_set(system: System, qref: np.ndarray, x_c: np.ndarray, p: Pieces, excursion: np.ndarray,
               budget: certify.CertifyBudget) -> dict:
    """The hold's set at x_c for the active pieces p, tested on the plant: the one-step program's where the plant
    certifies it, else the k-step sampled program's (the one-step one's record where that has none); VerifyError
    (one line) where neither program has a set."""
    bounds, rows = hold_bounds(system, qref, x_c, p), cell_rows(system.ctrl, p)
    one = None
    try:
        shape, H, names = design(p, rows, bounds)
    except VerifyError as e:
        why = str(e)
    else:
        one = {"program": "one step, the S-procedure on the cells",
               **plant_tested(system, qref, x_c, shape, 1, H, names, budget)}
        if one["certified"]:
            return one
        why = f"the one-step set: {one['reason']}"
    try:
        shape, k, H, names, how = k_step_shape(system, p, rows, bounds, excursion, budget.seed, why)
    except VerifyError:
        if one is None:
            raise
        return one
    return {**how, **plant_tested(system, qref, x_c, shape, k, H, names, budget)}


def falsified(rounds: list, inner: float) -> str:
    """Why the plant test certified nothing, in words."""
    last = rounds[-1]
    if not last["violations"]:  # clean, at or below the inner level
        return f"the last clean level {last['level']:.4g} is not above the inner level {inner:.4g}"
    shrunk = certify.SHRINK * last["smallest_violating_v0"]
    if shrunk <= inner:
        return (f"plant falsified at level {last['level']:.4g}: a violation at V(x_0) = "
                f"{last['smallest_violating_v0']:.4g} leaves a level of {shrunk:.4g}, not above the inner level "
                f"{inner:.4g}")
    return f"plant falsified at every one of the {len(rounds)} levels tried, down to {last['level']:.4g}"


def hold_set(system: System, qref: np.ndarray, hold: roa.Hold, pieces: list, switches: float,
             budget: certify.CertifyBudget) -> dict:
    """The record (docs/verify.md) of the switching hold (roa.find_hold's: its centre x_c [2 nv] and excursion)
    between pieces: the tested set, or certified false with the reason where no program has one."""
    x_c = hold.x
    task = system.task
    p = affine_pieces(system, qref, x_c, pieces)
    out = {"claim": certify.CLAIM, "rule": RULE, "pieces": pieces, "switches_per_second": switches,
           **state_fields(task, qref, x_c), "coordinates": certify.coordinates(task.model), "k": 1,
           "k_seconds": float(task.dt), "cells": cells_kind(system.ctrl, p.obs), "spectral_radii": spectral_radii(p),
           "drift": p.a.tolist()}
    try:
        return {**out, **tested_set(system, qref, x_c, p, hold.excursion, budget)}
    except VerifyError as e:
        return {**out, "certified": False, "reason": str(e).removeprefix("nothing to certify: "), "level": 0.0}


def no_hold(task: Any, qref: np.ndarray, hold: roa.Hold) -> str:
    """What the run from the equilibrium found where it holds nothing, in words."""
    return (f"the closed loop does not hold the equilibrium (its run from there terminates, moves away or falls: "
            f"the last tenth's mean qpos {np.round(state_fields(task, qref, hold.x)['qpos'], 4).tolist()}, largest "
            f"excursion {np.round(hold.excursion, 4).tolist()} in SI units)")


def certify_hold(system: System, qref: np.ndarray, local: dict, hold: roa.Hold, budget: certify.CertifyBudget) -> dict:
    """verify --certify's records: 'certificate' (certify.certificate) where the closed loop has a stable fixed
    point, 'hold_set' (hold_set; with 'fixed_point', why none is certified, or null) where the hold switches between
    pieces; VerifyError (one line) where neither applies, saying what was found."""
    out, fixed = {}, None
    try:
        out["certificate"] = certify.certificate(system, qref, local, budget)
    except VerifyError as e:
        fixed = str(e)
    if "certificate" in out:  # after the certificate, so that nothing here can undo it
        out["certificate"].update(certify.held_equilibrium(system.task, qref, hold.x, hold.holds, out["certificate"]))
        out["certificate"]["margins"] = margins.certificate_margins(system, qref, out["certificate"], budget.seed)
    if not hold.holds:
        if fixed:
            raise VerifyError(f"{fixed}; {no_hold(system.task, qref, hold)}")
        return out
    pieces, switches = hold_pieces(system, qref) if system.ctrl.kind == MIXTURE else ([0], 0.0)
    if len(pieces) > 1:
        out["hold_set"] = {**hold_set(system, qref, hold, pieces, switches, budget), "fixed_point": fixed}
    elif fixed:
        raise VerifyError(fixed)
    return out
