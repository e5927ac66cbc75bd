"""The analyses of one controller, each timed: local analysis per piece, region of attraction (with a Lyapunov
sublevel set and an LQR beside it), falsification and switching -> the dict verify.json holds."""

import time
from typing import Callable, NamedTuple

import numpy as np

from envs.task import Task
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment import starts
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.verify import certify, falsify, invariant, roa, simulate, switching
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.system import (System, VerifyError, equilibrium_guess, joints_at_limit, state_scale, to_qpos,
                                   wrap)


class Budget(NamedTuple):
    nominal_episodes: int = 50
    roa_directions: int = 96
    roa_bisections: int = 7
    roa_radius: float = 4.0  # r_max, scaled coordinates: the first radius tried and the sampled ball's
    roa_growths: int = 4  # doublings beyond r_max while a direction converges (r_limit = r_max 2^growths)
    roa_inside: int = 2  # starts per direction below its radius (the star-shape check)
    roa_samples: int = 96  # uniform samples in the ball of radius r_max
    population: int = 64
    iterations: int = 8
    counterexamples: int = 3
    neighbours: int = falsify.NEIGHBOURS  # perturbed starts per counterexample
    seed: int = 0


QUICK = Budget(nominal_episodes=16, roa_directions=16, roa_bisections=4, roa_growths=2, roa_inside=1, roa_samples=16,
               population=24, iterations=4)


def eig_list(a: np.ndarray) -> list:
    return [[float(e.real), float(e.imag)] for e in sorted(np.linalg.eigvals(a), key=lambda e: -abs(e))]


def piece_jac(ctrl: Controller, piece: "int | None") -> Callable:
    return lambda obs: lin.piece_jacobian(ctrl, obs, piece)


def state_dict(task: Task, qref: np.ndarray, x: np.ndarray) -> dict:
    nv = task.model.nv
    return {"qpos": [float(q) for q in to_qpos(task.model, qref, x[:nv])[0]], "qvel": [float(v) for v in x[nv:]]}


def local_piece(system: System, piece: "int | None", qref: np.ndarray, scale: np.ndarray, starts: np.ndarray) -> dict:
    """One piece's fixed point (Newton from each of starts [S, 2 nv]; the converged one nearest the first start),
    whether the partition picks that piece there, and the closed loop's eigenvalues there (piece None: flat PPO's
    network)."""
    task, ctrl = system.task, system.ctrl
    jac = piece_jac(ctrl, piece)
    tries = [lin.fixed_point(task, jac, qref, x0, scale) for x0 in starts]
    done = [f for f in tries if f.converged and np.all(np.isfinite(f.x))]
    distance = lambda x: float(np.linalg.norm(wrap(task.model, x - starts[0]) / scale))
    fp = min(done, key=lambda f: distance(f.x)) if done else tries[0]
    out = {"piece": piece, "fixed_point_found": bool(done), "residual": fp.residual}
    if not done:
        return out
    x = wrap(task.model, fp.x)
    L = lin.linearize(task, jac, qref, x)
    out.update(state_dict(task, qref, x))
    picked = int(ctrl.cluster(lin.observe_at(task, out["qpos"], x[task.model.nv:]).astype(np.float32)))
    a_cl = L.closed
    return {**out, "picked_there": picked, "own_region": bool(piece is None or picked == piece),
            "at_limit": joints_at_limit(task.model, np.asarray(out["qpos"])),
            "action": [float(a) for a in L.action], "saturated": saturated(ctrl, L.action),
            "eigenvalues": eig_list(a_cl), "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(a_cl)))),
            "distance_from_hold_scaled": distance(x), "_a_cl": a_cl}


def saturated(ctrl: Controller, action: np.ndarray) -> bool:
    """Whether an action lies on the controller's bounds (its Jacobian is zero there)."""
    if ctrl.action_low is None:
        return False
    return bool(np.any(np.isclose(action, ctrl.action_low) | np.isclose(action, ctrl.action_high)))


def local_analysis(system: System, qref: np.ndarray, scale: np.ndarray, hold: roa.Hold) -> dict:
    """Every piece's fixed point near the hold and the equilibrium, and the closed loop's own fixed point: the one
    nearest the hold among those that lie in their own piece's region and not at a joint's limit (system.
    joints_at_limit: the limit's constraint holds it there, and its linearization is not the loop's)."""
    starts = np.stack([hold.x, np.zeros_like(hold.x)])
    pieces = range(system.ctrl.num_clusters) if system.ctrl.kind == MIXTURE else [None]
    found = [local_piece(system, p, qref, scale, starts) for p in pieces]
    own = [p for p in found if p["fixed_point_found"] and p["own_region"] and not p["at_limit"]]
    fp = min(own, key=lambda p: p["distance_from_hold_scaled"]) if own else None
    return {"pieces": found, "has_fixed_point": fp is not None,
            "closed_loop_fixed_point": None if fp is None else {k: fp[k] for k in
                                                                 ("piece", "qpos", "qvel", "spectral_radius")},
            "_a_cl": None if fp is None else fp["_a_cl"]}


