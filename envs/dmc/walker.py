"""dm_control's planar walker (suite/walker.py): stand, walk, run; 1000 steps of 0.025 s (10 physics steps).

Observation: orientations [xmat xx, xz of every body but the world] (14), height (torso z, 1), velocity (9).
Reward: standing (torso height >= 1.2, margin 0.6) and upright, times the move reward above a speed (walk 1,
run 8) from the torso's subtree linear velocity sensor."""

import types

import numpy as np

from envs.dmc.base import XMAT, DmcTask, joint_start_law, tolerance

STAND_HEIGHT = 1.2


class PlanarWalker(DmcTask):
    """The walker's joints uniform in their ranges and its pitch uniform in [-pi, pi], at rest."""

    domain, control_timestep, time_limit = "walker", 0.025, 25.0
    derived = ("xmat", "xpos", "sensordata")
    observation_keys = (("orientations", 14), ("height", 1), ("velocity", 9))
    vel_noise = 0.0
    push_body, planar = "torso", True
    move_speed = 0.0

    def __init__(self):
        super().__init__()
        self.start_qpos, self.noise = joint_start_law(self.model)

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        xmat = derived["xmat"][:, 1:]
        n = xmat.shape[0]
        orientations = xp.stack([xmat[:, :, XMAT["xx"]], xmat[:, :, XMAT["xz"]]], axis=2).reshape(n, -1)
        height = derived["xpos"][:, self.id("body", "torso"), 2:3]
        return xp.concatenate([orientations, height, qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        torso = self.id("body", "torso")
        standing = tolerance(derived["xpos"][:, torso, 2], bounds=(STAND_HEIGHT, float("inf")), margin=STAND_HEIGHT / 2,
                             xp=xp)
        upright = (1 + derived["xmat"][:, torso, XMAT["zz"]]) / 2
        stand_reward = (3 * standing + upright) / 4
        if self.move_speed == 0:
            return stand_reward
        speed = self.sensor(derived["sensordata"], "torso_subtreelinvel")[:, 0]
        move_reward = tolerance(speed, bounds=(self.move_speed, float("inf")), margin=self.move_speed / 2,
                                value_at_margin=0.5, sigmoid="linear", xp=xp)
        return stand_reward * (5 * move_reward + 1) / 6


class Stand(PlanarWalker):
    move_speed = 0.0


class Walk(PlanarWalker):
    move_speed = 1.0


class Run(PlanarWalker):
    move_speed = 8.0
