"""Robustness margins of the closed loop at its certified fixed point (`gsa verify --certify`), from its
linearization and checked on the plant.

The loop is broken at the action: one control step x' = A x + B_u a with B_u = B G, and the controller's action
a = M x with M = K C (gsa_jax.verify.linearize: the closed loop's Jacobian is A + B_u M). A perturbed loop acts
a* + g (pi(obs) - a*) (a gain g on every action channel at once, around the fixed point's action a*) or
pi(obs_{t-d}) (d control steps of delay). Linear margins:

- gain margins (lower, upper): the largest interval of g around 1 in which A + g B_u M stays stable (spectral
  radius below 1); the lower one 0 where the loop is stable down to no feedback, the upper one inf where it stays
  stable up to GAIN_MAX;
- delay margin: the most control steps of delay d with every delay 0 .. d stable (the loop on the state x_t and the
  d actions computed before it);
- disk margin: alpha = 1 / max over the unit circle of sigma_max(S - I/2), S = (I + L)^-1, L(z) = -M (zI - A)^-1 B_u
  (the symmetric disk, skew 0; with several action channels a lower bound on the margin to simultaneous
  perturbations of all of them), its gain range ((1 - alpha/2) / (1 + alpha/2), (1 + alpha/2) / (1 - alpha/2)) and
  phase margin 2 atan(alpha / 2).

The plant check runs the exported controller in MuJoCo C from the fixed point plus small offsets (PLANT_STARTS starts
PLANT_OFFSET state-scale units away in random directions) under a gain or a delay: it holds where no episode ends
early and the median over the starts of each start's largest deviation over the horizon's last tenth, relative to
its start's, is below 1 (so up to half the starts may still grow). A gain margin g is checked at
1 + CHECK_INSIDE (g - 1) (it should hold) and 1 + CHECK_OUTSIDE (g - 1) (it should not), the delay margin at itself and
one step past it; a margin is `confirmed` where both come out so. A lower gain margin below MARGINAL (a loop that
needs no feedback to stay marginally bounded, e.g. an integrator) is 0 and not checked.
"""

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from gsa_jax.deployment.numpy_policy import Controller
    from gsa_jax.verify.simulate import Policy

GAIN_MAX = 100.0  # the upper gain margin is inf where the loop is stable up to this gain
MARGINAL = 1e-9  # a lower gain margin below this is 0
GAIN_GRID = 400  # gains scanned on each side of 1 before bisection
DELAY_MAX = 50  # control steps
FREQUENCIES = 4096  # points on the upper unit circle for the disk margin
FLAG_GAIN = 1.25  # a certificate is flagged where a gain margin lies within this factor of 1 (below 1.25x or above 0.8x)
FLAG_DELAY = 1  # ... or its delay margin is below this many control steps
FLAG_DISK = 0.2  # ... or its disk margin is below this
PLANT_OFFSET = 0.05  # state-scale units: the plant check's starting offsets from the fixed point
PLANT_STARTS = 16
CHECK_INSIDE, CHECK_OUTSIDE = 0.9, 1.1  # the plant checks each gain margin g at these multiples of g - 1, from 1


class Loop(NamedTuple):
    A: np.ndarray  # [n, n] one control step's state Jacobian
    Bu: np.ndarray  # [n, d_a] its action Jacobian (B G)
    M: np.ndarray  # [d_a, n] the controller's action Jacobian in the state (K C)


def loop_of(lin: "object") -> Loop:
    """The loop broken at the action of a linearize.Linearization (A, B, C, G, K)."""
    return Loop(np.asarray(lin.A), np.asarray(lin.B) @ np.asarray(lin.G), np.asarray(lin.K) @ np.asarray(lin.C))


def spectral_radius(a: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(a)))) if a.size else 0.0


def stable_at(loop: Loop, g: float) -> bool:
    return spectral_radius(loop.A + g * loop.Bu @ loop.M) < 1.0


def first_unstable(loop: Loop, gains: np.ndarray) -> "float | None":
    """The gain, to bisection precision, where the loop first loses stability along `gains` (from a stable first
    entry), or None where it never does."""
    for before, g in zip(gains[:-1], gains[1:]):
        if not stable_at(loop, g):
            lo, hi = float(before), float(g)
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if stable_at(loop, mid) else (lo, mid)
            return 0.5 * (lo + hi)
    return None


def gain_margins(loop: Loop) -> tuple:
    """(lower, upper) gain margins (the module docstring); (nan, nan) where the loop is unstable at g = 1."""
    if not stable_at(loop, 1.0):
        return math.nan, math.nan
    upper = first_unstable(loop, np.geomspace(1.0, GAIN_MAX, GAIN_GRID))
    lower = first_unstable(loop, np.linspace(1.0, 0.0, GAIN_GRID))
    return (0.0 if lower is None or lower < MARGINAL else lower), (math.inf if upper is None else upper)