DRIFT_TOL = 1e-3  # scaled state change of one zero-action step at the equilibrium that still counts as one


class LqrWeights(NamedTuple):
    """The LQR's diagonal weights in the task's own units: q [2 nv] on the tangent state (positions, then
    velocities), r [d_a] on the actions. None: Q = I on scaled states, R = I."""
    q: tuple
    r: tuple


def lqr_weights(weights: "LqrWeights | None", scale: np.ndarray, d_a: int) -> tuple:
    """(Q, R, record) in scaled coordinates (x / scale) of LqrWeights, or the identities."""
    if weights is None:
        return np.eye(len(scale)), np.eye(d_a), "Q = I on scaled states, R = I"
    q, r = np.asarray(weights.q, float), np.asarray(weights.r, float)
    return np.diag(q * scale ** 2), np.diag(r), {"q": q.tolist(), "r": r.tolist()}


def lqr_design(system: System, qref: np.ndarray, scale: np.ndarray, x_eq: np.ndarray,
               weights: "LqrWeights | None" = None) -> tuple:
    """(summary, policy) of an LQR (weights: LqrWeights in the task's units, default Q = I on scaled states and
    R = I on actions) on the task's linearization at the equilibrium with zero action, or (note, None) where that
    is not an equilibrium."""
    task, ctrl = system.task, system.ctrl
    zero = lambda obs: (np.zeros(ctrl.action_size), np.zeros((ctrl.action_size, len(obs))))
    drift = float(np.linalg.norm((lin.closed_step(task, zero, qref, x_eq) - x_eq) / scale))
    if drift > DRIFT_TOL:
        return {"note": f"zero action does not hold the equilibrium (drift {drift:.3g}); no LQR designed"}, None
    L = lin.linearize(task, zero, qref, x_eq)
    A, B = roa.scaled_system(L.A, L.B @ L.G, scale)
    Q, R, record = lqr_weights(weights, scale, ctrl.action_size)
    K, P = roa.lqr_gain(A, B, Q, R)
    summary = {"weights": record, "gain_scaled": K.tolist(), "gain": (K / scale[None, :]).tolist(), "eigenvalues": eig_list(A - B @ K), "drift": drift,
               "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(A - B @ K)))),
               "open_loop_eigenvalues": eig_list(A), "_a_cl": A - B @ K}
    bounds = (ctrl.action_low, ctrl.action_high) if ctrl.action_low is not None else None
    return summary, roa.lqr_policy(task, qref, x_eq, np.zeros(ctrl.action_size), K, scale, bounds)


def roa_of(system: System, policy: simulate.Policy, qref: np.ndarray, scale: np.ndarray, budget: Budget,
           a_cl: "np.ndarray | None" = None, hold: "roa.Hold | None" = None) -> dict:
    """The region of attraction of policy's hold (gsa_jax.verify.roa: the task's tolerance, the horizon a_cl's
    slowest mode needs), with the Lyapunov sublevel set of a_cl (the closed loop's Jacobian at its fixed point, scaled
    coordinates; None: none). hold: the hold over one episode, where already found."""
    task = system.task
    h = roa.horizon(task, a_cl)
    if hold is None or h["steps"] != int(task.episode_length):
        hold = roa.find_hold(task, policy, qref, scale, h["steps"])
    tol = roa.convergence_tolerance(task)
    out = {"coordinates": certify.coordinates(task.model), "tolerance": tol.tolist(),
           "tolerance_rule": roa.TOLERANCE_RULE, "horizon": h,
           "hold": {**state_dict(task, qref, hold.x), "excursion": hold.excursion.tolist(),
                    "excursion_scaled": (hold.excursion / scale).tolist(), "holds": hold.holds,
                    "within_tolerance": bool(np.all(hold.excursion <= tol))},
           "r_max": budget.roa_radius, "directions": budget.roa_directions, "scale": scale.tolist()}
    if not hold.holds:
        return {**out, "radius": [], "volume_fraction": 0.0, "note": "the closed loop does not hold the equilibrium"}
    trial = roa.Trial(task, policy, qref, hold, scale, tol, h["steps"])
    region, samples, ok = roa.region(trial, roa.RegionBudget(
        budget.roa_directions, budget.roa_radius, budget.roa_bisections, budget.roa_growths, budget.roa_inside,
        budget.roa_samples, budget.seed))
    P = roa.lyapunov(a_cl, len(scale)) if a_cl is not None else None
    return {**out, **region, "lyapunov": roa.sublevel(P, samples, ok, budget.roa_radius) if P is not None else None}


