"""What a certified set E = {V <= level} does between its k-step instants and from its boundary (`gsa verify
--certify`): V decreases over k control steps, not necessarily at every step, so the set need not be invariant.

- Between the instants, on the linearization (exact): the peak over j = 1..k of max over E of V(x_j) / level,
  ||R A^j R^-1||_2^2 with P = R' R. At most 1: E is invariant at every step.
- On the plant (sampled): BOUNDARY_STARTS starts uniform on E's boundary, stepped in MuJoCo C with the exported
  controller for the region of attraction's horizon (roa.horizon): the peak of V(x_j) / level over their first k
  steps, and the convergence time, the first step after which a start stays within the task's convergence tolerance
  of x* (roa.convergence_tolerance) to the horizon's end; a start that terminates or ends outside has none.
"""

from typing import NamedTuple

import numpy as np

from gsa_jax.verify import roa
from gsa_jax.verify.simulate import controller_policy
from gsa_jax.verify.system import System, wrap

BOUNDARY_STARTS = 40  # starts on E's boundary for the plant's peak and convergence time
SEED_OFFSET = 7919  # their draw's seed: the budget's seed plus this (apart from the plant test's rounds)


class Plant(NamedTuple):
    """The closed loop as the plant test steps it: the task, the exported controller, x* around qref."""

    system: System
    qref: np.ndarray
    x_star: np.ndarray


def linear_peak(A: np.ndarray, P: np.ndarray, k: int) -> tuple:
    """(peak, step): the largest max over E of V(A^j d) / level for j = 1..k (exact on the linearization), and j."""
    R = np.linalg.cholesky(P).T  # P = R' R
    R_inv, Aj, best = np.linalg.inv(R), np.eye(len(P)), (0.0, 0)
    for j in range(1, k + 1):
        Aj = A @ Aj
        g = float(np.linalg.norm(R @ Aj @ R_inv, 2) ** 2)
        best = max(best, (g, j))
    return best


def settle_steps(dist_ok: np.ndarray, alive_to_end: np.ndarray) -> np.ndarray:
    """[B] the first step after which each start stays within tolerance to the end (dist_ok [T + 1, B]), -1 where it
    does not end within it or terminates (alive_to_end [B] false)."""
    outside = ~dist_ok
    last_out = np.where(outside.any(axis=0), len(dist_ok) - 1 - np.argmax(outside[::-1], axis=0), -1)
    settled = last_out + 1
    return np.where(alive_to_end & dist_ok[-1], settled, -1)


def plant_behaviour(plant: Plant, A: np.ndarray, P: np.ndarray, level: float, k: int, d0: np.ndarray) -> dict:
    """The plant's peak between the instants and the convergence times from E's boundary (module docstring) of the
    starts x* + d0 [B, n] on it; A [n, n], the closed loop's Jacobian at x*, sets the horizon."""
    task = plant.system.task
    T = roa.horizon(task, A)["steps"]
    ep = roa.run_from(task, controller_policy(plant.system.ctrl), plant.qref, plant.x_star + d0, T, record=True)
    d = wrap(task.model, roa.tangent_states(task, plant.qref, ep) - plant.x_star)  # [T' + 1, B, n]
    v = np.einsum("tbi,ij,tbj->tb", d[1: k + 1], P, d[1: k + 1]) / level
    ok = np.all(np.abs(d) <= roa.convergence_tolerance(task), axis=2)
    full = (ep.lengths == T) & ~ep.terminated
    steps = settle_steps(ok, full) if len(d) == T + 1 else np.full(len(d0), -1)
    dt, done = float(task.dt), steps >= 0
    return {"plant_peak": float(v.max()), "starts": len(d0), "horizon_seconds": T * dt, "converged": int(done.sum()),
            "seconds_median": float(np.median(steps[done]) * dt) if done.any() else None,
            "seconds_max": float(steps[done].max() * dt) if done.any() else None}


def behaviour(plant: Plant, A: np.ndarray, P: np.ndarray, level: float, k: int, d0: np.ndarray) -> dict:
    """The certificate's `between_instants` record: the linearization's peak and step, the plant's from the starts
    x* + d0 [B, n] on E's boundary (module docstring), whether both are at most 1 (invariant), and their
    convergence."""
    peak, at = linear_peak(A, P, k)
    plant_part = plant_behaviour(plant, A, P, level, k, d0)
    return {"linearization_peak": peak, "linearization_peak_step": at, **plant_part,
            "invariant": bool(peak <= 1.0 + 1e-9 and plant_part["plant_peak"] <= 1.0)}
