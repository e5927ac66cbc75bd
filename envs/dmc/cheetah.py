"""dm_control's cheetah run (suite/cheetah.py): 1000 steps of 0.01 s; reward: the torso's subtree linear velocity
(forward), tolerance(bounds (10, inf), margin 10, linear, 0 at the margin). Observation: position qpos[1:] (8),
velocity (9)."""

import types

import mujoco
import numpy as np

from envs.dmc.base import DmcTask, legacy_step, tolerance

RUN_SPEED = 10.0


class Run(DmcTask):
    """cheetah-run: the limited joints uniform in their ranges, then 200 physics steps at zero control to settle
    (dm_control's legacy steps: the first on the pre-randomization forward pass), the clock reset."""

    domain, time_limit = "cheetah", 10.0
    derived = ("sensordata",)
    observation_keys = (("position", 8), ("velocity", 9))
    push_body, planar = "torso", True

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        m = self.model
        limited = m.jnt_limited == 1
        lower, upper = m.jnt_range[limited].T
        data.qpos[limited] = rng.uniform(lower, upper)
        legacy_step(m, data, 200)
        data.time = 0.0

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        return xp.concatenate([qpos[:, 1:], qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        speed = self.sensor(derived["sensordata"], "torso_subtreelinvel")[:, 0]
        return tolerance(speed, bounds=(RUN_SPEED, float("inf")), margin=RUN_SPEED, value_at_margin=0, sigmoid="linear",
                         xp=xp)
