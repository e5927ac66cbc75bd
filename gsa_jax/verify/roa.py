"""Region of attraction of the hold an equilibrium task asks for, estimated by simulation, with a quadratic
Lyapunov function and an LQR design on the same linearization beside it.

The hold: the closed loop started at the task's equilibrium (Task.equilibrium_qpos, at rest) for `horizon` steps;
its last tenth is the hold (its mean state; a fixed point, or the small orbit a switching controller chatters in),
held when the episode does not terminate, the positions stay within one scale unit over that tenth, and no angle of
an unlimited hinge is more than 90 degrees from the equilibrium's (a pendulum resting hanging down holds nothing).
A start converges when its episode does not terminate and its last tenth stays within tol of the hold on every
coordinate: tol = TOL x scale + twice the hold's own excursion (scaled coordinates, gsa_jax.verify.system).
Radii: along unit directions sampled uniformly in scaled coordinates, the largest radius (bisection in
[0, r_max]) from which the episode converges, r_max when that converges (no boundary in range). Volume: the
star-shaped set's share of the ball of radius r_max, mean((r / r_max)^n), n = 2 nv.
"""

from typing import NamedTuple

import numpy as np
import scipy.linalg

from envs.task import Task
from gsa_jax.verify import simulate
from gsa_jax.verify.system import periodic_dofs, to_qpos, to_tangent, wrap

TOL = 0.1  # convergence tolerance in scaled coordinates (plus the hold's own excursion)


class Hold(NamedTuple):
    x: np.ndarray  # [2 nv] the hold's mean tangent state
    excursion: np.ndarray  # [2 nv] its largest deviation from the mean over the last tenth
    holds: bool  # the run from the equilibrium goes on, its positions stay within one scale unit, its angles upright


def tangent_states(task: Task, qref: np.ndarray, ep: simulate.Episodes) -> np.ndarray:
    """[T, B, 2 nv] tangent states of recorded episodes (simulate.Episodes), unlimited hinges' angles wrapped."""
    T, B = ep.qpos.shape[:2]
    dq = to_tangent(task.model, qref, ep.qpos.reshape(T * B, -1)).reshape(T, B, -1)
    return wrap(task.model, np.concatenate([dq, ep.qvel], axis=-1))


def run_from(task: Task, policy: simulate.Policy, qref: np.ndarray, xs: np.ndarray, horizon: int,
             record: bool = False) -> simulate.Episodes:
    """Episodes from tangent states xs [B, 2 nv] around qref."""
    nv = task.model.nv
    return simulate.run(task, policy, to_qpos(task.model, qref, xs[:, :nv]), xs[:, nv:], horizon, record=record)


