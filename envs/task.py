"""The task definition: what a user writes to define a MuJoCo task for gsa_jax, in one file.

    import numpy as np
    from envs.task import Task

    class Reach(Task):
        xml = "<mujoco>...</mujoco>"          # an MJCF: a path, an XML string, or a mujoco.MjSpec
        frame_skip, episode_length = 2, 200   # physics steps per env step; time limit (a truncation)
        noise = 0.1                           # start: qpos ~ init_qpos + U(-noise, noise) (a scalar or [nq])
        derived = ("site_xpos",)              # MjData fields observe/outcome read (as mj_step leaves them)

        def observe(self, qpos, qvel, derived, xp=np):            # [n, nq], [n, nv], {field: [n, ...]} -> [n, d]
            return xp.concatenate([qpos, qvel], axis=1)

        def outcome(self, before, qpos, qvel, derived, action, xp=np):   # after a step -> (obs, reward, terminated)
            reward = -xp.sum(xp.square(action), axis=1)
            return self.observe(qpos, qvel, derived, xp), reward, xp.zeros(qpos.shape[:1], bool)

    python -m gsa_jax.train --env my_module:Reach --physics c     # or envs.register("reach", Reach)

dm_control's tasks (envs/dmc/) read their derived fields as its legacy step leaves them: `derived_after = "step1"`
runs mj_step1 after the step, so position- and velocity-dependent fields (xpos, xmat, their sensors) are the new
state's, while acceleration-dependent ones (touch, accelerometer, force sensors) stay the last substep's; the
state itself is the same either way.

Observation, reward and termination are written once over batches (a leading axis of simulations) for NumPy and
jax.numpy (`xp`): backend 'c' (envs/c_backend.py) evaluates them in float64 on MuJoCo C's arrays inside the
compiled trainer, MJX (envs/task_mjx.py) with jax.numpy on MJX's data, and TaskC here (plain MuJoCo C, no JAX)
steps one MjData for deployment, evaluation and robustness. gymnasium's v5 tasks (envs/v5_tasks.py) are
instances. A step: `before` reads what the reward needs from the state before it, ctrl = controls(action) (the action,
already clipped to [-1, 1], or with ctrl_range 'model' its map onto the actuators' ctrlrange), mj_step frame_skip times (and mj_rnePostConstraint if post_constraint), then
`outcome`. envs/task_checks.py checks a definition in one line before anything compiles.

The task registry (envs/registry.py, envs/families/task_definition.py) builds every task definition from this module;
a task's name gives its plain MuJoCo C twin as envs.resolve(name).make_c().
"""

import hashlib
import inspect
import os
import types
from typing import Sequence

import mujoco
import numpy as np

from envs.errors import UserError


class TaskError(UserError, ValueError):
    """A task name or definition that cannot be used (one line)."""


def load_model(xml: "str | os.PathLike | mujoco.MjSpec", where: str = "the task") -> mujoco.MjModel:
    """An MjModel from an MJCF path, an XML string or a mujoco.MjSpec; TaskError (one line) if it does not load."""
    try:
        if isinstance(xml, mujoco.MjSpec):
            return xml.compile()
        if isinstance(xml, str) and xml.lstrip().startswith("<"):
            return mujoco.MjModel.from_xml_string(xml)
        if isinstance(xml, (str, os.PathLike)):
            if not os.path.exists(xml):
                raise TaskError(f"{where}: MJCF file {os.fspath(xml)!r} does not exist")
            return mujoco.MjModel.from_xml_path(os.fspath(xml))
    except (ValueError, TypeError) as e:
        if isinstance(e, TaskError):
            raise
        raise TaskError(f"{where}: the MJCF does not load: {' '.join(str(e).split())}") from None
    raise TaskError(f"{where}: xml must be an MJCF path, an XML string or a mujoco.MjSpec, got {type(xml).__name__}")


