"""The controller under verification, its task definition in MuJoCo C, and the state coordinates the analyses use.

A state is x = (dq [nv], v [nv]): qpos as a tangent displacement from a reference qpos (mj_differentiatePos) and
qvel. Searches work in *scaled* coordinates x / scale, where scale is the task's start-law spread per coordinate
(uniform half-width or normal std; 1 in SI units where that spread is 0 or above 1, e.g. an angle drawn over the
whole circle), so that radius 1 is the size of the start law.
"""

import os
import zipfile
from typing import TYPE_CHECKING, NamedTuple

import mujoco
import numpy as np

from envs.task import Task
from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment import numpy_policy
from gsa_jax.errors import UserError

if TYPE_CHECKING:
    from envs.families.record import TaskRecord


class VerifyError(UserError):
    """A one-line error of `gsa verify` (exit code 2)."""


C_TWINS = ("gymnasium's v5 tasks (Hopper-v5, Walker2d-v5, HalfCheetah-v5, Ant-v5, InvertedDoublePendulum-v5), "
           "the DeepMind Control Suite's (dmc:<domain>-<task>), Brax's hopper, walker2d, halfcheetah and ant, "
           "and a task of your own (module:Class, envs/task.py)")


class System(NamedTuple):
    ctrl: numpy_policy.Controller
    task: object  # envs.task.Task: the task definition MuJoCo C steps
    env: str  # the task's name as the controller names it
    path: str


def load_system(path: str, force: bool = False) -> System:
    """The controller at `path` and its task's definition; VerifyError (one line) for a file that is not an exported
    controller, a task without a MuJoCo C twin, an observation size that differs from the task's, or (unless force) a
    task whose definition changed since the controller was trained (numpy_policy.check_task, as deploy refuses it)."""
    ctrl, env = _load_controller(path)
    record = _task_record(ctrl, env)
    task = record.new()
    d_s, d_in = task.observation_size, controller_input_size(ctrl)
    if d_in != d_s:
        raise VerifyError(f"{path!r} takes observations of size {d_in} but its task {env!r} observes {d_s}: "
                          "it was exported for another version of the task")
    try:
        numpy_policy.check_task(ctrl.arrays, record, force, name=repr(path))
    except numpy_policy.TaskMismatch as e:
        raise VerifyError(str(e)) from None
    if task.goal_size:
        raise VerifyError(f"{env!r} draws a goal at reset, which verify does not search over yet")
    return System(ctrl, task, env, path)


def _load_controller(path):
    import json

    if not os.path.exists(path):
        raise VerifyError(f"{path!r} does not exist (make one with gsa export RUN --out FILE)")
    if not zipfile.is_zipfile(path):
        raise VerifyError(f"{path!r} is not an exported controller (not an .npz archive)")
    try:
        ctrl = numpy_policy.load(path)
        env = str(json.loads(str(ctrl.arrays["config_json"]))["config"]["env"])
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise VerifyError(f"{path!r} is not an exported controller ({' '.join(str(e).split())})") from None
    return ctrl, env


def _task_record(ctrl: numpy_policy.Controller, env: str) -> "TaskRecord":
    """The record of the controller's task (numpy_policy.controller_task), whose definition verify steps; VerifyError
    (one line) where it does not resolve here or has no MuJoCo C twin."""
    try:
        record = numpy_policy.controller_task(ctrl.arrays)
    except (ValueError, ImportError) as e:
        raise VerifyError(f"the controller is for {env!r}: {' '.join(str(e).split())}") from None
    if not record.verifiable:
        raise VerifyError(f"the controller is for {env!r}, which has no MuJoCo C twin verify can step; "
                          f"these have one: {C_TWINS}")
    return record


def controller_input_size(ctrl: numpy_policy.Controller) -> int:
    """d_s the controller reads: its normalizer's size, or where a mixture's pieces take the features of another
    size, that size's (the d_s whose features, by the sub-policy class's entry, are as wide as L [K, d_a, d_phi])."""
    d = int(np.shape(ctrl.obs_mean)[-1])
    if ctrl.kind != MIXTURE:
        return d
    size, d_phi = subpolicies.get(ctrl.subpolicy).size, int(ctrl.L.shape[-1])
    return next((n for n in (d, *range(1, d_phi + 1)) if size(n) == d_phi), d)


