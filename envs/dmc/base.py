"""What every DeepMind Control Suite task here shares: dm_control's MJCF read from the installed package, its
control timestep and time limit, its legacy step's derived fields (mj_step1 after the step), `rewards.tolerance`
for NumPy and jax.numpy, and the start-state law of dm_control's `randomize_limited_and_rotational_joints`.

dm_control (1.0.50) is the reference and the source of the models: an optional extra (`pip install
'dm_control==1.0.50'`, installed by `make test`); a task that needs it and does not find it says so in one line.
Its `suite.load` itself needs mujoco 3.17 (it fails under mujoco 4.0), so the step-for-step reference runs in its
own environment (experiments/dmc_reference/record.py); the MJCFs load in mujoco 4.0 as they are.
"""

import importlib.util
import math
import os
import types
from typing import Sequence

import mujoco
import numpy as np

from envs.task import Task, TaskError, seed_words

DM_CONTROL_VERSION = "1.0.50"
INSTALL = f"pip install 'dm_control=={DM_CONTROL_VERSION}' (or: pip install -e '.[dmc]'; make test installs it)"


def suite_dir(where: str = "a dmc task") -> str:
    """The installed dm_control's suite/ folder (its MJCFs); TaskError in one line without dm_control."""
    spec = importlib.util.find_spec("dm_control")
    if spec is None or not spec.submodule_search_locations:
        raise TaskError(f"{where} needs dm_control, which is not installed: {INSTALL}")
    return os.path.join(list(spec.submodule_search_locations)[0], "suite")


def _sigmoid(x, value_at_1, sigmoid, xp):
    """dm_control's rewards._sigmoids: 1 at x = 0, value_at_1 at x = 1, in the same floating-point operations."""
    if sigmoid == "gaussian":
        scale = np.sqrt(-2 * np.log(value_at_1))
        return xp.exp(-0.5 * (x * scale) ** 2)
    if sigmoid == "hyperbolic":
        return 1 / xp.cosh(x * np.arccosh(1 / value_at_1))
    if sigmoid == "long_tail":
        return 1 / ((x * np.sqrt(1 / value_at_1 - 1)) ** 2 + 1)
    if sigmoid == "reciprocal":
        return 1 / (xp.abs(x) * (1 / value_at_1 - 1) + 1)
    if sigmoid == "cosine":
        scaled = x * (np.arccos(2 * value_at_1 - 1) / np.pi)
        return xp.where(xp.abs(scaled) < 1, (1 + xp.cos(np.pi * scaled)) / 2, 0.0)
    if sigmoid == "linear":
        scaled = x * (1 - value_at_1)
        return xp.where(xp.abs(scaled) < 1, 1 - scaled, 0.0)
    if sigmoid == "quadratic":
        scaled = x * np.sqrt(1 - value_at_1)
        return xp.where(xp.abs(scaled) < 1, 1 - scaled ** 2, 0.0)
    if sigmoid == "tanh_squared":
        return 1 - xp.tanh(x * np.arctanh(np.sqrt(1 - value_at_1))) ** 2
    raise ValueError(f"unknown sigmoid {sigmoid!r}")


def tolerance(x: np.ndarray, bounds: tuple = (0.0, 0.0), margin: float = 0.0, sigmoid: str = "gaussian",
              value_at_margin: float = 0.1, xp: types.ModuleType = np) -> np.ndarray:
    """dm_control's rewards.tolerance over arrays for NumPy and jax.numpy: 1 inside [lower, upper], falling off
    with the distance to the nearest bound over `margin` (0 outside the bounds when margin is 0)."""
    lower, upper = bounds
    in_bounds = xp.logical_and(lower <= x, x <= upper)
    if margin == 0:
        return xp.where(in_bounds, 1.0, 0.0)
    d = xp.where(x < lower, lower - x, x - upper) / margin
    return xp.where(in_bounds, 1.0, _sigmoid(d, value_at_margin, sigmoid, xp))


def joint_start_law(model: mujoco.MjModel) -> tuple:
    """(center [nq], half-width [nq]) of dm_control's randomize_limited_and_rotational_joints as a uniform law: a
    limited hinge or slide uniform in its range, an unlimited hinge uniform in [-pi, pi], other coordinates at
    qpos0. TaskError for ball and free joints (their quaternions are not a per-coordinate uniform law)."""
    center, half = model.qpos0.copy(), np.zeros(model.nq)
    for j in range(model.njnt):
        kind, adr = int(model.jnt_type[j]), model.jnt_qposadr[j]  # an int: mjtJoint == numpy.int32 is False
        if kind in (mujoco.mjtJoint.mjJNT_BALL, mujoco.mjtJoint.mjJNT_FREE):
            raise TaskError(f"joint {model.joint(j).name!r}: random quaternions are not a per-coordinate law")
        lo, hi = model.jnt_range[j]
        if model.jnt_limited[j]:
            center[adr], half[adr] = (lo + hi) / 2, (hi - lo) / 2
        elif kind == mujoco.mjtJoint.mjJNT_HINGE:
            center[adr], half[adr] = 0.0, np.pi
    return center, half


