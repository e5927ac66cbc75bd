"""A certified local region of attraction of the closed loop's stable fixed point x* (`gsa verify --certify`).

Exact on the linearization, tested on the plant (not proved on it). States are verify's tangent coordinates in SI
units (rad, m, rad/s, m/s; gsa_jax.verify.system), the closed loop's Jacobian A one control step at x*
(gsa_jax.verify.linearize), V(x) = (x - x*)' P (x - x*) and the set E = {x : V(x) <= level}.

- k, rho: k is the fewest control steps with rho_A^k <= 1/2 (rho_A: A's spectral radius; at most K_MAX), so a slow
  loop is certified over k steps rather than one. The certified contraction is rho = (1 + rho_A^k) / 2 (V falls
  by rho^2 every k steps), the LMI's target halfway below it, rho_P = (rho_A^k + rho) / 2: on the linearization V
  falls by rho_P^2 < rho^2 in every direction, and the difference is what the plant's nonlinearity may take near x*
  (an LMI tight at rho itself would leave it none along its tight direction, at any distance from x*). Recorded
  beside them is P's own k-step contraction on A (exact, at most rho_P up to the solver's tolerance).
- P: with Q = P^-1, maximize t subject to Q >= t I (the inscribed ball's radius is sqrt(t) at level 1),
  A^k Q A^k' <= rho_P^2 Q (the decrease LMI, A^k' P A^k <= rho_P^2 P), E and its images A^j E (j < k) inside the
  linearization's validity bounds (h' Q h <= 1 per bound, below) and Q <= AXIS_CAP^2 I where no bound limits a
  direction: a semidefinite program, solved with cvxpy and Clarabel (the optional extra verify).
- Validity bounds, each |g (x - x*)| <= margin to first order: an action reaching its clip, an observation the
  normalizer's clip, the partition picking another piece (a mixture), a joint's range, an unlimited hinge's +-pi.
  The largest level of P they allow is the support function's min over bounds and j < k of
  margin^2 / (g A^j P^-1 A^j' g') (capped where the largest semi-axis would pass AXIS_CAP).
- The plant test: uniform samples in E and on its boundary and a cross-entropy search for the largest
  V(x_k) / V(x_0) inside it, each start stepped k control steps in MuJoCo C with the exported controller (float32,
  clipped, its partition): a violation is V(x_k) > rho^2 V(x_0) + DECREASE_TOL level, or an episode that terminates.
  A violation sets the level to SHRINK x the smallest V(x_0) among them and a fresh round runs. After a round that
  finds none the level is set to ROOM x that clean level (spare_level) and a confirmation round of fresh samples
  runs there; the
  level is certified when it finds none too (after CertifyBudget.rounds + 1 rounds, nothing is). Recorded beside it
  (gsa_jax.verify.boundary): V's peak between the k-step instants and the convergence time from E's boundary.
"""

import warnings
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

import mujoco
import numpy as np
import scipy.linalg

from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.verify import linearize as lin
from gsa_jax.verify import boundary, roa
from gsa_jax.verify.boundary import Plant
from gsa_jax.verify.simulate import controller_policy
from gsa_jax.verify.system import System, VerifyError, state_scale, to_tangent, wrap

if TYPE_CHECKING:
    from envs.task import Task
    from gsa_jax.deployment import numpy_policy

