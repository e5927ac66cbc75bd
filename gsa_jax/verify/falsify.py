"""Falsification: a cross-entropy search for the lowest-return episodes over start states and pushes, and its
counterexamples judged by their neighbours.

Search space, u in [-1, 1]^p: the start state centre + f x spread x u (the task's start law, envs/task.py: centre
start_qpos at rest, spread its uniform half-width or normal std per coordinate; f = 1 within the start law, 2 up
to twice its spread), and with pushes (push=True) the push's step (uniform over the episode's first 90%) and its
velocity change along each horizontal axis the push body moves along (push_axes; up to PUSH_SPEED m/s of the whole
robot in all, as gsa_jax.deployment.pushes sizes them), a force on the task's push body during that step. Each
iteration draws `population` from a Gaussian (mean 0, std 0.5 at first, clipped to the box), keeps the `elite` lowest
returns and refits the Gaussian to them: population x iterations episodes per search, the same for every controller.
A wider search starts from a narrower one's worst cases (evaluated with its first iteration; the same episodes, so
the wider's worst is at most the narrower's) and keeps their verdicts.

A counterexample is replayable: qpos, qvel, push (null, or body, force [fx, fy], velocity change, step: recorded only
where it acted within the episode), return and steps, the return and steps as plain MuJoCo C gives them
(envs.task.TaskC, one MjData, the controller acting on one observation at a time, step_task for the push). It fails
when its return is below the failure threshold (the nominal episodes' worst); NEIGHBOURS starts within PERTURBATION
scaled units of it (uniform in that ball; a push's velocity change within PERTURBATION x PUSH_SPEED m/s of its own,
at its step), the same offsets for every counterexample, give the share that fail too; a failing counterexample with
a share below KNIFE_EDGE is knife-edge, and is kept out of the worst return. Its robustness: how far past the
termination condition it went, in that condition's units (Task.termination_margin; negative: the closest it came),
or where the task exposes none, its return's shortfall below the threshold.
"""

from typing import NamedTuple

import mujoco
import numpy as np

from envs.task import Task, TaskC
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.deployment.pushes import PUSH_SIZES
from gsa_jax.deployment.shifts import step_task
from gsa_jax.verify import roa, simulate
from gsa_jax.verify.system import start_spread, to_qpos

PUSH_SPEED = max(PUSH_SIZES)  # m/s: the largest push the robustness study uses
PERTURBATION = 1e-3  # scaled units: how far from a counterexample its neighbours start
NEIGHBOURS = 20  # perturbed starts per counterexample
KNIFE_EDGE = 0.25  # a failing counterexample whose neighbours fail less often than this is knife-edge
AXES = ("x", "y")


class Search(NamedTuple):
    returns: np.ndarray  # [iterations, population] every drawn episode's return, in order
    params: np.ndarray  # [iterations, population, p] their points in the box
    best: np.ndarray  # [iterations] the lowest return so far after each iteration (seeds included)
    seeded_returns: np.ndarray  # [S] the returns of the points it started from (evaluated with the first iteration)
    seeded_params: np.ndarray  # [S, p]


class Sampling(NamedTuple):
    """What one search draws: starts (and a push if push) up to `spread` times the start law's, `population`
    episodes per iteration for `iterations` iterations from `seed`, the best `elite_frac` refitting the law."""

    push: bool
    spread: float = 1.0
    population: int = 64
    iterations: int = 8
    seed: int = 0
    elite_frac: float = 0.125


def push_axes(task: Task) -> list:
    """The horizontal world axes (0: x, 1: y) the task's push body moves along at its start state (a non-zero row of
    its centre of mass's translation Jacobian), x only for a task that says it is planar."""
    m = task.model
    d = mujoco.MjData(m)
    d.qpos[:] = task.start_qpos
    mujoco.mj_forward(m, d)
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jacBodyCom(m, d, jacp, None, task.push_body_id())
    axes = [i for i in (0, 1) if np.abs(jacp[i]).max() > 1e-9]
    return [i for i in axes if i == 0] if getattr(task, "planar", False) else axes


