"""dm_control's pendulum swingup (suite/pendulum.py): 1000 steps of 0.02 s; reward 1 while the pole is within
8 degrees of upright, else 0 (sparse). Observation: orientation [xmat zz, xz] (2), velocity (1)."""

import types

import numpy as np

from envs.dmc.base import XMAT, DmcTask, tolerance

COSINE_BOUND = np.cos(np.deg2rad(8))


class Swingup(DmcTask):
    """pendulum-swingup: the hinge uniform in [-pi, pi], at rest."""

    domain, time_limit = "pendulum", 20.0
    derived = ("xmat",)
    observation_keys = (("orientation", 2), ("velocity", 1))
    init_qpos, noise, vel_noise = (0.0,), np.pi, 0.0
    push_body = "pole"
    equilibrium_qpos = (0.0,)  # upright

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        pole = derived["xmat"][:, self.id("body", "pole")]
        return xp.concatenate([pole[:, XMAT["zz"], None], pole[:, XMAT["xz"], None], qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        return tolerance(derived["xmat"][:, self.id("body", "pole"), XMAT["zz"]], (COSINE_BOUND, 1), xp=xp)
