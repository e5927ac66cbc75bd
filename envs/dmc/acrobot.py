"""dm_control's acrobot swingup (suite/acrobot.py): 1000 steps of 0.01 s (RK4); reward: the tip's distance to the
target site, tolerance(bounds (0, target radius), margin 1). Observation: orientations [upper, lower arm xmat
xz, then zz] (4), velocity (2)."""

import types

import numpy as np

from envs.dmc.base import XMAT, DmcTask, tolerance


class Swingup(DmcTask):
    """acrobot-swingup: both hinges uniform in [-pi, pi], at rest."""

    domain, time_limit = "acrobot", 10.0
    derived = ("xmat", "site_xpos")
    observation_keys = (("orientations", 4), ("velocity", 2))
    init_qpos, noise, vel_noise = (0.0, 0.0), np.pi, 0.0
    push_body = "upper_arm"

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        arms = derived["xmat"][:, [self.id("body", "upper_arm"), self.id("body", "lower_arm")]]
        return xp.concatenate([arms[:, :, XMAT["xz"]], arms[:, :, XMAT["zz"]], qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        sites = derived["site_xpos"]
        to_target = xp.linalg.norm(sites[:, self.id("site", "target")] - sites[:, self.id("site", "tip")], axis=-1)
        radius = float(self.model.site_size[self.id("site", "target"), 0])
        return tolerance(to_target, bounds=(0, radius), margin=1, xp=xp)