def box_size(task: Task, push: bool) -> int:
    """p: the search box's dimension."""
    return 2 * task.model.nv + (1 + len(push_axes(task)) if push else 0)


def decode(task: Task, u: np.ndarray, horizon: int, sampling: Sampling) -> tuple:
    """(qpos [B, nq], qvel [B, nv], simulate.Push or None) of points u [B, p] in a search's box."""
    m, nv, spread = task.model, task.model.nv, sampling.spread
    sq, sv = start_spread(task)
    qpos, v = to_qpos(m, task.start_qpos, spread * sq * u[:, :nv]), spread * sv * u[:, nv:2 * nv]
    if not sampling.push:
        return qpos, v, None
    axes = push_axes(task)
    step = np.floor((u[:, 2 * nv] + 1) / 2 * (0.9 * horizon - 1)).astype(int)
    dv = np.zeros((len(u), 2))
    dv[:, axes] = PUSH_SPEED * u[:, 2 * nv + 1:] / np.sqrt(max(1, len(axes)))  # |dv| <= PUSH_SPEED
    return qpos, v, simulate.Push(step, simulate.push_impulse(task, 1.0) * dv)


def lift(task: Task, z: np.ndarray, sampling: Sampling) -> np.ndarray:
    """[S, p] points of a search's box for start offsets z [S, 2 nv] in units of the start law's spread (a narrower
    search's starts, without a push: its step 0, its velocity change 0)."""
    u = np.asarray(z, np.float64).reshape(-1, 2 * task.model.nv) / sampling.spread
    if sampling.push:
        u = np.concatenate([u, -np.ones((len(u), 1)), np.zeros((len(u), len(push_axes(task))))], axis=1)
    return u


def cem(task: Task, policy: simulate.Policy, horizon: int, sampling: Sampling,
        seeds: "np.ndarray | None" = None) -> Search:
    """The cross-entropy search (see the module docstring), its first iteration with the points seeds [S, p]."""
    population, p = sampling.population, box_size(task, sampling.push)
    rng = np.random.default_rng(sampling.seed)
    mean, std = np.zeros(p), np.full(p, 0.5)
    n_elite = max(2, int(round(sampling.elite_frac * population)))
    seeds = np.zeros((0, p)) if seeds is None else np.asarray(seeds, np.float64)
    rets, pars, best, seeded = [], [], [], np.zeros(0)
    for it in range(sampling.iterations):
        u = np.clip(mean + std * rng.standard_normal((population, p)), -1.0, 1.0)
        every = np.concatenate([seeds, u]) if it == 0 else u
        qpos, qvel, pushes = decode(task, every, horizon, sampling)
        r = simulate.run(task, policy, qpos, qvel, horizon, push=pushes).returns
        elite = every[np.argsort(r)[:n_elite]]
        mean, std = elite.mean(0), np.maximum(elite.std(0), 0.02)
        if it == 0:
            seeded, r = r[:len(seeds)], r[len(seeds):]
        rets.append(r)
        pars.append(u)
        best.append(min(r.min(), seeded.min() if len(seeded) else np.inf, best[-1] if best else np.inf))
    return Search(np.array(rets), np.array(pars), np.array(best), seeded, seeds)


def replay(task: Task, ctrl: Controller, qpos: np.ndarray, qvel: np.ndarray, push: "dict | None",
           horizon: int) -> tuple:
    """(return, steps) of one episode in plain MuJoCo C from (qpos, qvel) with push None or
    {"step", "force"}: the counterexample's own check."""
    tc = TaskC(task)
    obs = tc.set_start(np.asarray(qpos, np.float64), np.asarray(qvel, np.float64))
    total, t = 0.0, 0
    for t in range(1, horizon + 1):
        force = np.asarray(push["force"], np.float64) if push is not None and push["step"] == t - 1 else np.zeros(2)
        obs, r, done = step_task(tc, ctrl.act(np.asarray(obs, np.float32)), force)
        total += r
        if done:
            break
    return total, t


