"""Falsification: a cross-entropy search for the lowest-return episodes over start states and pushes.

Search space, u in [-1, 1]^p: the start state centre + f x spread x u (the task's start law, envs/task.py: centre
start_qpos at rest, spread its uniform half-width or normal std per coordinate; f = 1 within the start law, 2 up
to twice its spread), and
with pushes (push=True) three more: the push's step (uniform over the episode's first 90%), and its velocity change
along x and y (up to PUSH_SPEED m/s of the whole robot, as gsa_jax.deployment.pushes sizes them; along x only for a
planar robot), a force on the task's push body during that step. Each iteration draws `population` from a Gaussian
(mean 0, std 0.5 at first, clipped to the box), keeps the `elite` lowest returns and refits the Gaussian to them:
population x iterations episodes per search, the same for every controller.

A counterexample is replayable: qpos, qvel, push (null, or body, force [fx, fy], velocity change, step), return and
steps, the return and steps as plain MuJoCo C gives them (envs.task.TaskC, one MjData, the controller acting on one
observation at a time, gsa_jax.deployment.shifts.step_task for the push).
"""

from typing import NamedTuple

import numpy as np

from envs.task import Task, TaskC
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.deployment.pushes import PUSH_SIZES
from gsa_jax.deployment.shifts import step_task
from gsa_jax.verify import simulate
from gsa_jax.verify.system import start_spread, to_qpos

PUSH_SPEED = max(PUSH_SIZES)  # m/s: the largest push the robustness study uses


class Search(NamedTuple):
    returns: np.ndarray  # [iterations, population] every episode's return, in order
    params: np.ndarray  # [iterations, population, p] their points in the box
    best: np.ndarray  # [iterations] the lowest return so far after each iteration


def decode(task: Task, u: np.ndarray, horizon: int, push: bool, spread: float) -> tuple:
    """(qpos [B, nq], qvel [B, nv], simulate.Push or None) of points u [B, p] in the search box (spread: f)."""
    m, nv = task.model, task.model.nv
    sq, sv = start_spread(task)
    dq, v = spread * sq * u[:, :nv], spread * sv * u[:, nv:2 * nv]
    qpos = to_qpos(m, task.start_qpos, dq)
    if not push:
        return qpos, v, None
    step = np.floor((u[:, 2 * nv] + 1) / 2 * (0.9 * horizon - 1)).astype(int)
    dv = PUSH_SPEED * u[:, 2 * nv + 1:2 * nv + 3] / np.sqrt(2.0)  # |dv| <= PUSH_SPEED
    if getattr(task, "planar", False):
        dv = np.stack([PUSH_SPEED * u[:, 2 * nv + 1], np.zeros(len(u))], axis=1)
    return qpos, v, simulate.Push(step, simulate.push_impulse(task, 1.0) * dv)


class Sampling(NamedTuple):
    """What one search draws: starts (and a push if push) up to `spread` times the start law's, `population`
    episodes per iteration for `iterations` iterations from `seed`, the best `elite_frac` refitting the law."""

    push: bool
    spread: float = 1.0
    population: int = 64
    iterations: int = 8
    seed: int = 0
    elite_frac: float = 0.125


def cem(task: Task, policy: simulate.Policy, horizon: int, sampling: Sampling) -> Search:
    """The cross-entropy search (see the module docstring)."""
    push, population = sampling.push, sampling.population
    p = 2 * task.model.nv + (3 if push else 0)
    rng = np.random.default_rng(sampling.seed)
    mean, std = np.zeros(p), np.full(p, 0.5)
    n_elite = max(2, int(round(sampling.elite_frac * population)))
    rets, pars, best = [], [], []
    for _ in range(sampling.iterations):
        u = np.clip(mean + std * rng.standard_normal((population, p)), -1.0, 1.0)
        qpos, qvel, pushes = decode(task, u, horizon, push, sampling.spread)
        r = simulate.run(task, policy, qpos, qvel, horizon, push=pushes).returns
        elite = u[np.argsort(r)[:n_elite]]
        mean, std = elite.mean(0), np.maximum(elite.std(0), 0.02)
        rets.append(r)
        pars.append(u)
        best.append(min(r.min(), best[-1] if best else np.inf))
    return Search(np.array(rets), np.array(pars), np.array(best))


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


def counterexamples(task: Task, ctrl: Controller, search: Search, horizon: int, push: bool, spread: float,
                    count: int) -> list:
    """The `count` lowest-return distinct episodes of a search, replayed in plain MuJoCo C."""
    flat_r, flat_u = search.returns.ravel(), search.params.reshape(-1, search.params.shape[-1])
    order = np.argsort(flat_r)
    picked = [i for k, i in enumerate(order) if not any(np.allclose(flat_u[i], flat_u[j]) for j in order[:k])][:count]
    qpos, qvel, pushes = decode(task, flat_u[picked], horizon, push, spread)
    out = []
    for j, i in enumerate(picked):
        p = None
        if pushes is not None:
            p = {"body": task.model.body(task.push_body_id()).name, "step": int(pushes.step[j]),
                 "force": [float(f) for f in pushes.force[j]],
                 "velocity_change": [float(f) for f in pushes.force[j] / simulate.push_impulse(task, 1.0)]}
        ret, steps = replay(task, ctrl, qpos[j], qvel[j], p, horizon)
        out.append({"qpos": [float(q) for q in qpos[j]], "qvel": [float(v) for v in qvel[j]], "push": p,
                    "return": float(ret), "steps": int(steps), "search_return": float(flat_r[i])})
    return out


def start_law_states(task: Task, episodes: int, seed: int) -> tuple:
    """(qpos [E, nq], qvel [E, nv]) drawn by the task's own reset (TaskC.reset(seed + e))."""
    tc = TaskC(task)
    qs, vs = [], []
    for e in range(episodes):
        tc.reset(seed + e)
        qs.append(tc.data.qpos.copy())
        vs.append(tc.data.qvel.copy())
    return np.array(qs), np.array(vs)
