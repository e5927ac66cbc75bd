"""dm_control's quadruped (suite/quadruped.py): walk; 1000 steps of 0.02 s (4 physics steps of 0.005 s).

The model is dm_control's own, built in Python: quadruped.make_model(floor_size=10) (time limit x walk speed; no
terrain, rangefinders, walls, ball or target), loaded with dm_control's assets. Its 12 actuators are first-order
filters (act, na = 12) of affine position servos; their ctrlrange is dm_control's ([-1, 1] yaw, [-1, 1.1] lift,
[-0.8, 0.8] extend): an action in [-1, 1] is mapped onto it (ctrl_range 'model'), so the policy's clipped actions
span every control dm_control's action spec allows.

Start: a normalized N(0, I) orientation quaternion, the joints at qpos0, at rest, and the lowest height (from 0 in
1 cm steps) at which the quadruped touches nothing (dm_control's _find_non_contacting_height: per try mj_resetData,
a forward pass, the root's position (0, 0, z) and orientation, a forward pass, the number of contacts).

Observation: egocentric_state (hinge qpos 16, hinge qvel 16, act 12), torso_velocity (velocimeter, 3),
torso_upright (torso xmat zz, 1), imu (accelerometer and gyro, in sensor order, 6), force_torque (arcsinh of the
toes' force and torque sensors, in sensor order, 24). Reward: upright (linear from 1 at zz >= 1 to 0 at zz = -1)
times move (linear from 1 at a forward torso velocity >= 0.5 to 0.5 at 0)."""

import types

import mujoco
import numpy as np

from envs.task import TaskError
from envs.dmc.base import XMAT, DmcTask, suite_dir, tolerance

WALK_SPEED, TIME_LIMIT = 0.5, 20.0
MAX_ATTEMPTS = 10000


class Quadruped(DmcTask):
    domain, control_timestep, time_limit = "quadruped", 0.02, TIME_LIMIT
    derived = ("xmat", "sensordata", "act")
    observation_keys = (("egocentric_state", 44), ("torso_velocity", 3), ("torso_upright", 1), ("imu", 6),
                        ("force_torque", 24))
    push_body = "torso"
    ctrl_range = "model"  # actions in [-1, 1] onto dm_control's ctrlranges (lift [-1, 1.1], extend [-0.8, 0.8])
    desired_speed = WALK_SPEED
    floor_size = TIME_LIMIT * WALK_SPEED

    def __init__(self):
        super().__init__()
        m = self.model
        hinges = np.flatnonzero(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
        self.hinge_qpos, self.hinge_qvel = m.jnt_qposadr[hinges].copy(), m.jnt_dofadr[hinges].copy()
        self.root = int(m.jnt_qposadr[self.id("joint", "root")])

        def columns(*types):  # sensordata columns of the sensors of these types, in sensor order (dm_control's)
            ids = np.flatnonzero(np.isin(m.sensor_type, types))
            return np.concatenate([np.arange(m.sensor_adr[s], m.sensor_adr[s] + m.sensor_dim[s]) for s in ids])

        self.imu_columns = columns(mujoco.mjtSensor.mjSENS_GYRO, mujoco.mjtSensor.mjSENS_ACCELEROMETER)
        self.force_torque_columns = columns(mujoco.mjtSensor.mjSENS_FORCE, mujoco.mjtSensor.mjSENS_TORQUE)

    def load_model(self) -> mujoco.MjModel:
        where = f"task {self.name or type(self).__name__!r}"
        try:
            from dm_control.suite import common, quadruped  # dm_control: an optional extra (envs/dmc/)
        except ImportError:
            suite_dir(where)  # TaskError in one line without dm_control
            raise
        xml = quadruped.make_model(floor_size=self.floor_size, terrain=False, rangefinders=False, walls_and_ball=False)
        return mujoco.MjModel.from_xml_string(xml.decode() if isinstance(xml, bytes) else xml, assets=common.ASSETS)

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        orientation = rng.standard_normal(4)
        orientation /= np.linalg.norm(orientation)
        self.find_non_contacting_height(data, orientation)
        return None

    def find_non_contacting_height(self, data: mujoco.MjData, orientation: np.ndarray, x_pos: float = 0.0,
                                   y_pos: float = 0.0) -> None:
        """dm_control's _find_non_contacting_height: up from z = 0 in 1 cm steps until the forward pass finds no
        contact, each try from mj_resetData as its physics.reset_context() does."""
        m, root = self.model, self.root
        z_pos, num_contacts, num_attempts = 0.0, 1, 0
        while num_contacts > 0:
            mujoco.mj_resetData(m, data)
            mujoco.mj_forward(m, data)
            data.qpos[root: root + 3] = x_pos, y_pos, z_pos
            data.qpos[root + 3: root + 7] = orientation
            mujoco.mj_forward(m, data)
            num_contacts = data.ncon
            z_pos += 0.01
            num_attempts += 1
            if num_attempts > MAX_ATTEMPTS:
                raise TaskError("Failed to find a non-contacting configuration.")

    def upright(self, derived: dict) -> np.ndarray:
        return derived["xmat"][:, self.id("body", "torso"), XMAT["zz"]]

    def torso_velocity(self, derived: dict) -> np.ndarray:
        return self.sensor(derived["sensordata"], "velocimeter")

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        s = derived["sensordata"]
        return xp.concatenate([qpos[:, self.hinge_qpos], qvel[:, self.hinge_qvel], derived["act"],
                               self.torso_velocity(derived), self.upright(derived)[:, None], s[:, self.imu_columns],
                               xp.arcsinh(s[:, self.force_torque_columns])], axis=1)

    def upright_reward(self, derived: dict, xp: types.ModuleType, deviation_angle: float = 0) -> np.ndarray:
        deviation = np.cos(np.deg2rad(deviation_angle))
        return tolerance(self.upright(derived), bounds=(deviation, float("inf")), sigmoid="linear",
                         margin=1 + deviation, value_at_margin=0, xp=xp)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        move = tolerance(self.torso_velocity(derived)[:, 0], bounds=(self.desired_speed, float("inf")),
                         margin=self.desired_speed, value_at_margin=0.5, sigmoid="linear", xp=xp)
        return self.upright_reward(derived, xp) * move


class Walk(Quadruped):
    desired_speed = WALK_SPEED