CLAIM = "exact on the linearization, tested on the plant (not proved on it)"
INSTALL = "pip install 'gsa_jax[verify]'"
HALF = 0.5  # k: the fewest steps whose linear contraction rho_A^k is at most this
K_MAX = 1000  # control steps
AXIS_CAP = 100.0  # SI units: the largest semi-axis where no validity bound limits a direction
SHRINK = 0.9  # a violation at V(x_0) = v sets the level to SHRINK v
ROOM = 0.8  # the certified level's share of the last clean level, confirmed by a round of fresh samples
DECREASE_TOL = 1e-6  # x level: the float32 controller's rounding
RULE = (f"k: the fewest control steps with rho_A^k <= {HALF} (at most {K_MAX}); rho: (1 + rho_A^k) / 2, tested on "
        "the plant; P: the largest inscribed ball subject to A^k' P A^k <= rho_P^2 P, rho_P = (rho_A^k + rho) / 2 "
        "with the ellipsoid and its images over the k steps inside the linearization's validity bounds (action "
        "clips, normalizer clips, partition boundaries, joint ranges, +-pi on unlimited hinges; semi-axes at most "
        f"{AXIS_CAP:g}); level: the largest those bounds allow, then {SHRINK} x the smallest V(x_0) of a violation "
        f"found on the plant (V(x_k) > rho^2 V(x_0) + {DECREASE_TOL:g} level, or termination) until a round finds none, "
        f"then {ROOM} x that clean level, confirmed by a round of fresh samples")


class CertifyBudget(NamedTuple):
    samples: int = 2000  # uniform samples in E per round
    boundary: int = 2000  # uniform samples on its boundary (where a violation first appears as the level grows)
    population: int = 64  # the falsifier's episodes per iteration
    iterations: int = 6
    rounds: int = 12
    seed: int = 0


QUICK = CertifyBudget(samples=500, boundary=500, population=32, iterations=4)


def require_solver() -> None:
    """VerifyError (one line) unless cvxpy with the Clarabel solver imports."""
    try:
        import cvxpy
    except ImportError:
        cvxpy = None
    if cvxpy is None or "CLARABEL" not in cvxpy.installed_solvers():
        raise VerifyError(f"--certify needs cvxpy and Clarabel, the optional extra verify: {INSTALL}")


def stable_fixed_point(local: dict) -> dict:
    """The closed loop's fixed point record (local analysis) to certify; VerifyError (one line) saying what was
    found instead where it has none or it is unstable."""
    fp = local.get("closed_loop_fixed_point")
    if fp is None:
        found = [p for p in local["pieces"] if p["fixed_point_found"]]
        if not found:
            worst = min(p["residual"] for p in local["pieces"])
            raise VerifyError(f"nothing to certify: no fixed point found near the hold (Newton's residual {worst:.3g} "
                              "scaled units)")
        where = ", ".join(f"piece {p['piece']}'s " + (f"at joint {', '.join(p['at_limit'])}'s limit" if p["at_limit"]
                                                      else f"where piece {p['picked_there']} is picked") for p in found)
        raise VerifyError(f"nothing to certify: no piece's fixed point lies in its own region ({where}): the hold "
                          "switches between pieces, or does not hold")
    if fp["spectral_radius"] >= 1.0:
        who = "the network" if fp["piece"] is None else f"piece {fp['piece']}"
        raise VerifyError(f"nothing to certify: the closed loop's fixed point ({who}'s) is unstable, spectral radius "
                          f"{fp['spectral_radius']:.4f}")
    return fp


def solved(cp: Any, objective: Any, cons: list) -> bool:
    """Whether Clarabel solves the program to its tolerance (an inaccurate solution does not count; cvxpy's warning
    about one is not shown)."""
    problem = cp.Problem(objective, cons)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        return False
    return problem.status == "optimal"


def step_rule(rho_a: float) -> tuple:
    """(k, the certified contraction rho, the LMI's target rho_P) for a closed loop of spectral radius rho_a < 1
    (module docstring)."""
    k = 1 if rho_a <= HALF else min(K_MAX, int(np.ceil(np.log(HALF) / np.log(rho_a))))
    rho = 0.5 * (1.0 + rho_a ** k)
    return k, rho, 0.5 * (rho_a ** k + rho)


class Bounds(NamedTuple):
    g: np.ndarray  # [m, n] d (bounded quantity) / dx at x*
    margin: np.ndarray  # [m] its distance to the bound there
    names: list  # [m] what each bound is


def join_bounds(*parts: Bounds) -> Bounds:
    """The bounds of every part, in order."""
    return Bounds(np.concatenate([b.g for b in parts]), np.concatenate([b.margin for b in parts]),
                  [name for b in parts for name in b.names])