def randomize_joints(model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
    """dm_control's randomizers.randomize_limited_and_rotational_joints on `data` with a numpy Generator: limited hinges
    and slides uniform in their ranges, unlimited hinges uniform in [-pi, pi], unlimited ball joints a normalized
    N(0, I) quaternion, free joints' orientation a normalized U[0, 1)^4 quaternion (dm_control's own choice);
    positions of free joints untouched."""
    for j in range(model.njnt):
        kind, adr = int(model.jnt_type[j]), model.jnt_qposadr[j]  # an int: mjtJoint == numpy.int32 is False
        lo, hi = model.jnt_range[j]
        if model.jnt_limited[j]:
            if kind in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
                data.qpos[adr] = rng.uniform(lo, hi)
            elif kind == mujoco.mjtJoint.mjJNT_BALL:
                raise TaskError(f"joint {model.joint(j).name!r}: limited ball joints are not supported")
        elif kind == mujoco.mjtJoint.mjJNT_HINGE:
            data.qpos[adr] = rng.uniform(-np.pi, np.pi)
        elif kind == mujoco.mjtJoint.mjJNT_BALL:
            quat = rng.standard_normal(4)
            data.qpos[adr: adr + 4] = quat / np.linalg.norm(quat)
        elif kind == mujoco.mjtJoint.mjJNT_FREE:
            quat = rng.random(4)
            data.qpos[adr + 3: adr + 7] = quat / np.linalg.norm(quat)


def legacy_step(model: mujoco.MjModel, data: mujoco.MjData, nstep: int = 1) -> None:
    """dm_control's Physics.step (legacy_step): mj_step2 on the stages already computed, nstep - 1 mj_steps, then
    mj_step1 (RK4: nstep mj_steps, then mj_step1). From a state set after the last forward pass, the first
    substep uses that pass's position stage, as dm_control's settling steps at reset do."""
    if model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4:
        mujoco.mj_step2(model, data)
        if nstep > 1:
            mujoco.mj_step(model, data, nstep - 1)
    else:
        mujoco.mj_step(model, data, nstep)
    mujoco.mj_step1(model, data)


def forward_without_actuation(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """mj_forward with the actuation flag disabled, as dm_control's Physics.reset and after_reset run it."""
    flag = int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    saved = model.opt.disableflags
    model.opt.disableflags = saved | flag
    try:
        mujoco.mj_forward(model, data)
    finally:
        model.opt.disableflags = saved


def sub_steps(control_timestep: float, timestep: float) -> int:
    """dm_control's control.compute_n_steps: physics steps per control step (ValueError unless a whole number)."""
    n = control_timestep / timestep
    if abs(n - round(n)) > 1e-8:
        raise ValueError(f"control timestep {control_timestep} is not a multiple of the physics timestep {timestep}")
    return int(round(n))


XMAT = {"xx": 0, "xy": 1, "xz": 2, "yx": 3, "yy": 4, "yz": 5, "zx": 6, "zy": 7, "zz": 8}  # dm_control's xmat columns


class DmcTask(Task):
    """A dm_control suite task: `domain` names its MJCF (suite/<domain>.xml), `control_timestep` (seconds, None: one
    physics step) and `time_limit` (seconds) its env step and episode, as its suite module sets them. Episodes end
    at the time limit only (dm_control's tasks here have no termination); derived fields are read as dm_control's
    legacy step leaves them (derived_after 'step1'). Observations are dm_control's observation dict flattened in
    its own key order (observation_keys says which entries)."""

    domain = ""
    control_timestep = None
    time_limit = 20.0
    derived_after = "step1"
    observation_keys: tuple = ()  # (name, size) of each entry of dm_control's observation dict, in its order

    def __init__(self):
        super().__init__()
        timestep = self.model.opt.timestep
        self.frame_skip = 1 if self.control_timestep is None else sub_steps(self.control_timestep, timestep)
        self.dt = timestep * self.frame_skip
        self.episode_length = int(math.ceil(self.time_limit / self.dt - 1e-9))  # control.Environment's step limit
        self.max_return = float(self.episode_length)  # every suite reward is in [0, 1] a step

    def load_model(self) -> mujoco.MjModel:
        path = os.path.join(suite_dir(f"task {self.name or type(self).__name__!r}"), f"{self.domain}.xml")
        return mujoco.MjModel.from_xml_path(path)

    def start(self, data: mujoco.MjData, seed: "int | Sequence[int] | np.ndarray") -> np.ndarray:
        """As dm_control's reset: mj_resetData and a forward pass (Physics.reset), initialize(), a forward pass (both
        with actuation disabled, as dm_control's)."""
        mujoco.mj_resetData(self.model, data)
        forward_without_actuation(self.model, data)
        goal = self.initialize(data, np.random.default_rng(seed_words(seed)))
        forward_without_actuation(self.model, data)  # Physics.after_reset
        return np.zeros(0) if goal is None else np.asarray(goal, np.float64).reshape(self.goal_size)

    def id(self, kind: str, name: str) -> int:
        """The index of a named body / joint / site / geom / sensor (kind: 'body', 'joint', ...)."""
        return mujoco.mj_name2id(self.model, getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}"), name)

    def sensor(self, sensordata: np.ndarray, name: str) -> np.ndarray:
        """[n, dim] the named sensor's values of sensordata [n, nsensordata]."""
        s = self.model.sensor(name)
        return sensordata[:, s.adr[0]: s.adr[0] + s.dim[0]]

    def outcome(self, before: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
                xp: types.ModuleType = np) -> tuple:
        obs = self.observe(qpos, qvel, derived, xp)
        return obs, self.reward(qpos, qvel, derived, action, xp), xp.zeros(qpos.shape[:1], bool)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        """[n] dm_control's get_reward after a step (action: the control as set, physics.control())."""
        raise NotImplementedError

    def observation_layout(self) -> list[str]:
        names = [f"{key}[{i}]" if size > 1 else key for key, size in self.observation_keys for i in range(size)]
        return names if len(names) == self.observation_size else super().observation_layout()
