"""dm_control's finger spin (suite/finger.py): 1000 steps of 0.02 s (2 physics steps of 0.01 s), no gravity.

Observation (all from sensors): position [proximal, distal joint angles, tip x - spinner x, tip z - spinner z] (4),
velocity [proximal, distal, hinge joint velocities] (3), touch log1p(touchtop, touchbottom touch sensors) (2, from
the last physics substep as dm_control's legacy step leaves them). Reward: 1 while the spinner's hinge velocity
sensor reads <= -15 rad/s, else 0.

dm_control's Spin.initialize_episode sets the hinge's damping to 0.03 (the MJCF says 0.5) before every episode; the
model never changes afterwards, so here load_model() sets it once. (Its site_rgba changes are cosmetic: skipped.)
dist_to_target and target_position belong to finger-turn's observation, not to spin's."""

import types

import mujoco
import numpy as np

from envs.dmc.base import DmcTask, randomize_joints
from envs.task import TaskError

SPIN_VELOCITY = 15.0
HINGE_DAMPING = 0.03  # Spin.initialize_episode: physics.named.model.dof_damping['hinge'] = .03
MAX_ATTEMPTS = 1000  # _set_random_joint_angles


class Spin(DmcTask):
    """finger-spin: the finger's limited joints uniform in their ranges and the spinner's hinge uniform in
    [-pi, pi], at rest, redrawn until nothing touches (dm_control's _set_random_joint_angles: a forward pass after
    each draw, at most 1000 draws)."""

    domain, control_timestep, time_limit = "finger", 0.02, 20.0
    derived = ("sensordata",)
    observation_keys = (("position", 4), ("velocity", 3), ("touch", 2))
    push_body, planar = "proximal", True

    def load_model(self) -> mujoco.MjModel:
        model = super().load_model()
        hinge = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "hinge")
        model.dof_damping[model.jnt_dofadr[hinge]] = HINGE_DAMPING
        return model

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        for _ in range(MAX_ATTEMPTS):
            randomize_joints(self.model, data, rng)
            mujoco.mj_forward(self.model, data)  # physics.after_reset() (actuation off: ctrl is 0 here anyway)
            if data.ncon == 0:
                return None
        raise TaskError(f"finger-spin: could not find a collision-free state after {MAX_ATTEMPTS} attempts")

    def relative_xz(self, s: np.ndarray, name: str) -> np.ndarray:
        """[n, 2] the x, z of a framepos sensor relative to the spinner's."""
        return self.sensor(s, name)[:, 0::2] - self.sensor(s, "spinner")[:, 0::2]

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        s = derived["sensordata"]
        position = [self.sensor(s, "proximal"), self.sensor(s, "distal"), self.relative_xz(s, "tip")]
        velocity = [self.sensor(s, f"{j}_velocity") for j in ("proximal", "distal", "hinge")]
        touch = [xp.log1p(self.sensor(s, "touchtop")), xp.log1p(self.sensor(s, "touchbottom"))]
        return xp.concatenate(position + velocity + touch, axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        hinge_velocity = self.sensor(derived["sensordata"], "hinge_velocity")[:, 0]
        return xp.where(hinge_velocity <= -SPIN_VELOCITY, 1.0, 0.0)