def delayed(loop: Loop, d: int) -> np.ndarray:
    """The loop with d control steps of delay, on (x_t, a_{t-1}, ..., a_{t-d}) where a_s = M x_s is computed at s and
    applied at s + d: x_{t+1} = A x_t + B_u a_{t-d}."""
    n, m = loop.Bu.shape
    if d == 0:
        return loop.A + loop.Bu @ loop.M
    big = np.zeros((n + d * m, n + d * m))
    big[:n, :n] = loop.A
    big[:n, n + (d - 1) * m:] = loop.Bu  # the oldest action is applied
    big[n:n + m, :n] = loop.M  # the newest computed
    for i in range(1, d):
        big[n + i * m:n + (i + 1) * m, n + (i - 1) * m:n + i * m] = np.eye(m)
    return big


def delay_margin(loop: Loop, max_steps: int = DELAY_MAX) -> int:
    """The most control steps of delay with every delay up to it stable; -1 where the loop itself is unstable."""
    for d in range(max_steps + 1):
        if spectral_radius(delayed(loop, d)) >= 1.0:
            return d - 1
    return max_steps


def peak_at(loop: Loop, w: float) -> float:
    """sigma_max(S - I/2) at z = e^{jw} (0 where the open loop has a pole there: L unbounded, S = 0)."""
    n, m = loop.Bu.shape
    z = np.exp(1j * w)
    try:
        L = -loop.M @ np.linalg.solve(z * np.eye(n) - loop.A, loop.Bu)
        S = np.linalg.inv(np.eye(m) + L)
    except np.linalg.LinAlgError:
        S = np.zeros((m, m))
    return float(np.linalg.svd(S - 0.5 * np.eye(m), compute_uv=False)[0])


