"""The analyses of one controller, each timed: local analysis per piece, region of attraction (with a Lyapunov
sublevel set and an LQR beside it), falsification and switching -> the dict verify.json holds."""

import time
from typing import NamedTuple

import numpy as np

from gsa_jax.verify import falsify, roa, simulate, switching
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.system import System, equilibrium_guess, state_scale, to_qpos


class Budget(NamedTuple):
    nominal_episodes: int = 50
    roa_directions: int = 96
    roa_bisections: int = 7
    roa_radius: float = 4.0  # r_max, scaled coordinates
    population: int = 64
    iterations: int = 8
    counterexamples: int = 3
    seed: int = 0


QUICK = Budget(nominal_episodes=16, roa_directions=24, roa_bisections=5, population=32, iterations=4)


def eig_list(a) -> list:
    return [[float(e.real), float(e.imag)] for e in sorted(np.linalg.eigvals(a), key=lambda e: -abs(e))]


def piece_jac(ctrl, piece):
    return lambda obs: lin.piece_jacobian(ctrl, obs, piece)


def state_dict(task, qref, x) -> dict:
    nv = task.model.nv
    return {"qpos": [float(q) for q in to_qpos(task.model, qref, x[:nv])[0]], "qvel": [float(v) for v in x[nv:]]}


def local_piece(system: System, piece, qref, scale) -> dict:
    """One piece's fixed point near the equilibrium (Newton), whether the partition picks that piece there, and the
    closed loop's eigenvalues there (piece None: flat PPO's network)."""
    task, ctrl = system.task, system.ctrl
    jac = piece_jac(ctrl, piece)
    fp = lin.fixed_point(task, jac, qref, np.zeros(2 * task.model.nv), scale)
    out = {"piece": piece, "fixed_point_found": bool(fp.converged), "residual": fp.residual,
           **state_dict(task, qref, fp.x)}
    if not np.all(np.isfinite(fp.x)):
        return {**out, "fixed_point_found": False}
    L = lin.linearize(task, jac, qref, fp.x)
    picked = int(ctrl.cluster(lin.observe_at(task, out["qpos"], fp.x[task.model.nv:]).astype(np.float32)))
    a_cl = L.closed
    return {**out, "picked_there": picked, "own_region": bool(piece is None or picked == piece),
            "action": [float(a) for a in L.action], "saturated": saturated(ctrl, L.action),
            "eigenvalues": eig_list(a_cl), "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(a_cl)))),
            "distance_scaled": float(np.linalg.norm(fp.x / scale)), "_a_cl": a_cl, "_x": fp.x}


def saturated(ctrl, action) -> bool:
    """Whether an action lies on the controller's bounds (its Jacobian is zero there)."""
    if ctrl.action_low is None:
        return False
    return bool(np.any(np.isclose(action, ctrl.action_low) | np.isclose(action, ctrl.action_high)))


def local_analysis(system: System, qref, scale) -> list:
    pieces = range(system.ctrl.num_clusters) if system.ctrl.kind == "mixture" else [None]
    return [local_piece(system, p, qref, scale) for p in pieces]


def closed_loop_fixed_point(pieces) -> "dict | None":
    """The nearest-to-equilibrium fixed point that lies in its own piece's region (a fixed point of the closed loop)."""
    own = [p for p in pieces if p["fixed_point_found"] and p.get("own_region")]
    return min(own, key=lambda p: p["distance_scaled"]) if own else None


def lqr_design(system, qref, scale, x_eq):
    """(summary, policy) of an LQR on the task's linearization at the equilibrium with zero action, or (note, None)."""
    task, ctrl = system.task, system.ctrl
    zero = lambda obs: (np.zeros(ctrl.action_size), np.zeros((ctrl.action_size, len(obs))))
    drift = lin.closed_step(task, zero, qref, x_eq) - x_eq
    if np.linalg.norm(drift / scale) > 1e-6:
        return {"note": "the equilibrium needs a nonzero action; no LQR designed"}, None
    L = lin.linearize(task, zero, qref, x_eq)
    A, B = roa.scaled_system(L.A, L.B @ L.G, scale)
    K, P = roa.lqr_gain(A, B)
    summary = {"gain_scaled": K.tolist(), "eigenvalues": eig_list(A - B @ K),
               "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(A - B @ K)))),
               "open_loop_eigenvalues": eig_list(A), "_a_cl": A - B @ K}
    bounds = (ctrl.action_low, ctrl.action_high) if ctrl.action_low is not None else None
    return summary, roa.lqr_policy(task, qref, x_eq, np.zeros(ctrl.action_size), K, scale, bounds)


