"""Region of attraction of the hold an equilibrium task asks for, estimated by simulation, with a quadratic
Lyapunov function and an LQR design on the same linearization beside it.

The hold: the closed loop started at the task's equilibrium (Task.equilibrium_qpos, at rest) for `horizon` steps;
its last tenth is the hold (its mean state; a fixed point, or the small orbit a switching controller chatters in),
held when the episode does not terminate, the positions stay within one scale unit over that tenth, and no angle of
an unlimited hinge is more than 90 degrees from the equilibrium's (a pendulum resting hanging down holds nothing).

The rule, one per task (the same for every controller of it): a start converges when its episode does not terminate
and its last tenth stays within the task's tolerance of the hold on every coordinate: Task.convergence_tolerance where
the task declares one, else TOL x its start-law spread (gsa_jax.verify.system.state_scale), in the task's units.
The episode lasts HORIZON_TIME_CONSTANTS time constants of the closed loop's slowest mode at its fixed point (the
eigenvalue nearest the unit circle, tau = -1 / ln |lambda| control steps), at least the task's episode length and at
most HORIZON_EPISODES of them; the episode length where there is no stable fixed point.

Radii, along unit directions uniform in scaled coordinates (and along each coordinate's axis, both ways): from
r_max, doubled while the start converges (at most `growths` times, up to r_limit = r_max 2^growths), then bisected
between the last radius that converged and the first that did not (0 and r_max where r_max does not). Bisection
assumes the region star-shaped; `inside` more starts per direction, uniform in radius below the one found, count the
directions where one fails (not star-shaped along them). Volume: the share of the ball of radius r_max that
converges, from uniform samples in it (no shape assumed) and from the radii (star-shaped: mean((min(r, r_max) /
r_max)^n), n = 2 nv), and the radius of the ball as large as the star-shaped region (radii not capped at r_max).
"""

from typing import NamedTuple

import numpy as np
import scipy.linalg

from envs.task import Task
from gsa_jax.verify import simulate
from gsa_jax.verify.system import periodic_dofs, state_scale, to_qpos, to_tangent, wrap

TOL = 0.1  # x the start law's spread: the convergence tolerance of a task that declares none
HORIZON_TIME_CONSTANTS = 5.0  # of the slowest closed-loop mode: how long a start has to converge
HORIZON_EPISODES = 10  # the horizon's cap, in episode lengths
TOLERANCE_RULE = (f"Task.convergence_tolerance where the task declares one, else {TOL:g} x its start-law spread per "
                  "coordinate (1 in the task's units where that spread is 0 or above 1); the task's units")


def convergence_tolerance(task: Task) -> np.ndarray:
    """[2 nv] how near its hold a start must stay to count as converged, in the task's units: a property of the task
    alone, the same for every controller of it (TOLERANCE_RULE)."""
    scale = state_scale(task)
    declared = getattr(task, "convergence_tolerance", None)
    if declared is None:
        return TOL * scale
    return np.broadcast_to(np.asarray(declared, np.float64), scale.shape).copy()


def horizon(task: Task, a_cl: "np.ndarray | None") -> dict:
    """The episode a start has to converge in (module docstring) from the closed loop's Jacobian a_cl [n, n] at its
    fixed point (None: none): steps, seconds, the slowest mode's modulus and time constant, what set it."""
    length, dt = int(task.episode_length), float(task.dt)
    rho = None if a_cl is None else float(np.max(np.abs(np.linalg.eigvals(a_cl))))
    if rho is None or rho >= 1.0:
        why = "no fixed point" if rho is None else "an unstable fixed point"
        return {"steps": length, "seconds": length * dt, "slowest_modulus": rho, "time_constant_seconds": None,
                "set_by": f"the episode length ({why})"}
    tau = -1.0 / np.log(rho) if rho > 0 else 0.0  # control steps
    cap = HORIZON_EPISODES * length
    steps = int(min(cap, max(length, np.ceil(HORIZON_TIME_CONSTANTS * tau))))
    set_by = ("the episode length" if steps == length else f"the cap ({HORIZON_EPISODES} episode lengths)"
              if steps == cap else f"{HORIZON_TIME_CONSTANTS:g} time constants of the slowest mode")
    return {"steps": steps, "seconds": steps * dt, "slowest_modulus": rho, "time_constant_seconds": tau * dt,
            "set_by": set_by}


class Hold(NamedTuple):
    x: np.ndarray  # [2 nv] the hold's mean tangent state
    excursion: np.ndarray  # [2 nv] its largest deviation from the mean over the last tenth
    holds: bool  # the run from the equilibrium goes on, its positions stay within one scale unit, its angles upright


def tangent_states(task: Task, qref: np.ndarray, ep: simulate.Episodes, last: int = 0) -> np.ndarray:
    """[T, B, 2 nv] tangent states of recorded episodes (simulate.Episodes; the last `last` states only where > 0),
    unlimited hinges' angles wrapped."""
    qpos, qvel = (ep.qpos[-last:], ep.qvel[-last:]) if last else (ep.qpos, ep.qvel)
    T, B = qpos.shape[:2]
    dq = to_tangent(task.model, qref, qpos.reshape(T * B, -1)).reshape(T, B, -1)
    return wrap(task.model, np.concatenate([dq, qvel], axis=-1))