def observation_bounds(ctrl: "numpy_policy.Controller", obs: np.ndarray, C: np.ndarray) -> Bounds:
    """Each observation reaching the normalizer's clip, at obs [d_s] (C = d obs / dx [d_s, n])."""
    zraw = (np.asarray(obs, np.float64) - ctrl.obs_mean) / ctrl.obs_std
    return Bounds(C / ctrl.obs_std[:, None].astype(np.float64), np.abs(ctrl.obs_clip - np.abs(zraw)),
                  [f"observation {i}'s normalizer clip" for i in range(len(zraw))])


def action_bounds(ctrl: "numpy_policy.Controller", piece: "int | None", obs: np.ndarray, C: np.ndarray,
                  who: str = "") -> Bounds:
    """Each of piece `piece`'s actions (None: the partition's pick, or the flat network) reaching its clip, at obs;
    no rows for a controller without action bounds. who: prefixed to each bound's name."""
    raw, j = lin.raw_jacobian(ctrl, obs, piece)
    if ctrl.action_low is None:
        return Bounds(np.zeros((0, C.shape[1])), np.zeros(0), [])
    return Bounds(j @ C, np.minimum(np.abs(raw - ctrl.action_low), np.abs(ctrl.action_high - raw)),
                  [f"{who}action {i}'s clip" for i in range(len(raw))])


def partition_bounds(ctrl: "numpy_policy.Controller", piece: int, others: list, obs: np.ndarray,
                     C: np.ndarray) -> Bounds:
    """Where the partition's logit of each of `others` reaches that of `piece`, at obs (lin.logit_rows)."""
    logits, jl, _ = lin.logit_rows(ctrl, obs)
    return Bounds((jl[others] - jl[piece]) @ C, np.abs(logits[piece] - logits[others]),
                  [f"the partition's boundary with piece {c}" for c in others])


def controller_bounds(ctrl: "numpy_policy.Controller", piece: "int | None", obs: np.ndarray, C: np.ndarray) -> Bounds:
    """The controller's validity bounds at obs [d_s] (C = d obs / dx [d_s, n]): its action clips, its normalizer's
    clips and, for a mixture, where the partition's logit of another piece reaches that of `piece`."""
    parts = [observation_bounds(ctrl, obs, C), action_bounds(ctrl, piece, obs, C)]
    if ctrl.kind == MIXTURE and ctrl.num_clusters > 1:
        parts.append(partition_bounds(ctrl, piece, [c for c in range(ctrl.num_clusters) if c != piece], obs, C))
    return join_bounds(*parts)


def joint_bounds(model: mujoco.MjModel, qref: np.ndarray, x: np.ndarray) -> Bounds:
    """Validity bounds of the tangent state x [n]: each limited hinge or slide joint's range, each unlimited hinge's
    +-pi (where its angle wraps)."""
    n, g, margin, names = 2 * model.nv, [], [], []
    for j in range(model.njnt):
        kind, dof, adr = int(model.jnt_type[j]), int(model.jnt_dofadr[j]), int(model.jnt_qposadr[j])
        if kind not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            continue
        if model.jnt_limited[j]:
            lo, hi = model.jnt_range[j]
            q = qref[adr] + x[dof]
            margin.append(max(0.0, min(q - lo, hi - q)))
            names.append(f"joint {model.joint(j).name!r}'s range")
        elif kind == mujoco.mjtJoint.mjJNT_HINGE:
            margin.append(np.pi)
            names.append(f"joint {model.joint(j).name!r}'s +-pi")
        else:
            continue
        g.append(np.eye(n)[dof])
    return Bounds(np.reshape(g, (-1, n)), np.array(margin), names)


def slab_rows(bounds: Bounds, where: str) -> tuple:
    """(h [m', n] = g / margin over the bounds that limit a direction, their names): a set lies inside them where
    h' P^-1 h <= level^-1 for every row; VerifyError (one line) where `where` (the linearization's point, in words)
    lies on one."""
    keep = np.isfinite(bounds.margin) & (np.abs(bounds.g).sum(1) > 0)
    if np.any(bounds.margin[keep] <= 0):
        name = bounds.names[int(np.flatnonzero(keep & (bounds.margin <= 0))[0])]
        raise VerifyError(f"nothing to certify: {where} lies on {name} (its linearization holds on no neighbourhood)")
    return bounds.g[keep] / bounds.margin[keep][:, None], [bounds.names[i] for i in np.flatnonzero(keep)]


