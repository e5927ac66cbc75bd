"""Batched closed-loop episodes of a task definition in MuJoCo C (mujoco.batch: one thread, bit-identical to
mj_step on one MjData per simulation), stepped as envs.task.TaskC steps one: the task's controls(), frame_skip
mj_steps (mj_step1 after them for derived_after 'step1'), its outcome() in float64.

A policy maps (obs [B, d_s], qpos [B, nq], qvel [B, nv]) to actions [B, d_a] in the task's action space (what
controls() takes). A push is a horizontal force on the task's push body during one env step (as
gsa_jax.deployment.shifts.step_task applies it).
"""

from typing import Callable, NamedTuple, Optional

import mujoco
import numpy as np
from mujoco import batch as mj_batch

from envs.task import Task
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.deployment.pushes import act_each

Policy = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class Push(NamedTuple):
    step: np.ndarray  # [B] int: the env step during which the force acts (-1: no push)
    force: np.ndarray  # [B, 2] the horizontal force (N) on the push body


class Episodes(NamedTuple):
    returns: np.ndarray  # [B] summed rewards until termination or the step limit
    lengths: np.ndarray  # [B] steps taken (the terminating one included)
    terminated: np.ndarray  # [B] bool
    qpos: np.ndarray  # [T + 1, B, nq] states visited (only the last when not recorded: [1, B, nq])
    qvel: np.ndarray  # [T + 1, B, nv]
    obs: np.ndarray  # [T + 1, B, d_s] observations (likewise)
    margin: "np.ndarray | None" = None  # [B] the least Task.termination_margin over the steps taken (None: not exposed)


def controller_policy(ctrl: Controller) -> Policy:
    """The exported controller's deterministic action (clipped to its bounds), computed for each observation alone
    as deployment computes it (gsa_jax.deployment.pushes.act_each: a batched float32 product rounds differently)."""
    return lambda obs, qpos, qvel: act_each(ctrl, obs)


def push_impulse(task: Task, velocity: float) -> float:
    """The force (N) over one env step that changes the whole robot's velocity by `velocity` m/s."""
    return velocity * float(np.sum(task.model.body_mass)) / (task.model.opt.timestep * task.frame_skip)


def _derived(task, b):
    return {f: getattr(b, f) for f in task.derived}


def _start(task, qpos, qvel, threads):
    b = mj_batch.Batch(task.model, nsim=len(qpos), nthread=threads)
    for f in task.derived:
        b.bind(f)
    b.reset(stage=int(mujoco.mjtStage.mjSTAGE_NONE))
    b.qpos[:], b.qvel[:] = qpos, qvel
    b.forward()
    return b, task.observe(b.qpos, b.qvel, _derived(task, b))


def run(task: Task, policy: Policy, qpos: np.ndarray, qvel: np.ndarray, steps: int, push: Optional[Push] = None,
        record: bool = False, threads: int = 1) -> Episodes:
    """B closed-loop episodes from qpos [B, nq], qvel [B, nv] for `steps` env steps at most."""
    b, obs = _start(task, np.asarray(qpos, np.float64), np.asarray(qvel, np.float64), threads)
    n = len(qpos)
    stage = int(mujoco.mjtStage.mjSTAGE_VEL) if task.derived_after == "step1" else 0
    body = task.push_body_id()
    alive, returns, lengths, margin = np.ones(n, bool), np.zeros(n), np.zeros(n, int), np.full(n, np.inf)
    traj = [(b.qpos.copy(), b.qvel.copy(), obs.copy())]
    for t in range(steps):
        before = task.before(b.qpos, _derived(task, b))
        u = task.controls(np.asarray(policy(obs, b.qpos, b.qvel), np.float64))
        b.ctrl[:] = u
        pushed = np.flatnonzero(push.step == t) if push is not None else []
        if len(pushed):
            b.xfrc_applied[pushed, body, :2] = push.force[pushed]
        b.step(nstep=task.frame_skip, stage=stage)
        if len(pushed):
            b.xfrc_applied[pushed, body, :2] = 0.0
        obs, reward, terminated = task.outcome(before, b.qpos, b.qvel, _derived(task, b), u)
        m = task.termination_margin(b.qpos, b.qvel, _derived(task, b))
        margin = np.where(alive, np.minimum(margin, m), margin) if m is not None else None
        returns += np.where(alive, reward, 0.0)
        lengths += alive
        alive &= ~np.asarray(terminated, bool)
        if record:
            traj.append((b.qpos.copy(), b.qvel.copy(), obs.copy()))
        if not alive.any():
            break
    if not record:
        traj = [(b.qpos.copy(), b.qvel.copy(), obs.copy())]
    qs, vs, os_ = (np.stack(x) for x in zip(*traj))
    return Episodes(returns, lengths, ~alive, qs, vs, os_, margin)