def run_from(task: Task, policy: simulate.Policy, qref: np.ndarray, xs: np.ndarray, horizon: int,
             record: bool = False) -> simulate.Episodes:
    """Episodes from tangent states xs [B, 2 nv] around qref."""
    nv = task.model.nv
    return simulate.run(task, policy, to_qpos(task.model, qref, xs[:, :nv]), xs[:, nv:], horizon, record=record)


def find_hold(task: Task, policy: simulate.Policy, qref: np.ndarray, scale: np.ndarray, horizon: int) -> Hold:
    ep = run_from(task, policy, qref, np.zeros((1, 2 * task.model.nv)), horizon, record=True)
    tail = tangent_states(task, qref, ep, max(1, horizon // 10))[:, 0]
    mean = tail.mean(0)
    exc = np.abs(tail - mean).max(0)
    nv = task.model.nv
    upright = np.all(np.abs(mean[:nv][periodic_dofs(task.model)]) <= np.pi / 2)  # not fallen to the other side
    still = np.all(exc[:nv] <= scale[:nv])
    return Hold(mean, exc, bool(not ep.terminated[0] and ep.lengths[0] == horizon and still and upright))


class Trial(NamedTuple):
    """One closed loop's convergence test: its task and policy, the reference qpos, its hold, the scale [2 nv] of the
    scaled coordinates, the task's tolerance [2 nv] (its units) and the horizon (control steps)."""

    task: Task
    policy: simulate.Policy
    qref: np.ndarray
    hold: Hold
    scale: np.ndarray
    tol: np.ndarray
    horizon: int


def converged(trial: Trial, offsets: np.ndarray) -> np.ndarray:
    """[B] whether each start, the hold plus offsets [B, 2 nv] (scaled), converges (the module docstring's rule)."""
    t = trial
    ep = run_from(t.task, t.policy, t.qref, t.hold.x + offsets * t.scale, t.horizon, record=True)
    tail = tangent_states(t.task, t.qref, ep, max(1, t.horizon // 10))
    near = np.all(np.abs(wrap(t.task.model, tail - t.hold.x)) <= t.tol, axis=(0, 2))
    return near & ~ep.terminated & (ep.lengths == t.horizon)


def sphere(rng: np.random.Generator, count: int, n: int) -> np.ndarray:
    """[count, n] unit vectors uniform on the sphere."""
    u = rng.standard_normal((count, n))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def ball(rng: np.random.Generator, count: int, n: int) -> np.ndarray:
    """[count, n] uniform in the unit ball."""
    return sphere(rng, count, n) * rng.uniform(size=(count, 1)) ** (1.0 / n)


def directions(n_dirs: int, dim: int, seed: int) -> np.ndarray:
    """[n_dirs, dim] unit vectors uniform on the sphere, drawn from seed."""
    return sphere(np.random.default_rng(seed), n_dirs, dim)


class Radii(NamedTuple):
    radius: np.ndarray  # [D] scaled radius per direction
    bounded: np.ndarray  # [D] bool: a radius that does not converge was found (else radius = r_limit)
    samples: np.ndarray  # [S, 2 nv] scaled offsets tried
    ok: np.ndarray  # [S] whether each converged


class Rays(NamedTuple):
    """Where the region is searched: unit directions [D, 2 nv] in scaled coordinates, the first radius tried, the
    doublings beyond it and the bisections per direction."""

    dirs: np.ndarray
    r_max: float
    bisections: int
    growths: int


def search_radii(trial: Trial, rays: Rays) -> Radii:
    """The radius per direction (module docstring: grown from r_max, then bisected), each round's episodes one batch."""
    dirs, samples, oks = rays.dirs, [], []
    lo, hi = np.zeros(len(dirs)), np.full(len(dirs), np.inf)

    def test(idx, r):
        samples.append(dirs[idx] * r[:, None])
        oks.append(converged(trial, samples[-1]))
        return oks[-1]

    growing = np.arange(len(dirs))
    for g in range(rays.growths + 1):
        r = np.full(len(growing), rays.r_max * 2.0 ** g)
        ok = test(growing, r) if len(growing) else np.zeros(0, bool)
        lo[growing[ok]], hi[growing[~ok]] = r[ok], r[~ok]
        growing = growing[ok]
    open_ = np.flatnonzero(np.isfinite(hi))
    for _ in range(rays.bisections if len(open_) else 0):
        mid = (lo[open_] + hi[open_]) / 2
        ok = test(open_, mid)
        lo[open_], hi[open_] = np.where(ok, mid, lo[open_]), np.where(ok, hi[open_], mid)
    return Radii(lo, np.isfinite(hi), np.concatenate(samples), np.concatenate(oks))


def inside_failures(trial: Trial, dirs: np.ndarray, radius: np.ndarray, count: int,
                    rng: np.random.Generator) -> tuple:
    """(failed [D] bool, offsets [S, 2 nv], ok [S]): `count` starts per direction dirs [D, 2 nv] at radii uniform
    below radius [D] (directions with radius 0 skipped); failed where one of them does not converge."""
    idx = np.repeat(np.flatnonzero(radius > 0), count)
    offsets = dirs[idx] * (rng.uniform(size=len(idx)) * radius[idx])[:, None]
    ok = converged(trial, offsets) if len(idx) else np.zeros(0, bool)
    failed = np.zeros(len(dirs), bool)
    np.logical_or.at(failed, idx, ~ok)
    return failed, offsets, ok


def reach(samples: np.ndarray, ok: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """[2 nv] in the task's own units (rad, m, rad/s, m/s): per coordinate, the largest offset from the hold among
    the sampled starts [S, 2 nv] (scaled) that converged (0 where none did): how far each coordinate was seen to
    recover from, comparable across tasks and controllers where the scaled radii are not."""
    off = np.abs(samples * scale)[ok]
    return off.max(axis=0) if len(off) else np.zeros(len(scale))


def volume_fraction(radius: np.ndarray, r_max: float, dim: int) -> float:
    """The star-shaped set's share of the ball of radius r_max (radii capped at r_max)."""
    return float(np.mean((np.minimum(radius, r_max) / r_max) ** dim))


def equivalent_radius(radius: np.ndarray, dim: int) -> float:
    """The radius of the ball as large as the star-shaped set of radii [D] (uniform directions)."""
    return float(np.mean(np.asarray(radius, np.float64) ** dim) ** (1.0 / dim))


class RegionBudget(NamedTuple):
    """The region's search: uniform directions, the first radius, doublings and bisections per direction, starts
    inside each radius (the star-shape check), uniform samples in the ball of radius r_max, the seed."""

    directions: int
    r_max: float
    bisections: int
    growths: int
    inside: int
    samples: int
    seed: int


def region(trial: Trial, rb: RegionBudget) -> tuple:
    """(record, offsets [S, 2 nv] every start tried, ok [S]) of the closed loop's region of attraction (module
    docstring): radii along uniform directions and both ways along each axis, the star-shape check, the volume."""
    dim, scale = len(trial.scale), trial.scale
    rng = np.random.default_rng([rb.seed, 1])
    uniform = directions(rb.directions, dim, rb.seed)
    axes = np.concatenate([-np.eye(dim), np.eye(dim)])
    r = search_radii(trial, Rays(np.concatenate([uniform, axes]), rb.r_max, rb.bisections, rb.growths))
    radius, axis = r.radius[:rb.directions], r.radius[rb.directions:].reshape(2, dim).T  # [dim, (-, +)]
    failed, in_offsets, in_ok = inside_failures(trial, uniform, radius, rb.inside, rng)
    ball_offsets = rb.r_max * ball(rng, rb.samples, dim)
    ball_ok = converged(trial, ball_offsets) if rb.samples else np.zeros(0, bool)
    samples = np.concatenate([r.samples, in_offsets, ball_offsets])
    ok = np.concatenate([r.ok, in_ok, ball_ok])
    record = {"radius": radius.tolist(), "radius_min": float(radius.min()), "radius_median": float(np.median(radius)),
              "r_limit": rb.r_max * 2.0 ** rb.growths, "unbounded_directions": int(np.sum(~r.bounded[:rb.directions])),
              "no_boundary_in_range": bool(np.all(~r.bounded)),
              "volume_fraction": volume_fraction(radius, rb.r_max, dim),
              "volume_fraction_sampled": float(ball_ok.mean()) if rb.samples else None, "ball_samples": rb.samples,
              "radius_equivalent": equivalent_radius(radius, dim),
              "not_star_shaped_directions": int(failed.sum()), "inside_samples": int(len(in_ok)),
              "axis_radius": axis.tolist(), "axis_radius_si": (axis * scale[:, None]).tolist(),
              "reach": reach(samples, ok, scale).tolist()}
    return record, samples, ok


def lyapunov(a_cl: np.ndarray, dim: int) -> "np.ndarray | None":
    """P with a_cl' P a_cl - P = -I (scaled coordinates), or None unless a_cl is stable."""
    if np.max(np.abs(np.linalg.eigvals(a_cl))) >= 1.0:
        return None
    return scipy.linalg.solve_discrete_lyapunov(a_cl.T, np.eye(dim))


def sublevel(P: np.ndarray, samples: np.ndarray, ok: np.ndarray, r_max: float) -> dict:
    """The largest level c of V(x) = x' P x (scaled coordinates) with every sampled start [S, 2 nv] below it
    converged (ok [S]) and its ellipsoid inside the ball of radius r_max (c <= lambda_min(P) r_max^2), and the
    ellipsoid's share of that ball."""
    v = np.einsum("si,ij,sj->s", samples, P, samples)
    failed = v[~ok]
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