def image_rows(A: np.ndarray, bounds: Bounds, k: int) -> tuple:
    """(h [k m', n] = g A^j / margin for j < k over the bounds that limit a direction, their names): E's images
    over the k steps lie inside the bounds where h' P^-1 h <= level^-1 for every row."""
    h, names = slab_rows(bounds, "the closed loop's fixed point")
    rows = []
    for _ in range(k):
        rows.append(h)
        h = h @ A
    return np.concatenate(rows), [f"{name} at step {j}" for j in range(k) for name in names]


def decrease_shape(Ak: np.ndarray, rho: float, H: np.ndarray) -> np.ndarray:
    """Q = P^-1 [n, n] of the largest inscribed ball with Ak Q Ak' <= rho^2 Q, h' Q h <= 1 for each row of H [M, n]
    and Q <= AXIS_CAP^2 I (the module docstring's program; cvxpy with Clarabel)."""
    import cvxpy as cp

    n = len(Ak)
    Q, t, eye = cp.Variable((n, n), symmetric=True), cp.Variable(), np.eye(n)
    S = rho ** 2 * Q - Ak @ Q @ Ak.T
    cons = [Q - t * eye >> 0, AXIS_CAP ** 2 * eye - Q >> 0, (S + S.T) / 2 >> 0]
    if len(H):
        cons.append(np.einsum("mi,mj->mij", H, H).reshape(len(H), -1) @ cp.vec(Q, order="F") <= 1.0)
    problem = cp.Problem(cp.Maximize(t), cons)
    problem.solve(solver=cp.CLARABEL)
    if problem.status not in ("optimal", "optimal_inaccurate") or Q.value is None or not t.value > 0:
        raise VerifyError(f"nothing to certify: the decrease LMI has no solution Clarabel finds ({problem.status})")
    return 0.5 * (Q.value + Q.value.T)


def contraction(Ak: np.ndarray, P: np.ndarray) -> float:
    """The least rho with Ak' P Ak <= rho^2 P."""
    return float(np.sqrt(scipy.linalg.eigh(Ak.T @ P @ Ak, P, eigvals_only=True).max()))


def largest_level(P: np.ndarray, H: np.ndarray, names: list) -> tuple:
    """(level, what bounds it): the largest level with E's images inside every row of H [M, n] (the support
    function, min 1 / h' P^-1 h) and E's largest semi-axis at most AXIS_CAP."""
    cap = AXIS_CAP ** 2 * float(np.linalg.eigvalsh(P)[0])
    if not len(H):
        return cap, f"the semi-axis cap {AXIS_CAP:g}"
    support = np.einsum("mi,ij,mj->m", H, np.linalg.inv(P), H)
    i = int(np.argmax(support))
    return (1.0 / support[i], names[i]) if 1.0 / support[i] < cap else (cap, f"the semi-axis cap {AXIS_CAP:g}")


class Linear(NamedTuple):
    """The certificate on the linearization: V's matrix, the contraction certified over k steps, P's own on the
    linearization (exact, below it), the level its bounds allow."""

    P: np.ndarray
    k: int
    rho: float
    rho_p: float
    rho_a: float
    level: float
    bounded_by: str


def certify_linear(A: np.ndarray, bounds: Bounds) -> Linear:
    """The certificate of the closed loop's Jacobian A [n, n] (stable) within bounds."""
    rho_a = float(np.max(np.abs(np.linalg.eigvals(A))))
    k, rho, rho_target = step_rule(rho_a)
    H, names = image_rows(A, bounds, k)
    Ak = np.linalg.matrix_power(A, k)
    P = np.linalg.inv(decrease_shape(Ak, rho_target, H))
    P = 0.5 * (P + P.T)
    level, by = largest_level(P, H, names)
    return Linear(P, k, rho, contraction(Ak, P), rho_a, level, by)


