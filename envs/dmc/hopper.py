"""dm_control's hopper (suite/hopper.py): stand and hop; 1000 steps of 0.02 s (4 physics steps).

Observation: position qpos[1:] (6), velocity (7), touch log1p(toe, heel touch sensors) (2). Reward: standing
(torso above foot by 0.6-2, xipos z) times small control (stand) or the hop speed above 2 (hop)."""

import types

import numpy as np

from envs.dmc.base import DmcTask, joint_start_law, tolerance

STAND_HEIGHT, HOP_SPEED = 0.6, 2.0


class Hopper(DmcTask):
    """The hopper's joints uniform in their ranges and its pitch uniform in [-pi, pi], at rest."""

    domain, control_timestep, time_limit = "hopper", 0.02, 20.0
    derived = ("xipos", "sensordata")
    observation_keys = (("position", 6), ("velocity", 7), ("touch", 2))
    vel_noise = 0.0
    push_body, planar = "torso", True
    hopping = False

    def __init__(self):
        super().__init__()
        self.start_qpos, self.noise = joint_start_law(self.model)

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        s = derived["sensordata"]
        touch = xp.log1p(xp.concatenate([self.sensor(s, "touch_toe"), self.sensor(s, "touch_heel")], axis=1))
        return xp.concatenate([qpos[:, 1:], qvel, touch], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        xipos = derived["xipos"]
        height = xipos[:, self.id("body", "torso"), 2] - xipos[:, self.id("body", "foot"), 2]
        standing = tolerance(height, (STAND_HEIGHT, 2), xp=xp)
        if self.hopping:
            speed = self.sensor(derived["sensordata"], "torso_subtreelinvel")[:, 0]
            return standing * tolerance(speed, bounds=(HOP_SPEED, float("inf")), margin=HOP_SPEED / 2,
                                        value_at_margin=0.5, sigmoid="linear", xp=xp)
        small_control = xp.mean(tolerance(action, margin=1, value_at_margin=0, sigmoid="quadratic", xp=xp), axis=1)
        return standing * (small_control + 4) / 5


class Stand(Hopper):
    hopping = False


class Hop(Hopper):
    hopping = True
