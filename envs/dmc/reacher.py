"""dm_control's reacher (suite/reacher.py): easy (target radius 0.05) and hard (0.015); 1000 steps of 0.02 s.

The target is drawn at reset (angle U(0, 2 pi), radius U(0.05, 0.20)) and dm_control writes it into the model
(geom_pos); here it is the task's goal [x, y] (the target geom is the world's, so its position is exactly that),
carried in the state. Observation: position (2), to_target (goal - finger xy, 2), velocity (2). Reward: 1 while the
finger touches the target (distance <= target + finger radii), else 0."""

import types

import mujoco
import numpy as np

from envs.dmc.base import DmcTask, randomize_joints, tolerance


class Reacher(DmcTask):
    domain, time_limit = "reacher", 20.0
    derived = ("geom_xpos",)
    observation_keys = (("position", 2), ("to_target", 2), ("velocity", 2))
    goal_size = 2
    push_body = "arm"
    target_size = 0.05

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        randomize_joints(self.model, data, rng)
        angle, radius = rng.uniform(0, 2 * np.pi), rng.uniform(0.05, 0.20)
        return np.array([radius * np.sin(angle), radius * np.cos(angle)])

    def to_target(self, derived: dict) -> np.ndarray:
        return derived["goal"] - derived["geom_xpos"][:, self.id("geom", "finger"), :2]

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        return xp.concatenate([qpos, self.to_target(derived), qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        radii = self.target_size + float(self.model.geom_size[self.id("geom", "finger"), 0])
        return tolerance(xp.linalg.norm(self.to_target(derived), axis=-1), (0, radii), xp=xp)


class Easy(Reacher):
    target_size = 0.05


class Hard(Reacher):
    target_size = 0.015