def refined_peak(loop: Loop, lo: float, hi: float, iters: int = 60) -> float:
    """The largest sigma_max(S - I/2) between two grid frequencies around the grid's peak (golden-section search)."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    for _ in range(iters):
        c, d = b - g * (b - a), a + g * (b - a)
        a, b = (a, d) if peak_at(loop, c) > peak_at(loop, d) else (c, b)
    return peak_at(loop, 0.5 * (a + b))


def disk_margin(loop: Loop, points: int = FREQUENCIES) -> dict:
    """The symmetric disk margin (module docstring) -> {"alpha", "gain_range": [low, high], "phase_deg"}; alpha 0
    where the loop is unstable."""
    if not stable_at(loop, 1.0):
        return {"alpha": 0.0, "gain_range": [1.0, 1.0], "phase_deg": 0.0}
    grid = np.linspace(0.0, np.pi, points)
    peaks = [peak_at(loop, w) for w in grid]
    i = int(np.argmax(peaks))
    worst = max(peaks[i], refined_peak(loop, grid[max(i - 1, 0)], grid[min(i + 1, points - 1)]))
    alpha = 1.0 / worst if worst > 0 else math.inf
    half = alpha / 2.0
    low, high = ((1 - half) / (1 + half), (1 + half) / (1 - half)) if half < 1 else (0.0, math.inf)
    return {"alpha": alpha, "gain_range": [low, high], "phase_deg": math.degrees(2.0 * math.atan(half))}


def linear_margins(loop: Loop) -> dict:
    """Every linear margin of the loop, and whether it is flagged (below FLAG_GAIN, FLAG_DELAY or FLAG_DISK)."""
    lower, upper = gain_margins(loop)
    delay, disk = delay_margin(loop), disk_margin(loop)
    checks = ((not upper >= FLAG_GAIN, f"upper gain margin {upper:.4g}x"),
              (not lower <= 1.0 / FLAG_GAIN, f"lower gain margin {lower:.4g}x"),
              (delay < FLAG_DELAY, f"delay margin {delay} control steps"),
              (not disk["alpha"] >= FLAG_DISK, f"disk margin {disk['alpha']:.3g}"))
    flags = [words for low, words in checks if low]
    channels = int(loop.Bu.shape[1])
    return {"gain_lower": lower, "gain_upper": upper, "delay_steps": delay, "disk": disk, "channels": channels,
            "flags": flags,
            "thresholds": {"gain": FLAG_GAIN, "delay_steps": FLAG_DELAY, "disk": FLAG_DISK}}


def perturbed_policy(ctrl: "Controller", a_fix: np.ndarray, gain: float = 1.0, delay: int = 0) -> "Policy":
    """The exported controller's policy (simulate.controller_policy) acting a* + gain (pi(obs) - a*), clipped to its
    bounds, `delay` control steps late (a* until the first computed action arrives). Stateful: one episode batch."""
    from gsa_jax.verify.simulate import controller_policy

    base, queue = controller_policy(ctrl), []
    low, high = ctrl.bounds() if ctrl.action_low is not None else (-np.inf, np.inf)

    def policy(obs, qpos, qvel):
        a = np.asarray(base(obs, qpos, qvel), np.float64)
        queue.append(np.clip(a_fix + gain * (a - a_fix), low, high))
        return queue.pop(0) if len(queue) > delay else np.broadcast_to(a_fix, a.shape).copy()

    return policy


class Plant(NamedTuple):
    system: "object"  # verify's System (task, ctrl)
    qref: np.ndarray  # [nq] the reference qpos of the tangent coordinates
    x: np.ndarray  # [2 nv] the fixed point, tangent
    action: np.ndarray  # [d_a] the controller's action there
    seed: int


def holds_on_plant(plant: Plant, gain: float = 1.0, delay: int = 0) -> dict:
    """Whether the perturbed loop holds the fixed point in MuJoCo C (module docstring) -> {"holds", "growth": the
    median over starts of the last tenth's largest deviation over the start's, "terminated": starts that ended}."""
    from gsa_jax.verify import roa
    from gsa_jax.verify.system import state_scale, wrap

    task = plant.system.task
    steps, scale = int(task.episode_length), state_scale(task)
    rng = np.random.default_rng(plant.seed)
    offsets = roa.sphere(rng, PLANT_STARTS, len(plant.x)) * PLANT_OFFSET * scale
    policy = perturbed_policy(plant.system.ctrl, plant.action, gain, delay)
    ep = roa.run_from(task, policy, plant.qref, plant.x + offsets, steps, record=True)
    tail = roa.tangent_states(task, plant.qref, ep, max(1, steps // 10))
    deviation = np.linalg.norm(wrap(task.model, tail - plant.x) / scale, axis=-1).max(axis=0)  # [B]
    growth = float(np.median(deviation / np.linalg.norm(offsets / scale, axis=-1)))
    ended = int(np.sum(ep.terminated | (ep.lengths < steps)))
    return {"holds": bool(ended == 0 and growth < 1.0), "growth": round(growth, 4), "terminated": ended}


def checked_gain(plant: Plant, margin: float) -> "dict | None":
    """A gain margin checked on the plant at CHECK_INSIDE and CHECK_OUTSIDE of its distance from 1 (None where the
    margin is 0, inf or nan: nothing to cross)."""
    if not (0.0 < margin < math.inf):
        return None
    inside, outside = (1.0 + f * (margin - 1.0) for f in (CHECK_INSIDE, CHECK_OUTSIDE))
    at_in, at_out = holds_on_plant(plant, gain=inside), holds_on_plant(plant, gain=max(outside, 0.0))
    return {"inside": round(inside, 5), "outside": round(max(outside, 0.0), 5), "holds_inside": at_in,
            "holds_outside": at_out, "confirmed": bool(at_in["holds"] and not at_out["holds"])}


def checked_delay(plant: Plant, margin: int) -> "dict | None":
    """The delay margin checked on the plant: it holds at the margin and not one step past it (None: unstable)."""
    if margin < 0 or margin >= DELAY_MAX:
        return None
    at, past = holds_on_plant(plant, delay=margin), holds_on_plant(plant, delay=margin + 1)
    return {"at": margin, "past": margin + 1, "holds_at": at, "holds_past": past,
            "confirmed": bool(at["holds"] and not past["holds"])}


def certificate_margins(system: "object", qref: np.ndarray, cert: dict, seed: int = 0) -> dict:
    """The margins of a certificate's fixed point (its piece's linearization there) with their plant checks; the
    record verify.json keeps as the certificate's 'margins'."""
    from gsa_jax.verify import linearize as lin
    from gsa_jax.verify.certify import tangent_state
    from gsa_jax.verify.simulate import controller_policy

    task, ctrl = system.task, system.ctrl
    x = tangent_state(task, qref, cert["qpos"], cert["qvel"])
    L = lin.linearize(task, lambda obs: lin.piece_jacobian(ctrl, obs, cert["piece"]), qref, x)
    obs = lin.observe_at(task, np.array(cert["qpos"]), np.array(cert["qvel"]))
    action = np.asarray(controller_policy(ctrl)(obs[None], None, None), np.float64)[0]
    out = linear_margins(loop_of(L))
    plant = Plant(system, qref, x, action, seed)
    out["plant"] = {"gain_upper": checked_gain(plant, out["gain_upper"]),
                    "gain_lower": checked_gain(plant, out["gain_lower"]),
                    "delay": checked_delay(plant, out["delay_steps"])}
    return out
