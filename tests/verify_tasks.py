"""Tasks for tests/test_verify.py: a point mass on a damped slide, whose dynamics are exactly linear.

MuJoCo's Euler step with implicit damping (its default): (m + h d) v' = m v + h g u, x' = x + h v', so one physics
step is x_{k+1} = A_h x_k + B_h u with A_h = [[1, h m / (m + h d)], [0, m / (m + h d)]], B_h = [h^2 g, h g] / (m + h d).
"""

import numpy as np

from envs.task import Task

MASS, DAMPING, GEAR, TIMESTEP = 1.0, 0.5, 10.0, 0.01

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


def analytic_step():
    """(A [2, 2], B [2, 1]) of one control step (frame_skip physics steps) of PointMass, from the formula above."""
    h, m, d, g = TIMESTEP, MASS, DAMPING, GEAR
    a_h = np.array([[1.0, h * m / (m + h * d)], [0.0, m / (m + h * d)]])
    b_h = np.array([[h * h * g], [h * g]]) / (m + h * d)
    A, B = np.eye(2), np.zeros((2, 1))
    for _ in range(PointMass.frame_skip):
        A, B = a_h @ A, a_h @ B + b_h
    return A, B