def offsets(P: np.ndarray, level: float, u: np.ndarray) -> np.ndarray:
    """[B, n] x - x* of points u [B, n] of the unit ball mapped onto E (V = level |u|^2)."""
    lam, W = np.linalg.eigh(P)
    return np.sqrt(level) * (u / np.sqrt(lam)) @ W.T


class PlantTest(NamedTuple):
    """What the plant test checks, V(x) = (x - x*)' P (x - x*): V(x_k) <= rho^2 V(x_0) + gamma from every start in
    {V <= level} (gamma > 0: an invariant set around a hold that does not rest at x*, gsa_jax.verify.invariant)."""

    plant: Plant
    P: np.ndarray
    k: int
    rho: float
    gamma: float = 0.0


def decrease_values(test: PlantTest, level: float, u: np.ndarray) -> tuple:
    """(V(x_0) [B], V(x_k) [B], +inf where the episode terminates) of starts u [B, n] (the unit ball, mapped onto
    {V <= level}) after k control steps in MuJoCo C with the exported controller."""
    plant, P = test.plant, test.P
    task = plant.system.task
    dx0 = offsets(P, level, u)
    ep = roa.run_from(task, controller_policy(plant.system.ctrl), plant.qref, plant.x_star + dx0, test.k)
    xk = np.concatenate([to_tangent(task.model, plant.qref, ep.qpos[-1]), ep.qvel[-1]], axis=1)
    dxk = wrap(task.model, xk - plant.x_star)
    v0, vk = (np.einsum("bi,ij,bj->b", d, P, d) for d in (dx0, dxk))
    return v0, np.where(ep.terminated, np.inf, vk)


def ratio(v0: np.ndarray, vk: np.ndarray) -> np.ndarray:
    """V(x_k) / V(x_0): unlike their difference, it does not favour starts near x*."""
    return vk / np.maximum(v0, np.finfo(float).tiny)