class Task:
    """A MuJoCo task: its model, control frame skip, episode length, start-state law, and its observation,
    reward and termination over batches for NumPy and jax.numpy (subclass it; see the module docstring).

    Start state: qpos ~ init_qpos + U(-noise, noise) (qpos_noise 'uniform') or init_qpos + noise * N(0, 1)
    ('normal'); qvel ~ U(-vel_noise, vel_noise) (qvel_noise 'uniform') or vel_noise * N(0, 1) ('normal'); noise
    and vel_noise are scalars or per-coordinate arrays [nq] / [nv] (vel_noise None: noise). init_qpos None: the
    model's qpos0."""

    name: str = ""  # set by the registry: the name the task was asked for
    xml: "str | os.PathLike | mujoco.MjSpec | None" = None
    frame_skip: int = 1
    episode_length: int = 1000
    init_qpos: "np.ndarray | None" = None
    noise: "float | np.ndarray" = 0.0
    vel_noise: "float | np.ndarray | None" = None
    qpos_noise: str = "uniform"
    qvel_noise: str = "uniform"
    derived: tuple = ()  # MjData fields read after a call, as mj_step leaves them (one substep behind the state)
    # "step": derived fields as mj_step leaves them (gymnasium); "step1": mj_step1 after the step (dm_control)
    derived_after: str = "step"
    goal_size: int = 0  # values initialize() returns, read back by observe/outcome as derived["goal"] [n, goal_size]
    # "unit": every actuator's ctrlrange is [-1, 1] and ctrl = action; "model": action a in [-1, 1] is mapped onto
    # the MJCF's ctrlrange, ctrl = lo + (a + 1) (hi - lo) / 2 (controls())
    ctrl_range: str = "unit"
    post_constraint: bool = False  # whether a derived field needs mj_rnePostConstraint after the step
    # robustness pushes (gsa_jax.robustness): the body they act on (a name, or an index: 1 is the first body below
    # the world, a locomotion robot's torso) and whether the robot moves in the x-z plane (pushes along +-x)
    push_body: "int | str" = 1
    planar: bool = False
    # the domain randomization this task is trained under with --randomize task (envs/randomization.py's text or a
    # {name: value} table; '': none declared)
    randomize: "str | dict" = ""
    # the qpos of the state the task asks the controller to hold (an inverted pendulum's upright, at rest), where it
    # has one: python -m gsa_jax.verify analyses the closed loop there (None: no equilibrium, falsification only)
    equilibrium_qpos: "np.ndarray | None" = None
    # how close to its hold a state must come for verify to count it as converged, in the task's units per tangent
    # coordinate [2 nv] (positions, then velocities) or one number for all; None: 0.1 x the start law's spread
    # (gsa_jax.verify.roa.convergence_tolerance)
    convergence_tolerance: "float | np.ndarray | None" = None
    # the most an episode can return where rewards are bounded (dm_control's tasks: at most 1 a step), None where they
    # are not (gymnasium's locomotion): gsa_jax.answer gives no answer where flat PPO does not learn a tenth of it
    max_return: "float | None" = None

    def __init__(self):
        for field in ("noise", "vel_noise", "init_qpos"):  # lists as arrays (scalars stay scalars)
            if isinstance(getattr(self, field), (list, tuple)):
                setattr(self, field, np.asarray(getattr(self, field), np.float64))
        self.model = self.load_model()
        self.dt = self.model.opt.timestep * self.frame_skip
        self.start_qpos = np.array(self.model.qpos0 if self.init_qpos is None else self.init_qpos, np.float64)

    def load_model(self) -> mujoco.MjModel:
        """The task's MjModel (default: from `xml`). Override to build it otherwise."""
        return load_model(self.xml, type(self).__name__)

    @property
    def vel_scale(self) -> "float | np.ndarray":
        """The qvel start-noise scale (vel_noise, or noise when None)."""
        return self.noise if self.vel_noise is None else self.vel_noise

    @property
    def observation_size(self) -> int:
        zeros = {f: np.zeros((1,) + getattr(mujoco.MjData(self.model), f).shape) for f in self.derived}
        zeros.update({"goal": np.zeros((1, self.goal_size))} if self.goal_size else {})
        return self.observe(self.start_qpos[None], np.zeros((1, self.model.nv)), zeros).shape[-1]

    def controls(self, action: np.ndarray, xp: types.ModuleType = np) -> np.ndarray:
        """[n, nu] the controls of actions [n, nu] in [-1, 1] (ctrl_range); outcome() receives these as `action`."""
        if self.ctrl_range == "unit":
            return action
        lo, hi = self.model.actuator_ctrlrange.T
        return lo + (action + 1.0) * (0.5 * (hi - lo))

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        """The start law as code, for what the noise fields cannot say (dm_control's initialize_episode): set the state
        of `data` (an MjData just after mj_resetData) with draws from `rng` (a numpy Generator); it may step `data`
        (a settling phase) and redraw (rejection). Returns the goal [goal_size] (a target drawn at reset), or None
        when goal_size is 0. mj_forward follows. Backend 'c' and TaskC run it on the host, MJX through a host
        callback. It must not change the model (one model serves every env; MJX never sees such a change): draw what
        differs per episode as the goal. Not overridden: the noise law above, drawn in the program."""
        raise NotImplementedError

    @property
    def has_initialize(self) -> bool:
        """Whether the task's start law is initialize() (rather than the noise fields)."""
        return type(self).initialize is not Task.initialize

    def start(self, data: mujoco.MjData, seed: "int | Sequence[int] | np.ndarray") -> np.ndarray:
        """initialize() on `data` from mj_resetData with a Generator seeded by `seed` (an int or a sequence of ints),
        then mj_forward -> goal [goal_size]."""
        mujoco.mj_resetData(self.model, data)
        goal = self.initialize(data, np.random.default_rng(seed_words(seed)))
        mujoco.mj_forward(self.model, data)
        return np.zeros(0) if goal is None else np.asarray(goal, np.float64).reshape(self.goal_size)

    def before(self, qpos: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        """[n, k] what the reward needs from before a step (default: nothing, k = 0)."""
        return qpos[:, :0] + 0.0

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        """[n, d] observation of n simulations: qpos [n, nq], qvel [n, nv], derived {field: [n, ...]}."""
        raise NotImplementedError(f"{type(self).__name__} defines no observe()")

    def outcome(self, before: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
                xp: types.ModuleType = np) -> tuple:
        """(obs [n, d], reward [n], terminated [n] bool) after a step from `before`, with `action` [n, nu]."""
        raise NotImplementedError(f"{type(self).__name__} defines no outcome()")

    def termination_margin(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict,
                           xp: types.ModuleType = np) -> "np.ndarray | None":
        """[n] how far each simulation is from the termination condition after a step, in that condition's own units
        (> 0 before it, <= 0 where it terminates), as outcome() sees the state; None (the default): not exposed.
        verify reports its counterexamples' robustness with it."""
        return None

    def observation_layout(self) -> list[str]:
        """One short description per observation entry (exported controllers' docs)."""
        return [f"obs[{i}]" for i in range(self.observation_size)]

    def push_body_id(self) -> int:
        """The index of the body robustness pushes act on (push_body)."""
        if isinstance(self.push_body, str):
            return mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, self.push_body)
        return int(self.push_body)


