"""dm_control's point_mass easy (suite/point_mass.py): 1000 steps of 0.02 s; reward: near the target
(tolerance(distance, (0, target size), margin target size)) x small control. Observation: position (2),
velocity (2)."""

import types

import numpy as np

from envs.dmc.base import DmcTask, joint_start_law, tolerance


class Easy(DmcTask):
    """point_mass-easy: the mass uniform in its joints' ranges, at rest (the gains not randomized)."""

    domain, time_limit = "point_mass", 20.0
    derived = ("geom_xpos",)
    observation_keys = (("position", 2), ("velocity", 2))
    vel_noise = 0.0
    push_body = "pointmass"

    def __init__(self):
        super().__init__()
        self.start_qpos, self.noise = joint_start_law(self.model)

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        return xp.concatenate([qpos, qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        geoms = derived["geom_xpos"]
        dist = xp.linalg.norm(geoms[:, self.id("geom", "target")] - geoms[:, self.id("geom", "pointmass")], axis=-1)
        size = float(self.model.geom_size[self.id("geom", "target"), 0])
        near_target = tolerance(dist, bounds=(0, size), margin=size, xp=xp)
        control = xp.mean(tolerance(action, margin=1, value_at_margin=0, sigmoid="quadratic", xp=xp), axis=1)
        return near_target * (control + 4) / 5