def nominal(system: System, budget: Budget) -> tuple:
    task = system.task
    qpos, qvel = falsify.start_law_states(task, budget.nominal_episodes, starts.SELECTION_SEED + budget.seed)
    ep = simulate.run(task, simulate.controller_policy(system.ctrl), qpos, qvel, int(task.episode_length), record=True)
    r = ep.returns
    return {"episodes": len(r), "return_mean": float(r.mean()), "return_p05": float(np.percentile(r, 5)),
            "return_min": float(r.min()), "length_mean": float(ep.lengths.mean())}, ep


SEARCHES = (("start_law", 1.0, False, None), ("twice_the_spread", 2.0, False, "start_law"),
            ("start_law_and_pushes", 1.0, True, "start_law"))  # name, spread, pushes, the narrower it starts from


def falsification(system: System, budget: Budget, threshold: "float | None" = None) -> dict:
    """The three searches (start law; starts up to twice its spread; start law and pushes), each population x
    iterations episodes, the wider two from the start law's worst cases, with their counterexamples judged against
    threshold (the failure return; None: the nominal episodes' worst)."""
    task, ctrl = system.task, system.ctrl
    threshold = nominal(system, budget)[0]["return_min"] if threshold is None else threshold
    horizon, out = int(task.episode_length), {}
    judge = falsify.Judge(threshold, state_scale(task), budget.neighbours, budget.seed)
    for name, spread, push, narrower in SEARCHES:
        sampling = falsify.Sampling(push, spread, budget.population, budget.iterations, budget.seed)
        inherited = tuple(out[narrower]["_inherit"]) if narrower else ()
        out[name] = {**falsify.search(task, ctrl, horizon, sampling, judge, budget.counterexamples, inherited),
                     "starts_from": narrower}
    rule = {"failure": f"a return below {threshold:.6g}, the nominal episodes' worst", "failure_return": threshold,
            "neighbours": judge.neighbours, "perturbation_scaled": falsify.PERTURBATION,
            "knife_edge_share": falsify.KNIFE_EDGE, "robustness": falsify.robustness_measure(task),
            "horizon": horizon}
    return {"rule": rule, **out}


def equilibrium_part(system: System, budget: Budget, scale: np.ndarray, qref: np.ndarray, cost: dict,
                     weights: "LqrWeights | None" = None,
                     certify_budget: "certify.CertifyBudget | None" = None) -> dict:
    """Local analysis, the certificate (where certify_budget is given), region of attraction and the LQR beside it,
    for a task with an equilibrium."""
    task, policy = system.task, simulate.controller_policy(system.ctrl)
    t0 = time.perf_counter()
    hold = roa.find_hold(task, policy, qref, scale, int(task.episode_length))
    local = local_analysis(system, qref, scale, hold)
    cost["local"] = time.perf_counter() - t0
    out = {"local": local}
    if certify_budget is not None:
        t0 = time.perf_counter()
        out.update(invariant.certify_hold(system, qref, local, hold, certify_budget))
        cost["certificate"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    a_cl = local["_a_cl"] / scale[:, None] * scale[None, :] if local["_a_cl"] is not None else None  # scaled
    out["roa"] = roa_of(system, policy, qref, scale, budget, a_cl, hold)
    cost["roa"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    lqr, lqr_policy = lqr_design(system, qref, scale, np.zeros(2 * task.model.nv), weights)
    if lqr_policy is not None:
        lqr["roa"] = roa_of(system, lqr_policy, qref, scale, budget, lqr["_a_cl"])
    out["lqr"] = lqr
    cost["lqr"] = time.perf_counter() - t0
    return out


def verify(system: System, budget: Budget, lqr: "LqrWeights | None" = None,
           certify_budget: "certify.CertifyBudget | None" = None) -> dict:
    """Every analysis of one controller, with its cost in seconds. lqr: the weights of the LQR beside it;
    certify_budget: certify the closed loop's stable fixed point (VerifyError, one line, where there is none)."""
    task, ctrl, cost = system.task, system.ctrl, {}
    if certify_budget is not None and equilibrium_guess(task) is None:
        raise VerifyError(f"nothing to certify: {system.env!r} declares no equilibrium (Task.equilibrium_qpos)")
    scale = state_scale(task)
    t0 = time.perf_counter()
    nom, ep = nominal(system, budget)
    result = {"nominal": nom, "switching": switching.switching_stats(ctrl, ep.obs, ep.lengths, task.dt)}
    cost["nominal_and_switching"] = time.perf_counter() - t0
    qref = equilibrium_guess(task)
    if qref is not None:
        result.update(equilibrium_part(system, budget, scale, qref, cost, lqr, certify_budget))
    else:
        result["local"] = {"note": f"{system.env!r} declares no equilibrium (Task.equilibrium_qpos): no local "
                                   "analysis or region of attraction"}
    t0 = time.perf_counter()
    result["falsification"] = falsification(system, budget, nom["return_min"])
    cost["falsification"] = time.perf_counter() - t0
    result["cost_seconds"] = {k: round(v, 2) for k, v in cost.items()}
    return result
