"""Local analysis: the closed loop linearized at a state, and its fixed points.

One control step of the task, x' = f(x, u), in tangent coordinates x = (dq [nv], v [nv]) around a reference qpos,
is linearized with MuJoCo's finite-difference transition derivatives (mjd_transitionFD) at each physics substep,
composed over the frame skip: A = A_n ... A_1, B = sum_k A_n ... A_{k+1} B_k. The controller closes the loop
through the observation: u = controls(pi(obs(x))), so the closed loop's Jacobian is A + B G K C with C = d obs / dx
(central differences of the task's observe() after mj_forward), K = d pi / d obs (exact: L_c through the normalizer
and the clips for a mixture's piece c, the tanh network's chain rule for flat PPO) and G = d controls / d action.
Observations read from derived fields are taken at the state itself (mj_forward), not one substep behind as
mj_step leaves them: the same wherever those fields are smooth in the state (at an equilibrium in particular).
"""

from typing import Callable, NamedTuple

import mujoco
import numpy as np

from envs.task import Task, TaskC
from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.kinds import MLP
from gsa_jax.deployment.cells import raw_logits
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.verify.system import to_qpos, to_tangent

FD_EPS = 1e-6  # finite-difference step (tangent coordinates, SI units), central differences


def normalized(ctrl: Controller, obs: np.ndarray) -> tuple:
    """(z [d_s] the normalizer's clipped output, d z / d obs [d_s], its diagonal) of the controller at obs [d_s]."""
    zraw = (np.asarray(obs, np.float64) - ctrl.obs_mean) / ctrl.obs_std
    dz = np.where(np.abs(zraw) < ctrl.obs_clip, 1.0 / ctrl.obs_std, 0.0)
    return np.clip(zraw, -ctrl.obs_clip, ctrl.obs_clip), dz


def raw_jacobian(ctrl: Controller, obs: np.ndarray, piece: "int | None" = None) -> tuple:
    """(raw action [d_a] before the action clip, d raw / d obs [d_a, d_s]) of the controller at obs [d_s]: piece
    `piece` of a mixture (None: the piece its partition picks there), or the flat network."""
    z, dz = normalized(ctrl, obs)
    if ctrl.kind == MLP:
        raw, jz = mlp_jacobian(ctrl.layers, z)
    else:
        c = int(ctrl.cluster(np.asarray(obs, np.float32))) if piece is None else int(piece)
        raw, jz = _subpolicy_jacobian(ctrl, c, z)
    return raw, jz * dz[None, :]


def piece_jacobian(ctrl: Controller, obs: np.ndarray, piece: "int | None" = None) -> tuple:
    """(action [d_a] as act() clips it, d action / d obs [d_a, d_s]) of the controller at obs [d_s]: piece `piece`
    of a mixture (None: the piece its partition picks there), or the flat network."""
    raw, j = raw_jacobian(ctrl, obs, piece)
    if ctrl.action_low is None:
        return raw, j
    inside = (raw > ctrl.action_low) & (raw < ctrl.action_high)
    return np.clip(raw, ctrl.action_low, ctrl.action_high), j * inside[:, None]


def mlp_jacobian(layers: list, z: np.ndarray) -> tuple:
    """(output, d output / d z) of a tanh MLP (layers [(w, b)]) at z."""
    h, jac = z, np.eye(len(z))
    for i, (w, b) in enumerate(layers):
        pre = h @ w + b
        jac = w.T.astype(np.float64) @ jac
        if i < len(layers) - 1:
            h = np.tanh(pre)
            jac = (1.0 - h * h)[:, None] * jac
        else:
            h = pre
    return h, jac