def start_noise(task: Task, rng: np.random.Generator) -> tuple:
    """(dq [nq], dv [nv]) of a reset, drawn from a NumPy Generator (qpos first, then qvel, as gymnasium draws)."""
    m = task.model
    if task.qpos_noise == "uniform":
        dq = rng.uniform(low=-task.noise, high=task.noise, size=m.nq)
    else:
        dq = task.noise * rng.standard_normal(m.nq)
    scale = task.vel_scale
    dv = rng.uniform(low=-scale, high=scale, size=m.nv) if task.qvel_noise == "uniform" else scale * rng.standard_normal(m.nv)
    return dq, dv


def seed_words(seed: "int | Sequence[int] | np.ndarray") -> list[int]:
    """A numpy seed from an int or the uint32 words a program drew (a list of ints)."""
    return [int(w) for w in np.ravel(seed)]


class TaskC:
    """One task on one MjData in plain MuJoCo C (no JAX), stepped as the trainer's backends step it
    (ctrl = action, mj_step frame_skip times, mj_rnePostConstraint), reading obs, reward and termination
    from the Task. task: a Task (by a task's name: envs.resolve(name).make_c())."""

    def __init__(self, task):
        self.task = task
        self.model = self.task.model
        self.data = mujoco.MjData(self.model)
        self.goal = np.zeros(task.goal_size)

    @property
    def action_size(self) -> int:
        return self.model.nu

    @property
    def n_frames(self) -> int:
        """Physics steps per env step (the task's frame_skip)."""
        return int(self.task.frame_skip)

    def _derived(self):
        derived = {f: getattr(self.data, f)[None].copy() for f in self.task.derived}
        return {**derived, "goal": self.goal[None].copy()} if self.task.goal_size else derived

    def set_start(self, qpos: np.ndarray, qvel: np.ndarray, goal: "np.ndarray | None" = None) -> np.ndarray:
        """The start state (mj_resetData, qpos, qvel, mj_forward; the goal [goal_size] of a task that has one) -> obs."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = qpos, qvel
        mujoco.mj_forward(m, d)
        if goal is None and self.task.goal_size:
            raise ValueError(f"{self.task.name or type(self.task).__name__} draws a goal at reset: give set_start its goal "
                             f"[{self.task.goal_size}]")
        self.goal = np.zeros(self.task.goal_size) if goal is None else np.asarray(goal, np.float64)
        return self.task.observe(d.qpos[None], d.qvel[None], self._derived())[0]

    def observe(self) -> np.ndarray:
        """[d] the observation of the current state."""
        d = self.data
        return self.task.observe(d.qpos[None], d.qvel[None], self._derived())[0]

    def reset(self, seed: "int | Sequence[int] | np.ndarray") -> np.ndarray:
        if self.task.has_initialize:
            self.goal = self.task.start(self.data, seed)
            return self.observe()
        dq, dv = start_noise(self.task, np.random.default_rng(seed))
        return self.set_start(self.task.start_qpos + dq, dv)

    def step(self, action: np.ndarray) -> tuple:
        """One env step with an action in [-1, 1]^nu -> (obs, reward, terminated)."""
        a = np.asarray(action, np.float64)
        if a.shape != (self.model.nu,):
            raise ValueError(f"action has shape {a.shape}; {self.task.name or type(self.task).__name__} takes ({self.model.nu},)")
        return self.step_controls(self.task.controls(a[None])[0])

    def step_controls(self, ctrl: np.ndarray) -> tuple:
        """One env step with the controls ctrl [nu] themselves (the task's controls() of an action) -> (obs, reward,
        terminated)."""
        m, d = self.model, self.data
        a = np.asarray(ctrl, np.float64)
        before = self.task.before(d.qpos[None], self._derived())
        d.ctrl[:] = a
        mujoco.mj_step(m, d, nstep=self.task.frame_skip)
        if self.task.post_constraint:
            mujoco.mj_rnePostConstraint(m, d)
        if self.task.derived_after == "step1":
            mujoco.mj_step1(m, d)
        obs, reward, terminated = self.task.outcome(before, d.qpos[None], d.qvel[None], self._derived(), a[None])
        return obs[0], float(reward[0]), bool(terminated[0])


def coordinate_names(m: mujoco.MjModel) -> tuple:
    """Names of the qpos [nq] and qvel [nv] coordinates of a model, from its joint names."""
    qpos, qvel = [], []
    for j in range(m.njnt):
        name, kind = m.joint(j).name or f"joint{j}", m.jnt_type[j]
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            qpos += [f"{name}.{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
            qvel += [f"{name}.{c}" for c in ("vx", "vy", "vz", "wx", "wy", "wz")]
        elif kind == mujoco.mjtJoint.mjJNT_BALL:
            qpos += [f"{name}.{c}" for c in ("qw", "qx", "qy", "qz")]
            qvel += [f"{name}.{c}" for c in ("wx", "wy", "wz")]
        else:
            qpos.append(name)
            qvel.append(name)
    return qpos, qvel


def source_record(cls: type) -> dict:
    """What says which code defined a task: its module, file and the file's sha256 (None where there is no file)."""
    path = inspect.getsourcefile(cls) or ""
    digest = None
    if path and os.path.exists(path):
        with open(path, "rb") as f:
            digest = hashlib.sha256(f.read()).hexdigest()
    if path:
        rel = os.path.relpath(os.path.abspath(path))
        path = rel if not rel.startswith("..") else os.path.abspath(path)  # relative to where it ran, when below it
    return {"module": cls.__module__, "class": cls.__qualname__, "file": path or None, "sha256": digest}
