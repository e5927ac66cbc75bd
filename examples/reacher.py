"""A task of your own in one file: a two-link planar arm that reaches a target (docs/your_task.md).

    python -m gsa_jax.train --env examples.reacher:Reacher --physics c --clusters 2 --steps 300000
"""

import numpy as np

from envs.task import Task

MJCF = """
<mujoco model="two_link_reacher">
  <option timestep="0.01" gravity="0 0 0"/>
  <default>
    <joint type="hinge" axis="0 0 1" damping="0.01"/>
    <geom type="capsule" size="0.01" contype="0" conaffinity="0"/>
  </default>
  <worldbody>
    <body name="upper_arm" pos="0 0 0.01">
      <joint name="shoulder"/>
      <geom fromto="0 0 0 0.1 0 0"/>
      <body name="forearm" pos="0.1 0 0">
        <joint name="elbow"/>
        <geom fromto="0 0 0 0.1 0 0"/>
        <site name="fingertip" pos="0.11 0 0"/>
      </body>
    </body>
    <body name="target" pos="0 0 0.01">
      <joint name="target_x" type="slide" axis="1 0 0" damping="0"/>
      <joint name="target_y" type="slide" axis="0 1 0" damping="0"/>
      <geom type="sphere" size="0.01"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" gear="0.05" ctrlrange="-1 1"/>
    <motor joint="elbow" gear="0.05" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


class Reacher(Task):
    """Reward: minus the fingertip's distance to the target, minus 0.1 |a|^2, for 200 steps of 20 ms.
    Start: both joints at any angle, the target anywhere in a square of side 0.28 around the shoulder
    (always within reach: 0.21), the arm moving a little, the target still."""

    xml = MJCF
    frame_skip = 2
    episode_length = 200
    noise = np.array([np.pi, np.pi, 0.14, 0.14])  # qpos ~ qpos0 + U(-noise, noise)
    vel_noise = np.array([0.1, 0.1, 0.0, 0.0])  # qvel ~ U(-vel_noise, vel_noise)
    derived = ("site_xpos",)  # the fingertip's position, as mj_step leaves it

    def _to_target(self, qpos, derived):
        return derived["site_xpos"][:, 0, :2] - qpos[:, 2:4]

    def observe(self, qpos, qvel, derived, xp=np):
        arm = qpos[:, :2]
        return xp.concatenate([xp.cos(arm), xp.sin(arm), qpos[:, 2:4], qvel[:, :2], self._to_target(qpos, derived)], axis=1)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        distance = xp.sqrt(xp.sum(xp.square(self._to_target(qpos, derived)), axis=1))
        reward = -distance - 0.1 * xp.sum(xp.square(action), axis=1)
        return self.observe(qpos, qvel, derived, xp), reward, xp.zeros(qpos.shape[:1], bool)

    def observation_layout(self):
        return ["cos shoulder", "cos elbow", "sin shoulder", "sin elbow", "target x", "target y",
                "shoulder velocity", "elbow velocity", "fingertip - target x", "fingertip - target y"]