def logit_rows(ctrl: Controller, obs: np.ndarray) -> tuple:
    """(logits [K], d logits / d obs [K, d_s], exact) of a mixture's partition at obs [d_s] over its K active
    pieces: for a linear partition with no observation at the normalizer's clip, its own W and c with the
    normalization folded in (deployment.cells.raw_logits: the logits are exactly affine in obs there, so the cells
    these rows give are the partition's, exactly); for a single piece (K = 1) one logit, 0 everywhere (exact);
    otherwise the network's linearization at obs."""
    k = ctrl.num_clusters
    if ctrl.single_piece:
        return np.zeros(1), np.zeros((1, len(obs))), True
    z, dz = normalized(ctrl, obs)
    if partitions.get(ctrl.partition).polyhedral and np.all(dz > 0):
        w_raw, c_raw = raw_logits(ctrl)
        return np.asarray(obs, np.float64) @ w_raw + c_raw, w_raw.T, True
    logits, jl = mlp_jacobian(ctrl.layers, z)
    return logits[:k], jl[:k] * dz[None, :], False


def _subpolicy_jacobian(ctrl, c, z):
    """(L_c phi(z) + b_c [d_a], its Jacobian in z [d_a, d_s]) of piece c, phi the sub-policy class's features."""
    L, b = ctrl.L[c].astype(np.float64), ctrl.b[c].astype(np.float64)
    sub = subpolicies.get(ctrl.subpolicy)
    return L @ sub.features(z, np) + b, L @ sub.jacobian(z)


class Linearization(NamedTuple):
    A: np.ndarray  # [n, n] the task's control step, n = 2 nv
    B: np.ndarray  # [n, nu] d x' / d ctrl
    C: np.ndarray  # [d_s, n] d obs / d x
    G: np.ndarray  # [nu, d_a] d ctrl / d action
    K: np.ndarray  # [d_a, d_s] d action / d obs
    action: np.ndarray  # [d_a] the action there

    @property
    def closed(self) -> np.ndarray:
        """[n, n] the closed loop's Jacobian A + B G K C."""
        return self.A + self.B @ self.G @ self.K @ self.C


def observe_at(task: Task, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """[d_s] the task's observation of a state (mj_forward there)."""
    return np.asarray(TaskC(task).set_start(qpos, qvel), np.float64)


def observation_jacobian(task: Task, qref: np.ndarray, x: np.ndarray) -> np.ndarray:
    """[d_s, 2 nv] d obs / d x at tangent state x (central differences)."""
    nv = task.model.nv
    cols = []
    for i in range(2 * nv):
        e = np.zeros(2 * nv)
        e[i] = FD_EPS
        hi, lo = (observe_at(task, to_qpos(task.model, qref, s[:nv])[0], s[nv:]) for s in (x + e, x - e))
        cols.append((hi - lo) / (2 * FD_EPS))
    return np.stack(cols, axis=1)


def step_jacobians(task: Task, qpos: np.ndarray, qvel: np.ndarray, ctrl_u: np.ndarray) -> tuple:
    """(A [2nv, 2nv], B [2nv, nu]) of one control step from (qpos, qvel) with controls ctrl_u: composed over the
    frame skip from mjd_transitionFD at each substep, or (RK4, which mjd_transitionFD does not support) central
    differences of the whole control step."""
    m = task.model
    if m.na:
        raise ValueError("actuator activations are not part of the analysed state")
    if m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        return _step_differences(task, qpos, qvel, ctrl_u)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:] = qpos, qvel, ctrl_u
    mujoco.mj_forward(m, d)
    n = 2 * m.nv
    A, B = np.eye(n), np.zeros((n, m.nu))
    for _ in range(task.frame_skip):
        a_k, b_k = np.zeros((n, n)), np.zeros((n, m.nu))
        mujoco.mjd_transitionFD(m, d, FD_EPS, True, a_k, b_k, None, None)
        A, B = a_k @ A, a_k @ B + b_k
        mujoco.mj_step(m, d)
    return A, B


