"""dm_control's ball in cup catch (suite/ball_in_cup.py): 1000 steps of 0.02 s (10 physics steps of 0.002 s).

Observation: position qpos [cup x, cup z, ball x, ball z] (4), velocity qvel (4). Reward: 1 while the ball's
centre (xpos) lies within the cup's 'target' box site shrunk by the ball's radius in x and z (|target - ball| <
target half-size - ball radius, both coordinates), else 0."""

import types

import mujoco
import numpy as np

from envs.dmc.base import DmcTask


class Catch(DmcTask):
    """ball_in_cup-catch: the cup at rest at its origin, the ball at rest with ball_x ~ U(-0.2, 0.2) and
    ball_z ~ U(0.2, 0.5) (its slides' coordinates), redrawn (x then z) until nothing touches, a forward pass after
    each draw (dm_control's loop: unbounded)."""

    domain, control_timestep, time_limit = "ball_in_cup", 0.02, 20.0
    derived = ("site_xpos", "xpos")
    observation_keys = (("position", 4), ("velocity", 4))
    push_body, planar = "cup", True

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        x, z = (self.model.jnt_qposadr[self.id("joint", name)] for name in ("ball_x", "ball_z"))
        while True:
            data.qpos[x] = rng.uniform(-0.2, 0.2)
            data.qpos[z] = rng.uniform(0.2, 0.5)
            mujoco.mj_forward(self.model, data)  # physics.after_reset() (actuation off: ctrl is 0 here anyway)
            if data.ncon == 0:
                return None

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        return xp.concatenate([qpos, qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        target = derived["site_xpos"][:, self.id("site", "target")][:, 0::2]
        ball = derived["xpos"][:, self.id("body", "ball")][:, 0::2]
        room = self.model.site_size[self.id("site", "target")][0::2] - self.model.geom_size[self.id("geom", "ball"), 0]
        return xp.where(xp.all(xp.abs(target - ball) < room, axis=1), 1.0, 0.0)