class Judge(NamedTuple):
    """How counterexamples are judged: the return below which an episode fails, the state's scale [2 nv] (scaled
    coordinates, gsa_jax.verify.system), the neighbours per counterexample and the seed of their offsets."""

    threshold: float
    scale: np.ndarray
    neighbours: int = NEIGHBOURS
    seed: int = 0


def neighbours(task: Task, judge: Judge, qpos: np.ndarray, qvel: np.ndarray, pushes: simulate.Push) -> tuple:
    """(qpos [C N, nq], qvel [C N, nv], simulate.Push) of N = judge.neighbours starts around each of C starts (qpos
    [C, nq], qvel [C, nv]), their pushes' velocity changes perturbed where they push (step >= 0): the module
    docstring's offsets, the same for every start."""
    m, nv, n = task.model, task.model.nv, judge.neighbours
    rng = np.random.default_rng([judge.seed, 2])
    d = PERTURBATION * roa.ball(rng, n, 2 * nv) * judge.scale
    dv = np.zeros((n, 2))
    axes = push_axes(task)
    dv[:, axes] = PERTURBATION * PUSH_SPEED * roa.ball(rng, n, max(1, len(axes)))[:, :len(axes)]
    q = np.concatenate([to_qpos(m, qc, d[:, :nv]) for qc in qpos])
    v = np.repeat(qvel, n, axis=0) + np.tile(d[:, nv:], (len(qpos), 1))
    pushed = np.repeat(pushes.step >= 0, n)
    force = np.repeat(pushes.force, n, axis=0) + np.where(pushed[:, None], simulate.push_impulse(task, 1.0), 0.0) * \
        np.tile(dv, (len(qpos), 1))
    return q, v, simulate.Push(np.repeat(pushes.step, n), force)


def push_record(task: Task, push: "simulate.Push | None", j: int, steps: int) -> "dict | None":
    """The j-th start's push as a counterexample records it, None where it did not act within its `steps` steps."""
    if push is None or not 0 <= push.step[j] < steps or not np.any(push.force[j]):
        return None
    return {"body": task.model.body(task.push_body_id()).name, "step": int(push.step[j]),
            "force": [float(f) for f in push.force[j]],
            "velocity_change": [float(f) for f in push.force[j] / simulate.push_impulse(task, 1.0)]}


def examine(task: Task, ctrl: Controller, horizon: int, judge: Judge, qpos: np.ndarray, qvel: np.ndarray,
            pushes: "simulate.Push | None") -> list:
    """The counterexample records (module docstring) of C starts qpos [C, nq], qvel [C, nv] with pushes (or None):
    replayed in plain MuJoCo C, their neighbours' failing share, knife-edge or not, their robustness."""
    policy, c = simulate.controller_policy(ctrl), len(qpos)
    ep = simulate.run(task, policy, qpos, qvel, horizon, push=pushes)
    recorded = [push_record(task, pushes, j, int(ep.lengths[j])) for j in range(c)]
    acted = simulate.Push(np.array([p["step"] if p else -1 for p in recorded]),
                          np.array([p["force"] if p else [0.0, 0.0] for p in recorded]))
    nb_qpos, nb_qvel, nb_push = neighbours(task, judge, qpos, qvel, acted)
    nb = simulate.run(task, policy, nb_qpos, nb_qvel, horizon, push=nb_push)
    share = (nb.returns.reshape(c, judge.neighbours) < judge.threshold).mean(1)
    fails = ep.returns < judge.threshold
    robust = -ep.margin if ep.margin is not None else judge.threshold - ep.returns
    out = []
    for j in range(c):
        ret, steps = replay(task, ctrl, qpos[j], qvel[j], recorded[j], horizon)
        out.append({"qpos": [float(q) for q in qpos[j]], "qvel": [float(v) for v in qvel[j]], "push": recorded[j],
                    "return": float(ret), "steps": int(steps), "search_return": float(ep.returns[j]),
                    "fails": bool(fails[j]), "neighbours_failing": float(share[j]),
                    "knife_edge": bool(fails[j] and share[j] < KNIFE_EDGE), "robustness": float(robust[j])})
    return out