def search_violations(values: Callable, gamma: float, start: np.ndarray, budget: CertifyBudget,
                      rng: np.random.Generator) -> tuple:
    """(V(x_0) [N], V(x_k) [N]) of a cross-entropy search over the unit ball for the largest
    (V(x_k) - gamma) / V(x_0), from start [n] (values(u [B, n]) -> (V(x_0), V(x_k)); the elite eighth refitted each
    iteration)."""
    mean, std, n_elite = start, np.full(len(start), 0.3), max(2, budget.population // 8)
    seen = []
    for _ in range(budget.iterations):
        u = mean + std * rng.standard_normal((budget.population, len(start)))
        u = u / np.maximum(1.0, np.linalg.norm(u, axis=1, keepdims=True))
        seen.append(values(u))
        elite = u[np.argsort(-ratio(seen[-1][0], seen[-1][1] - gamma))[:n_elite]]
        mean, std = elite.mean(0), np.maximum(elite.std(0), 0.02)
    return tuple(np.concatenate(v) for v in zip(*seen))


def check_round(test: PlantTest, level: float, budget: CertifyBudget, r: int) -> dict:
    """One round of the plant test at level: uniform samples in {V <= level} and on its boundary, then the falsifier
    from the sample with the largest (V(x_k) - gamma) / V(x_0)."""
    rng, n = np.random.default_rng([budget.seed, r]), len(test.P)
    values = lambda u: decrease_values(test, level, u)
    u = np.concatenate([roa.ball(rng, budget.samples, n), roa.sphere(rng, budget.boundary, n)])
    v0, vk = values(u)
    f0, fk = search_violations(values, test.gamma, u[int(np.argmax(ratio(v0, vk - test.gamma)))], budget, rng)
    v0, vk = np.concatenate([v0, f0]), np.concatenate([vk, fk])
    excess = (vk - test.rho ** 2 * v0 - test.gamma) / level
    bad = excess > DECREASE_TOL
    return {"level": float(level), "samples": int(budget.samples), "boundary_samples": int(budget.boundary),
            "falsifier_episodes": int(len(f0)), "violations": int(bad.sum()), "largest_excess": float(excess.max()),
            "smallest_violating_v0": float(v0[bad].min()) if bad.any() else None}


def check_on_plant(test: PlantTest, level: float, budget: CertifyBudget, floor: float = 0.0) -> tuple:
    """(level, certified, rounds): the plant test's rounds from `level`, shrinking at each violation; after a round
    that finds none, the level is set below that clean level (spare_level) and a confirmation round of fresh samples
    runs there (each round draws its own); certified when it finds none too (a violation there shrinks on), else
    after budget.rounds + 1 rounds or where the level would fall to floor or below, nothing is (level 0)."""
    rounds, confirming = [], False
    for r in range(budget.rounds + 1):
        rounds.append({**check_round(test, level, budget, r), "confirmation": confirming})
        if not rounds[-1]["violations"]:
            if confirming:
                return level, True, rounds
            confirming, level = True, spare_level(level, floor)
        else:
            confirming, level = False, SHRINK * rounds[-1]["smallest_violating_v0"]
        if level <= floor:
            break
    return 0.0, False, rounds


def spare_level(clean: float, floor: float) -> float:
    """The level certified below a clean one: ROOM x it, or where that would reach the floor (a hold set's inner
    level), halfway between the floor and it."""
    return ROOM * clean if ROOM * clean > floor else 0.5 * (floor + clean)


def room_fields(rounds: list, level: float) -> dict:
    """The certified level's room: the last clean level before the confirmation and the certified level's share of
    it (null where nothing is certified), the smallest V(x_0) of a violation any round found (null: none) and the
    certified level's share of that."""
    clean = rounds[-2]["level"] if level > 0 and len(rounds) > 1 else None
    bad = [r["smallest_violating_v0"] for r in rounds if r["smallest_violating_v0"] is not None]
    first = min(bad) if bad else None
    return {"room": level / clean if clean else None, "level_clean": clean, "first_violating_v0": first,
            "level_share_of_first_violation": level / first if first and level > 0 else None}


def ellipsoid_fields(P: np.ndarray, level: float) -> dict:
    """{V <= level}'s semi-axes [n] (largest first) and their unit directions [n, n], inscribed radius and extent
    [n] (per coordinate, the largest offset from the centre), in the state's units."""
    lam, W = np.linalg.eigh(P)
    axes = np.sqrt(level / lam)
    return {"semi_axes": axes.tolist(), "semi_axis_directions": W.T.tolist(), "inscribed_radius": float(axes.min()),
            "extent": np.sqrt(level * np.diag(np.linalg.inv(P))).tolist()}


def plant_fields(rounds: list, budget: CertifyBudget, level: float) -> dict:
    """The plant test's record: starts tested in all, violations per round, the rounds, the budget, the room of the
    certified level (room_fields)."""
    return {"samples": int(sum(r["samples"] + r["boundary_samples"] + r["falsifier_episodes"] for r in rounds)),
            "violations": [r["violations"] for r in rounds], "rounds": rounds, "budget": budget._asdict(),
            **room_fields(rounds, level)}


def coordinates(model: mujoco.MjModel) -> list:
    """[2 nv] each tangent coordinate's joint and SI unit, positions then velocities."""
    units = {int(mujoco.mjtJoint.mjJNT_FREE): ["m"] * 3 + ["rad"] * 3, int(mujoco.mjtJoint.mjJNT_BALL): ["rad"] * 3,
             int(mujoco.mjtJoint.mjJNT_SLIDE): ["m"], int(mujoco.mjtJoint.mjJNT_HINGE): ["rad"]}
    pos = []
    for j in range(model.njnt):
        u = units[int(model.jnt_type[j])]
        pos += [(model.joint(j).name + (f"[{i}]" if len(u) > 1 else ""), unit) for i, unit in enumerate(u)]
    return [f"{name} ({unit})" for name, unit in pos] + [f"{name} velocity ({unit}/s)" for name, unit in pos]


def certificate(system: System, qref: np.ndarray, local: dict, budget: CertifyBudget) -> dict:
    """The certificate record (docs/verify.md) of the closed loop's stable fixed point (local: verify's local
    analysis); VerifyError (one line) where there is nothing to certify."""
    task, ctrl = system.task, system.ctrl
    fp = stable_fixed_point(local)
    x = wrap(task.model, np.concatenate([to_tangent(task.model, qref, np.array(fp["qpos"]))[0], fp["qvel"]]))
    L = lin.linearize(task, lambda obs: lin.piece_jacobian(ctrl, obs, fp["piece"]), qref, x)
    obs = lin.observe_at(task, np.array(fp["qpos"]), np.array(fp["qvel"]))
    bounds = join_bounds(controller_bounds(ctrl, fp["piece"], obs, L.C), joint_bounds(task.model, qref, x))
    lc = certify_linear(L.closed, bounds)
    plant = Plant(system, qref, x)
    level, certified, rounds = check_on_plant(PlantTest(plant, lc.P, lc.k, lc.rho), lc.level, budget)
    between = None
    if certified:
        rng = np.random.default_rng(budget.seed + boundary.SEED_OFFSET)
        d0 = offsets(lc.P, level, roa.sphere(rng, boundary.BOUNDARY_STARTS, len(lc.P)))
        between = boundary.behaviour(plant, L.closed, lc.P, level, lc.k, d0)
    return {"claim": CLAIM, "rule": RULE, "certified": certified, "piece": fp["piece"],
            "qpos": fp["qpos"], "qvel": fp["qvel"], "coordinates": coordinates(task.model), "P": lc.P.tolist(),
            "k": lc.k, "k_seconds": lc.k * float(task.dt), "rho": lc.rho, "rho_per_step": lc.rho ** (1.0 / lc.k),
            "rho_linearization": lc.rho_p, "spectral_radius": lc.rho_a,
            "level_linearization": lc.level, "bounded_by": lc.bounded_by, "level": level,
            **ellipsoid_fields(lc.P, level), **plant_fields(rounds, budget, level), "between_instants": between}


HELD_SCALE = 1.0  # the certified fixed point is the held equilibrium within this many state-scale units of the hold


def tangent_state(task: "Task", qref: np.ndarray, qpos: list, qvel: list) -> np.ndarray:
    """[2 nv] verify's tangent state of a recorded qpos [nq] and qvel [nv] (unlimited hinges wrapped)."""
    dq = to_tangent(task.model, qref, np.array(qpos, np.float64))[0]
    return wrap(task.model, np.concatenate([dq, np.array(qvel, np.float64)]))


def held_equilibrium(task: "Task", qref: np.ndarray, hold_x: np.ndarray, holds: bool, cert: dict) -> dict:
    """Whether a certificate's fixed point is the equilibrium the task declares held: the closed loop holds it from
    the task's equilibrium (holds: roa.find_hold's, the run goes on, stays within a scale unit, its angles upright)
    and the fixed point's positions lie within HELD_SCALE state-scale units (system.state_scale) of that hold
    (hold_x [2 nv], tangent). A certificate elsewhere (a pendulum hanging down) is reported as such and never
    counted. -> {"held_equilibrium", "held_offset" (the largest position offset from the hold, in scale units),
    "held_why" ('' where held), "counted"}."""
    nv = task.model.nv
    x = tangent_state(task, qref, cert["qpos"], cert["qvel"])
    offset = float(np.max(np.abs(wrap(task.model, x - np.asarray(hold_x)))[:nv] / state_scale(task)[:nv]))
    at = bool(holds and offset <= HELD_SCALE)
    why = ("" if at else "the closed loop does not hold the task's equilibrium from it" if not holds else
           f"its fixed point lies {offset:.3g} state-scale units from where the closed loop holds the equilibrium")
    return {"held_equilibrium": at, "held_offset": round(offset, 4), "held_why": why,
            "counted": bool(cert["certified"] and at)}
