"""A linear-partition controller's closed loop near a certified fixed point as a piecewise-affine (PWA) model, the
form the field's verifiers read (gsa_jax.verify.vnnlib: ONNX + VNN-LIB; gsa_jax.verify.milp: a mixed-integer program).

States are verify's tangent coordinates in SI units, d = x - x_c around the certificate's fixed point x_c [n]. Every
piece i of the controller (all K, not only the one certified) is linearized at x_c (invariant.affine_pieces):
d' = A_i d + a_i (A_i its closed loop's Jacobian, a_i = f_i(x_c) - x_c its one-step drift; a_i ~ 0 for the piece
whose fixed point x_c is), its action a = f_i + F_i d (F_i = d action / dx = K_i C) and its cell {d : g_ij d + h_ij
>= 0 for every j != i} (invariant.cell_rows: the partition's own W and c through C = d obs / dx). For a linear
partition with affine pieces (the sub-policy classes 'linear' and 'constant') the controller is exactly this PWA map
of the linearized observation obs_c + C d wherever no clip acts (its normalizer's, its actions'); the model is the
plant's first order around x_c. On a shared boundary the controller takes the lower piece (piece_of).
"""

from typing import NamedTuple

import numpy as np

from gsa_jax.algorithm import partitions
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.verify import invariant
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.system import System, VerifyError

AFFINE_SUBPOLICIES = ("linear", "constant")  # the sub-policy classes whose pieces are affine in the observation


class Pwa(NamedTuple):
    """The PWA closed loop around x_c (module docstring); K pieces, n states, d_a actions."""

    x_c: np.ndarray  # [n] the fixed point (tangent, SI)
    obs: np.ndarray  # [d_s] the observation there
    C: np.ndarray  # [d_s, n] d obs / dx there
    A: np.ndarray  # [K, n, n] each piece's closed-loop Jacobian
    a: np.ndarray  # [K, n] each piece's one-step drift f_i(x_c) - x_c
    F: np.ndarray  # [K, d_a, n] d action / dx of each piece
    f: np.ndarray  # [K, d_a] each piece's action at x_c
    cells: list  # [K] of rows [K - 1, n + 1]: (g, h) with g d + h >= 0 on piece i's cell


def require_pwa(ctrl: Controller) -> None:
    """VerifyError (one line) unless the controller is exactly piecewise affine in its observation: a mixture with a
    linear partition (or a single piece) whose pieces are affine."""
    if ctrl.kind != MIXTURE:
        raise VerifyError("a PWA model needs a mixture of linear controllers; flat PPO's network is not piecewise "
                          "affine")
    if not ctrl.single_piece and not partitions.get(ctrl.partition).polyhedral:
        raise VerifyError(f"a PWA model needs a linear partition; this controller's ({ctrl.partition!r}) has cells "
                          "that are not polyhedra")
    if ctrl.subpolicy not in AFFINE_SUBPOLICIES:
        raise VerifyError(f"a PWA model needs affine pieces ({', '.join(AFFINE_SUBPOLICIES)}); this controller's are "
                          f"{ctrl.subpolicy!r}")


def build(system: System, qref: np.ndarray, x_c: np.ndarray) -> Pwa:
    """The PWA model of every piece of the system's controller at tangent state x_c [n] (its fixed point)."""
    ctrl = system.ctrl
    require_pwa(ctrl)
    pieces = list(range(ctrl.num_clusters))
    p = invariant.affine_pieces(system, qref, np.asarray(x_c, np.float64), pieces)
    rows = invariant.cell_rows(ctrl, p) if len(pieces) > 1 else [np.zeros((0, len(x_c) + 1))]
    acts = [lin.piece_jacobian(ctrl, p.obs, i) for i in pieces]
    f = np.array([a for a, _ in acts], np.float64)
    F = np.array([j @ p.C for _, j in acts], np.float64)
    return Pwa(np.asarray(x_c, np.float64), p.obs, p.C, p.A, p.a, F, f, rows)


def slacks(model: Pwa, d: np.ndarray) -> list:
    """[K] of [N, K - 1]: each piece's cell rows g d + h at deviations d [N, n] (all >= 0: inside the cell)."""
    d = np.atleast_2d(d)
    return [d @ r[:, :-1].T + r[:, -1] for r in model.cells]


def piece_of(model: Pwa, d: np.ndarray) -> np.ndarray:
    """[N] the piece acting at deviations d [N, n]: the lowest whose cell holds d (the controller's first maximum)."""
    inside = np.stack([np.all(s >= 0.0, axis=1) for s in slacks(model, d)], axis=1)  # [N, K]
    return np.argmax(inside, axis=1)


def step(model: Pwa, d: np.ndarray) -> np.ndarray:
    """[N, n] the PWA closed loop's next deviation from deviations d [N, n]."""
    d = np.atleast_2d(d)
    p = piece_of(model, d)
    return np.einsum("bij,bj->bi", model.A[p], d) + model.a[p]


def action(model: Pwa, d: np.ndarray) -> np.ndarray:
    """[N, d_a] the controller's action at the linearized observation obs + C d, for deviations d [N, n]."""
    d = np.atleast_2d(d)
    p = piece_of(model, d)
    return np.einsum("bij,bj->bi", model.F[p], d) + model.f[p]


def images(model: Pwa, piece: int, k: int) -> tuple:
    """(M [k + 1, n, n], m [k + 1, n]): d_j = M_j d + m_j, piece `piece`'s affine map applied j = 0..k times."""
    n = len(model.x_c)
    M, m = [np.eye(n)], [np.zeros(n)]
    for _ in range(k):
        M.append(model.A[piece] @ M[-1])
        m.append(model.A[piece] @ m[-1] + model.a[piece])
    return np.array(M), np.array(m)


def agreement(model: Pwa, ctrl: Controller, d: np.ndarray) -> dict:
    """How the PWA model's piece and action agree with the controller's own at the linearized observations
    obs + C d (d [N, n]): the share of the same piece and the largest action difference where they agree."""
    obs = (model.obs + np.atleast_2d(d) @ model.C.T).astype(np.float32)
    own, mine = np.asarray(ctrl.cluster(obs)).reshape(-1), piece_of(model, d)
    same = own == mine
    diff = np.abs(np.asarray(ctrl.act(obs), np.float64) - action(model, d))[same]
    return {"points": int(len(same)), "same_piece": float(same.mean()),
            "action_max_abs_diff": float(diff.max()) if diff.size else 0.0}


def model_fields(model: Pwa) -> dict:
    """The model as JSON lists (pwa.json)."""
    return {"x_c": model.x_c.tolist(), "obs": model.obs.tolist(), "C": model.C.tolist(), "A": model.A.tolist(),
            "a": model.a.tolist(), "F": model.F.tolist(), "f": model.f.tolist(),
            "cells": [r.tolist() for r in model.cells]}