def start_spread(task: Task) -> tuple:
    """(qpos half-widths [nv], qvel half-widths [nv]) of the start law: uniform half-width or normal std per
    coordinate (tangent coordinates: hinge and slide joints map one to one)."""
    m = task.model
    q = np.broadcast_to(np.asarray(task.noise, np.float64), (m.nq,))
    v = np.broadcast_to(np.asarray(task.vel_scale, np.float64), (m.nv,))
    if m.nq != m.nv:  # quaternions: no per-coordinate law in tangent space; the mean over the qpos entries
        q = np.full(m.nv, float(np.mean(q)))
    return np.array(q, np.float64), np.array(v, np.float64)


def state_scale(task: Task) -> np.ndarray:
    """[2 nv] the scale of each state coordinate: its start-law spread, 1 where that is 0 or above 1."""
    s = np.concatenate(start_spread(task))
    return np.where((s > 0) & (s <= 1.0), s, 1.0)


def to_qpos(model: mujoco.MjModel, qref: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """[..., nq] qpos of tangent displacements dq [..., nv] from qref [nq]."""
    dq = np.atleast_2d(dq)
    out = np.tile(qref, (len(dq), 1)).astype(np.float64)
    for i in range(len(dq)):
        mujoco.mj_integratePos(model, out[i], dq[i], 1.0)
    return out


def to_tangent(model: mujoco.MjModel, qref: np.ndarray, qpos: np.ndarray) -> np.ndarray:
    """[..., nv] tangent displacements of qpos [..., nq] from qref [nq]."""
    qpos = np.atleast_2d(qpos)
    out = np.zeros((len(qpos), model.nv))
    for i in range(len(qpos)):
        mujoco.mj_differentiatePos(model, out[i], 1.0, np.asarray(qref, np.float64), np.asarray(qpos[i], np.float64))
    return out


def periodic_dofs(model: mujoco.MjModel) -> np.ndarray:
    """[nv] bool: the degrees of freedom of unlimited hinge joints (an angle and that angle + 2 pi are one state)."""
    mask = np.zeros(model.nv, bool)
    for j in range(model.njnt):
        if int(model.jnt_type[j]) == mujoco.mjtJoint.mjJNT_HINGE and not model.jnt_limited[j]:
            mask[model.jnt_dofadr[j]] = True
    return mask


def wrap(model: mujoco.MjModel, x: np.ndarray) -> np.ndarray:
    """Tangent states x [..., 2 nv] with the periodic coordinates' displacements wrapped into [-pi, pi)."""
    x = np.array(x, np.float64)
    dq = x[..., : model.nv]
    periodic = periodic_dofs(model)
    dq[..., periodic] = np.mod(dq[..., periodic] + np.pi, 2 * np.pi) - np.pi
    return x


def equilibrium_guess(task: Task) -> "np.ndarray | None":
    """[nq] the task's declared equilibrium qpos (Task.equilibrium_qpos: the upright of a pendulum), or None."""
    q = getattr(task, "equilibrium_qpos", None)
    return None if q is None else np.asarray(q, np.float64).reshape(task.model.nq)


LIMIT_SHARE = 0.01  # of a joint's range: a position this close to one of its ends is at that limit


def joints_at_limit(model: mujoco.MjModel, qpos: np.ndarray) -> list:
    """The names of the limited hinge and slide joints (a cart's rail included) whose position in qpos [nq] lies
    within the limit's margin of an end of their range, or past it: max(jnt_margin, LIMIT_SHARE x range width)."""
    out = []
    for j in range(model.njnt):
        kind = int(model.jnt_type[j])
        if kind not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE) or not model.jnt_limited[j]:
            continue
        lo, hi = model.jnt_range[j]
        q = float(qpos[model.jnt_qposadr[j]])
        if min(q - lo, hi - q) <= max(float(model.jnt_margin[j]), LIMIT_SHARE * (hi - lo)):
            out.append(model.joint(j).name)
    return out