def roa_of(system, policy, qref, scale, budget, a_cl=None) -> dict:
    task = system.task
    horizon, dim = int(task.episode_length), 2 * task.model.nv
    hold = roa.find_hold(task, policy, qref, scale, horizon)
    out = {"hold": {**state_dict(task, qref, hold.x), "excursion_scaled": (hold.excursion / scale).tolist(),
                    "holds": hold.holds}, "r_max": budget.roa_radius, "directions": budget.roa_directions}
    if not hold.holds:
        return {**out, "radius": [], "volume_fraction": 0.0, "note": "the closed loop does not hold the equilibrium"}
    dirs = roa.directions(budget.roa_directions, dim, budget.seed)
    r = roa.search_radii(task, policy, qref, hold, scale, dirs, budget.roa_radius, budget.roa_bisections, horizon)
    out.update({"radius": r.radius.tolist(), "radius_min": float(r.radius.min()),
                "radius_median": float(np.median(r.radius)),
                "no_boundary_in_range": bool(np.all(r.radius >= budget.roa_radius)),
                "volume_fraction": roa.volume_fraction(r.radius, budget.roa_radius, dim)})
    P = roa.lyapunov(a_cl, dim) if a_cl is not None else None
    out["lyapunov"] = roa.sublevel(P, r) if P is not None else None
    return out


def nominal(system, budget) -> tuple:
    task = system.task
    qpos, qvel = falsify.start_law_states(task, budget.nominal_episodes, 10_000 + budget.seed)
    ep = simulate.run(task, simulate.controller_policy(system.ctrl), qpos, qvel, int(task.episode_length), record=True)
    r = ep.returns
    return {"episodes": len(r), "return_mean": float(r.mean()), "return_p05": float(np.percentile(r, 5)),
            "return_min": float(r.min()), "length_mean": float(ep.lengths.mean())}, ep


def falsification(system, budget) -> dict:
    task, ctrl = system.task, system.ctrl
    horizon, policy, out = int(task.episode_length), simulate.controller_policy(ctrl), {}
    for name, push in (("starts", False), ("starts_and_pushes", True)):
        s = falsify.cem(task, policy, horizon, push, budget.population, budget.iterations, budget.seed)
        out[name] = {"episodes": int(s.returns.size), "worst_return": float(s.returns.min()),
                     "first_iteration_p05": float(np.percentile(s.returns[0], 5)), "best_by_iteration": s.best.tolist(),
                     "counterexamples": falsify.counterexamples(task, ctrl, s, horizon, push, budget.counterexamples)}
    return out


def verify(system: System, budget: Budget) -> dict:
    """Every analysis of one controller, with its cost in seconds."""
    task, ctrl, cost = system.task, system.ctrl, {}
    scale = state_scale(task)
    t0 = time.perf_counter()
    nom, ep = nominal(system, budget)
    result = {"nominal": nom, "switching": switching.switching_stats(ctrl, ep.obs, ep.lengths, task.dt)}
    cost["nominal_and_switching"] = time.perf_counter() - t0
    qref = equilibrium_guess(task)
    if qref is not None:
        t0 = time.perf_counter()
        pieces = local_analysis(system, qref, scale)
        fp = closed_loop_fixed_point(pieces)
        cost["local"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        a_cl = fp["_a_cl"] / scale[:, None] * scale[None, :] if fp is not None else None  # scaled coordinates
        result["roa"] = roa_of(system, simulate.controller_policy(ctrl), qref, scale, budget, a_cl)
        cost["roa"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        lqr, lqr_pol = lqr_design(system, qref, scale, np.zeros(2 * task.model.nv))
        if lqr_pol is not None:
            lqr["roa"] = roa_of(system, lqr_pol, qref, scale, budget, lqr["_a_cl"])
        result["lqr"] = lqr
        cost["lqr"] = time.perf_counter() - t0
        result["local"] = {"pieces": pieces, "closed_loop_fixed_point": None if fp is None else fp["piece"],
                           "has_fixed_point": fp is not None}
    else:
        result["local"] = {"note": f"{system.env!r} declares no equilibrium (Task.equilibrium_qpos): no local "
                                   "analysis or region of attraction"}
    t0 = time.perf_counter()
    result["falsification"] = falsification(system, budget)
    cost["falsification"] = time.perf_counter() - t0
    result["cost_seconds"] = {k: round(v, 2) for k, v in cost.items()}
    return result
