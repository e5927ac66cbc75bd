"""Tasks and controllers for tests/test_verify.py and tests/test_certify.py: a point mass on a damped slide, whose
dynamics are exactly linear, its LQR gain, and exported mixture controllers of it.

MuJoCo's Euler step with implicit damping (its default): (m + h d) v' = m v + h g u, x' = x + h v', so one physics
step is x_{k+1} = A_h x_k + B_h u with A_h = [[1, h m / (m + h d)], [0, m / (m + h d)]], B_h = [h^2 g, h g] / (m + h d).
"""

import json

import numpy as np
import scipy.linalg

from envs.task import Task
from gsa_jax.running.checkpoint import save_npz_atomic

MASS, DAMPING, GEAR, TIMESTEP = 1.0, 0.5, 10.0, 0.01
RAIL = 1.0  # m: RailPointMass's rail ends

MJCF = f"""
<mujoco model="point_mass_on_a_slide">
  <option timestep="{TIMESTEP}" gravity="0 0 0"/>
  <worldbody>
    <body name="mass">
      <joint name="x" type="slide" axis="1 0 0" damping="{DAMPING}"/>
      <inertial pos="0 0 0" mass="{MASS}" diaginertia="1 1 1"/>
      <geom type="sphere" size="0.05" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="x" gear="{GEAR}" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


class PointMass(Task):
    """Observation [x, v]; reward -(x^2 + 0.1 v^2 + 0.01 a^2); 300 steps of 20 ms; start x, v ~ U(-0.5, 0.5)."""

    xml = MJCF
    frame_skip = 2
    episode_length = 300
    noise = 0.5
    planar = True
    equilibrium_qpos = (0.0,)

    def observe(self, qpos, qvel, derived, xp=np):
        return xp.concatenate([qpos, qvel], axis=1)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        reward = -(qpos[:, 0] ** 2 + 0.1 * qvel[:, 0] ** 2 + 0.01 * action[:, 0] ** 2)
        return self.observe(qpos, qvel, derived, xp), reward, xp.zeros(qpos.shape[:1], bool)


class RailPointMass(PointMass):
    """PointMass on a rail that ends at x = +-RAIL m (a limited slide joint)."""

    xml = MJCF.replace('damping="{DAMPING}"/>'.format(DAMPING=DAMPING),
                       f'damping="{DAMPING}" limited="true" range="-{RAIL} {RAIL}"/>')


def analytic_step():
    """(A [2, 2], B [2, 1]) of one control step (frame_skip physics steps) of PointMass, from the formula above."""
    h, m, d, g = TIMESTEP, MASS, DAMPING, GEAR
    a_h = np.array([[1.0, h * m / (m + h * d)], [0.0, m / (m + h * d)]])
    b_h = np.array([[h * h * g], [h * g]]) / (m + h * d)
    A, B = np.eye(2), np.zeros((2, 1))
    for _ in range(PointMass.frame_skip):
        A, B = a_h @ A, a_h @ B + b_h
    return A, B


def lqr_gain():
    """[1, 2] the discrete LQR gain (Q = diag(10, 1), R = 1) of PointMass's analytic step: a = -K x."""
    A, B = analytic_step()
    P = scipy.linalg.solve_discrete_are(A, B, np.diag([10.0, 1.0]), np.eye(1))
    return np.linalg.solve(np.eye(1) + B.T @ P @ B, B.T @ P @ A)


def export(path, env, L, b, w=None, bw=None, obs_var=(1.0, 1.0), obs_mean=(0.0, 0.0), partition=None):
    """An exported mixture controller (as python -m gsa_jax.export writes one): pieces L [K, 1, 2], b [K, 1];
    partition layers w, bw (default: one linear layer, argmax 0) of class `partition` (None: stored as none, mlp)."""
    K = len(L)
    w = w or [np.zeros((2, K))]
    bw = bw or [np.zeros(K)]
    arrays = {"kind": np.array("mixture"), "subpolicy": np.array("linear"), "obs_mean": np.asarray(obs_mean, np.float32),
              "obs_var": np.asarray(obs_var, np.float32), "obs_clip": np.array(1e3, np.float32),
              "n_layers": np.array(len(w)), "L": np.asarray(L, np.float32), "b": np.asarray(b, np.float32),
              "action_low": -np.ones(1, np.float32), "action_high": np.ones(1, np.float32),
              "config_json": np.array(json.dumps({"config": {"env": env}}))}
    if partition is not None:
        arrays["partition"] = np.array(partition)
    for i, (wi, bi) in enumerate(zip(w, bw)):
        arrays[f"w{i}"], arrays[f"b{i}"] = np.asarray(wi, np.float32), np.asarray(bi, np.float32)
    save_npz_atomic(str(path), **arrays)
    return str(path)


def biased_pair(path, env, bias, partition="mlp"):
    """K = 2 on PointMass that holds by switching across x = 0: piece 0 (picked where x < 0) the LQR gain pushing right
    by `bias`, piece 1 (x > 0) pushing left by it. Each piece alone is stable with its fixed point (x = +-bias / gain)
    in the other's cell, so the closed loop chatters across the boundary. The partition: an MLP (logits 0 and
    tanh(50 x)) or a linear one (logits -x and x)."""
    k = lqr_gain()[None]
    if partition == "linear":
        w, bw = [np.array([[-1.0, 1.0], [0.0, 0.0]])], [np.zeros(2)]
    else:
        w, bw = [np.array([[50.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 1.0], [0.0, 0.0]])], [np.zeros(2), np.zeros(2)]
    return export(path, env, np.concatenate([-k, -k]), [[bias], [-bias]], w, bw, partition=partition)