def robustness_measure(task: Task) -> str:
    """What a counterexample's robustness measures on this task (module docstring)."""
    d = mujoco.MjData(task.model)
    derived = {f: getattr(d, f)[None] for f in task.derived}
    exposed = task.termination_margin(task.start_qpos[None], np.zeros((1, task.model.nv)), derived) is not None
    return ("how far past the termination condition the episode went, in that condition's units "
            "(Task.termination_margin; negative: the closest it came)" if exposed else
            "the return's shortfall below the failure threshold (return units): the task exposes no termination margin")


def distinct_lowest(u: np.ndarray, r: np.ndarray, count: int) -> np.ndarray:
    """Indices of the `count` lowest returns r [N] among distinct points u [N, p]."""
    order = np.argsort(r)
    picked = []
    for i in order:
        if len(picked) == count:
            break
        if not any(np.allclose(u[i], u[j]) for j in picked):
            picked.append(i)
    return np.array(picked, int)


def search(task: Task, ctrl: Controller, horizon: int, sampling: Sampling, judge: Judge, count: int,
           inherited: tuple = ()) -> dict:
    """One search with its `count` lowest distinct episodes judged (examine) and its worst return without knife-edge
    counterexamples; inherited: a narrower search's '_inherit' records, started from and kept with their verdicts."""
    n = 2 * task.model.nv
    seeds = lift(task, np.array([c["_z"] for c in inherited]), sampling) if inherited else None
    s = cem(task, simulate.controller_policy(ctrl), horizon, sampling, seeds)
    u, r = s.params.reshape(-1, s.params.shape[-1]), s.returns.ravel()
    picked = distinct_lowest(u, r, count)
    own = [{**c, "inherited": False, "_z": (u[i, :n] * sampling.spread).tolist()}
           for c, i in zip(examine(task, ctrl, horizon, judge, *decode(task, u[picked], horizon, sampling)), picked)]
    knife_u = u[picked][[c["knife_edge"] for c in own]]
    clear = np.array([not any(np.allclose(x, k) for k in knife_u) for x in u])
    kept = [{**c, "inherited": True} for c in inherited if c.get("judged", True)]
    judged = sorted(own + kept, key=lambda c: c["search_return"])
    worst_robust = min([c["search_return"] for c in inherited if not c.get("knife_edge")] +
                       ([float(r[clear].min())] if clear.any() else []), default=None)
    unjudged = [i for i in np.argsort(r) if clear[i] and i not in picked][:1]
    onward = judged + [c for c in inherited if not c.get("judged", True)] + [
        {"_z": (u[i, :n] * sampling.spread).tolist(), "search_return": float(r[i]), "knife_edge": False,
         "judged": False} for i in unjudged]
    return {"spread": sampling.spread, "pushes": sampling.push,
            "push_axes": [AXES[i] for i in push_axes(task)] if sampling.push else [],
            "episodes": int(r.size + len(inherited)), "worst_return": worst_robust,
            "worst_return_with_knife_edges": float(min([r.min()] + [c["search_return"] for c in inherited])),
            "knife_edge_counterexamples": int(sum(c["knife_edge"] for c in judged)),
            "first_iteration_p05": float(np.percentile(s.returns[0], 5)), "best_by_iteration": s.best.tolist(),
            "counterexamples": judged[:count], "_inherit": onward}


def start_law_states(task: Task, episodes: int, seed: int) -> tuple:
    """(qpos [E, nq], qvel [E, nv]) drawn by the task's own reset (TaskC.reset(seed + e))."""
    tc = TaskC(task)
    qs, vs = [], []
    for e in range(episodes):
        tc.reset(seed + e)
        qs.append(tc.data.qpos.copy())
        vs.append(tc.data.qvel.copy())
    return np.array(qs), np.array(vs)