def find_hold(task: Task, policy: simulate.Policy, qref: np.ndarray, scale: np.ndarray, horizon: int) -> Hold:
    ep = run_from(task, policy, qref, np.zeros((1, 2 * task.model.nv)), horizon, record=True)
    tail = tangent_states(task, qref, ep)[-max(1, horizon // 10):, 0]
    mean = tail.mean(0)
    exc = np.abs(tail - mean).max(0)
    nv = task.model.nv
    upright = np.all(np.abs(mean[:nv][periodic_dofs(task.model)]) <= np.pi / 2)  # not fallen to the other side
    still = np.all(exc[:nv] <= scale[:nv])
    return Hold(mean, exc, bool(not ep.terminated[0] and ep.lengths[0] == horizon and still and upright))


def converged(task: Task, policy: simulate.Policy, qref: np.ndarray, hold: Hold, scale: np.ndarray, xs: np.ndarray,
              horizon: int) -> np.ndarray:
    """[B] whether each start xs [B, 2 nv] reaches and stays near the hold."""
    ep = run_from(task, policy, qref, xs, horizon, record=True)
    tail = tangent_states(task, qref, ep)[-max(1, horizon // 10):]
    tol = TOL * scale + 2.0 * hold.excursion
    near = np.all(np.abs(wrap(task.model, tail - hold.x)) <= tol, axis=(0, 2))
    return near & ~ep.terminated & (ep.lengths == horizon)


def sphere(rng: np.random.Generator, count: int, n: int) -> np.ndarray:
    """[count, n] unit vectors uniform on the sphere."""
    u = rng.standard_normal((count, n))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def directions(n_dirs: int, dim: int, seed: int) -> np.ndarray:
    """[n_dirs, dim] unit vectors uniform on the sphere, drawn from seed."""
    return sphere(np.random.default_rng(seed), n_dirs, dim)


class Radii(NamedTuple):
    radius: np.ndarray  # [D] scaled radius per direction
    samples: np.ndarray  # [S, 2 nv] scaled offsets tried
    ok: np.ndarray  # [S] whether each converged


class Rays(NamedTuple):
    """Where the region is searched: unit directions [D, 2 nv] in scaled coordinates, the largest radius tried,
    the bisections per direction, and the episode length a start has to converge in."""

    dirs: np.ndarray
    r_max: float
    bisections: int
    horizon: int


def search_radii(task: Task, policy: simulate.Policy, qref: np.ndarray, hold: Hold, scale: np.ndarray,
                 rays: Rays) -> Radii:
    """Bisection on the radius along each direction, every open direction's episodes run as one batch."""
    dirs, r_max = rays.dirs, rays.r_max

    def test(d, r):
        offsets = d * r[:, None]
        return offsets, converged(task, policy, qref, hold, scale, hold.x + offsets * scale, rays.horizon)

    offs, ok_max = test(dirs, np.full(len(dirs), r_max))
    samples, oks = [offs], [ok_max]
    open_ = ~ok_max
    lo, hi = np.where(ok_max, r_max, 0.0), np.full(len(dirs), r_max)
    for _ in range(rays.bisections if open_.any() else 0):
        mid = (lo[open_] + hi[open_]) / 2
        offs, ok = test(dirs[open_], mid)
        samples.append(offs)
        oks.append(ok)
        lo[open_], hi[open_] = np.where(ok, mid, lo[open_]), np.where(ok, hi[open_], mid)
    return Radii(lo, np.concatenate(samples), np.concatenate(oks))


def reach(radii: Radii, scale: np.ndarray) -> np.ndarray:
    """[2 nv] in the task's own units (rad, m, rad/s, m/s): per coordinate, the largest offset from the hold among
    the sampled starts that converged (0 where none did): how far each coordinate alone was seen to recover from,
    comparable across tasks and controllers where the scaled radii are not (their unit is each task's start law)."""
    off = np.abs(radii.samples * scale)[radii.ok]
    return off.max(axis=0) if len(off) else np.zeros(len(scale))


def volume_fraction(radius: np.ndarray, r_max: float, dim: int) -> float:
    """The star-shaped set's share of the ball of radius r_max."""
    return float(np.mean((np.asarray(radius) / r_max) ** dim))


def lyapunov(a_cl: np.ndarray, dim: int) -> "np.ndarray | None":
    """P with a_cl' P a_cl - P = -I (scaled coordinates), or None unless a_cl is stable."""
    if np.max(np.abs(np.linalg.eigvals(a_cl))) >= 1.0:
        return None
    return scipy.linalg.solve_discrete_lyapunov(a_cl.T, np.eye(dim))


def sublevel(P: np.ndarray, radii: Radii, r_max: float) -> dict:
    """The largest level c of V(x) = x' P x (scaled coordinates) with every sampled start below it converged and its
    ellipsoid inside the sampled ball (c <= lambda_min(P) r_max^2), and the ellipsoid's share of that ball."""
    v = np.einsum("si,ij,sj->s", radii.samples, P, radii.samples)
    failed = v[~radii.ok]
    inside = float(np.linalg.eigvalsh(P)[0]) * r_max ** 2
    c = min(float(failed.min()) if len(failed) else np.inf, inside)
    n = len(P)
    share = float(np.exp(0.5 * n * np.log(c) - 0.5 * np.linalg.slogdet(P)[1] - n * np.log(r_max)))
    return {"level": c, "bounded_by": "a failed start" if c < inside else "the sampled ball",
            "ball_share": share, "samples": int(len(v)), "failed_samples": int(len(failed))}


def scaled_system(A: np.ndarray, B: np.ndarray, scale: np.ndarray) -> tuple:
    """(A, B) of x' = A x + B u in scaled coordinates x / scale."""
    return A * (1.0 / scale)[:, None] * scale[None, :], B / scale[:, None]


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: "np.ndarray | None" = None, R: "np.ndarray | None" = None) -> tuple:
    """(K [d_a, n], P) of the discrete LQR u = -K x minimizing sum x'Qx + u'Ru (default Q = I, R = I: scaled
    states, action units)."""
    Q = np.eye(len(A)) if Q is None else Q
    R = np.eye(B.shape[1]) if R is None else R
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    return K, P


def lqr_policy(task: Task, qref: np.ndarray, x_eq: np.ndarray, a_eq: np.ndarray, K: np.ndarray, scale: np.ndarray,
               bounds: "tuple | None") -> simulate.Policy:
    """simulate.Policy a = clip(a_eq - K (x - x_eq) / scale) of an LQR gain on scaled tangent states."""

    def act(obs, qpos, qvel):
        x = np.concatenate([to_tangent(task.model, qref, qpos), qvel], axis=1)
        a = a_eq[None] - ((x - x_eq) / scale) @ K.T
        return np.clip(a, bounds[0], bounds[1]) if bounds is not None else a
    return act