def _step_differences(task, qpos, qvel, ctrl_u):
    m, nv = task.model, task.model.nv
    d = mujoco.MjData(m)

    def step(dx, du):
        mujoco.mj_resetData(m, d)
        d.qpos[:] = to_qpos(m, qpos, dx[:nv])[0]
        d.qvel[:], d.ctrl[:] = qvel + dx[nv:], ctrl_u + du
        mujoco.mj_step(m, d, nstep=task.frame_skip)
        return np.concatenate([to_tangent(m, qpos, d.qpos)[0], d.qvel])

    def column(i):
        e = np.zeros(2 * nv + m.nu)
        e[i] = FD_EPS
        return (step(e[:2 * nv], e[2 * nv:]) - step(-e[:2 * nv], -e[2 * nv:])) / (2 * FD_EPS)

    cols = np.stack([column(i) for i in range(2 * nv + m.nu)], axis=1)
    return cols[:, :2 * nv], cols[:, 2 * nv:]


def controls_jacobian(task: Task, d_a: int) -> np.ndarray:
    """[nu, d_a] d controls / d action (identity, or the map onto the actuators' ctrlrange)."""
    if task.ctrl_range == "unit":
        return np.eye(task.model.nu, d_a)
    lo, hi = task.model.actuator_ctrlrange.T
    return np.diag(0.5 * (hi - lo))


def linearize(task: Task, jac: Callable, qref: np.ndarray, x: np.ndarray) -> Linearization:
    """The closed loop at tangent state x [2 nv] around qref; jac(obs) -> (action, d action / d obs)."""
    nv = task.model.nv
    qpos = to_qpos(task.model, qref, x[:nv])[0]
    obs = observe_at(task, qpos, x[nv:])
    action, K = jac(obs)
    G = controls_jacobian(task, len(action))
    u = task.controls(np.asarray(action, np.float64)[None])[0]
    A, B = step_jacobians(task, qpos, x[nv:], u)
    return Linearization(A, B, observation_jacobian(task, qref, x), G, K, np.asarray(action))


def closed_step(task: Task, jac: Callable, qref: np.ndarray, x: np.ndarray) -> np.ndarray:
    """[2 nv] the tangent state after one closed-loop control step from x (TaskC's step)."""
    nv = task.model.nv
    tc = TaskC(task)
    obs = tc.set_start(to_qpos(task.model, qref, x[:nv])[0], x[nv:])
    action, _ = jac(np.asarray(obs, np.float64))
    tc.step_controls(task.controls(np.asarray(action, np.float64)[None])[0])
    return np.concatenate([to_tangent(task.model, qref, tc.data.qpos)[0], tc.data.qvel])


class FixedPoint(NamedTuple):
    x: np.ndarray  # [2 nv] tangent state around the reference qpos
    residual: float  # |f(x) - x| in scaled coordinates
    converged: bool


def fixed_point(task: Task, jac: Callable, qref: np.ndarray, x0: np.ndarray, scale: np.ndarray, iters: int = 40,
                tol: float = 1e-8,
                max_step: float = 1.0) -> FixedPoint:
    """x with f(x) = x for the closed loop of jac, by Newton's method from x0 (least squares where J - I is
    singular, e.g. coordinates the controller does not move), each step at most max_step scale units per coordinate,
    halved while it does not reduce the residual."""
    x, r = np.asarray(x0, np.float64), closed_step(task, jac, qref, x0) - x0
    for _ in range(iters):
        if np.linalg.norm(r / scale) < tol:
            return FixedPoint(x, float(np.linalg.norm(r / scale)), True)
        J = linearize(task, jac, qref, x).closed - np.eye(len(x))
        dx = np.linalg.lstsq(J, -r, rcond=1e-10)[0]
        dx = dx / max(1.0, float(np.max(np.abs(dx / scale))) / max_step)
        for _ in range(20):
            xn = x + dx
            rn = closed_step(task, jac, qref, xn) - xn
            if np.linalg.norm(rn / scale) < np.linalg.norm(r / scale):
                break
            dx = dx / 2
        x, r = xn, rn
    res = float(np.linalg.norm(r / scale))
    return FixedPoint(x, res, res < tol)
