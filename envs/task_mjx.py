"""A task definition (envs/task.py) on MJX: the same MJCF (its integrator and solver options), start-state
law, observation, reward and termination (the task's functions with jax.numpy), so the same program runs on an
accelerator. MJX steps float32 and is another implementation of MuJoCo's physics: it agrees with MuJoCo C
(backend 'c') within the tolerances tests state (tests/test_gym_v5.py for gymnasium's v5 tasks,
tests/test_your_task.py for a user's), not bit for bit. A derived field that needs mj_rnePostConstraint (Ant-v5's
contact forces) comes from MJX's rne_postconstraint after the step. A contact that MuJoCo C makes or breaks at a
distance within float32 rounding of the geoms' margin can go the other way in MJX, so trajectories with contacts
part after such an event (Ant-v5 from ~3 env steps on); from a shared state one env step agrees.
"""

import contextlib
import copy
import dataclasses
import functools
from typing import Any, Iterator

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf
from mujoco import mjx

from envs.starts import start_noise, task_start_noise  # noqa: F401 - re-exported


def mjx_model_fields() -> set:
    """The names of MJX's model fields (model scales on MJX apply to these)."""
    return {f.name for f in dataclasses.fields(mjx.Model)}


def step1(sys: Any, data: mjx.Data) -> mjx.Data:
    """mj_step1 on MJX: position- and velocity-dependent fields and sensors of the current state (acceleration
    sensors untouched), as dm_control's legacy step leaves them (Task.derived_after 'step1')."""
    data = mjx.fwd_position(sys, data)
    data = mjx.sensor_pos(sys, data)
    data = mjx.fwd_velocity(sys, data)
    return mjx.sensor_vel(sys, data)


def mjx_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """The MjModel MJX steps: the task's, less its energy flag (dm_control's MJCFs enable it; it computes
    data.energy for display and changes no dynamics; MJX refuses it)."""
    energy = int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    if not model.opt.enableflags & energy:
        return model
    model = copy.deepcopy(model)
    model.opt.enableflags &= ~energy
    return model


@jax.tree_util.register_pytree_node_class
class WithGoal:
    """MJX's data and the goal a task drew at reset ([goal_size]): the pipeline state of a task with a goal, so an
    auto-reset swaps both (qpos and qvel read through)."""

    def __init__(self, data, goal):
        self.data, self.goal = data, goal

    def tree_flatten(self) -> tuple:
        return (self.data, self.goal), None

    @classmethod
    def tree_unflatten(cls, _: None, children: tuple) -> "WithGoal":
        return cls(*children)

    @property
    def qpos(self) -> jax.Array:
        return self.data.qpos

    @property
    def qvel(self) -> jax.Array:
        return self.data.qvel


def host_start(task: Any, seeds: np.ndarray, needed: np.ndarray) -> tuple:
    """(qpos [..., nq], qvel [..., nv], goal [..., goal_size]) float32 of task.initialize() from seeds [..., 2] where
    needed [...] (elsewhere qpos0, at rest: a placeholder the caller discards): the host side of an MJX reset whose
    start law is code."""
    m, lead = task.model, np.shape(needed)
    seeds, needed = np.asarray(seeds).reshape(-1, 2), np.asarray(needed).reshape(-1)
    out = [np.zeros((len(needed), k), np.float32) for k in (m.nq, m.nv, task.goal_size)]
    out[0][:] = m.qpos0
    data = mujoco.MjData(m)
    for i in np.flatnonzero(needed):
        out[2][i] = task.start(data, seeds[i])
        out[0][i], out[1][i] = data.qpos, data.qvel
    return tuple(o.reshape(*lead, o.shape[-1]) for o in out)


class TaskMjx(PipelineEnv):
    """A Task (envs/task.py) as a single-env Brax environment on MJX. A start law written as code (initialize())
    runs on the host through a callback, for the envs that restart (reset_where); its goal rides with MJX's data
    (WithGoal)."""

    def __init__(self, task):
        self.task = task
        data = mujoco.MjData(task.model)
        self._shapes = {f: getattr(data, f).shape for f in task.derived}  # MuJoCo C's (xmat [nbody, 9], not [.., 3, 3])
        try:
            super().__init__(mjcf.load_model(mjx_model(task.model)), backend="mjx", n_frames=task.frame_skip)
        except NotImplementedError as e:  # a model MJX cannot step (dmc:fish-swim: ellipsoid-box collisions)
            raise ValueError(f"MJX cannot step task {task.name or type(task).__name__!r} ({e}); train it with backend "
                             "'c' (--physics c)") from None

    def _derived(self, data, goal=None):
        derived = {f: getattr(data, f).reshape(self._shapes[f])[None] for f in self.task.derived}
        return {**derived, "goal": goal[None]} if self.task.goal_size else derived

    def _state(self, data, goal):
        obs = self.task.observe(data.qpos[None], data.qvel[None], self._derived(data, goal), jnp)[0]
        zero = jnp.zeros((), jnp.float32)
        return State(WithGoal(data, goal) if self.task.goal_size else data, obs.astype(jnp.float32), zero, zero, {}, {})

    def reset(self, rng: jax.Array) -> State:
        task = self.task
        if task.has_initialize:
            return self.reset_where(rng, jnp.ones((), bool))
        dq, dv = task_start_noise(rng, task)
        return self._state(self.pipeline_init(jnp.asarray(task.start_qpos, jnp.float32) + dq, dv), None)

    def reset_where(self, rng: jax.Array, needed: jax.Array) -> State:
        """The reset where `needed` holds (else an unused placeholder): initialize() on the host by a callback."""
        if not self.task.has_initialize:
            return self.reset(rng)
        m = self.task.model
        shapes = tuple(jax.ShapeDtypeStruct((k,), jnp.float32) for k in (m.nq, m.nv, self.task.goal_size))
        qpos, qvel, goal = jax.pure_callback(functools.partial(host_start, self.task), shapes,
                                             jax.random.bits(rng, (2,), jnp.uint32), needed, vmap_method="broadcast_all")
        return self._state(self.pipeline_init(qpos, qvel), goal)

    def step(self, state: State, action: jax.Array) -> State:
        d0, goal = state.pipeline_state, None
        if self.task.goal_size:
            d0, goal = d0.data, d0.goal
        before = self.task.before(d0.qpos[None], self._derived(d0, goal), jnp)
        ctrl = self.task.controls(action[None], jnp)[0]
        data = self.pipeline_step(d0, ctrl)
        if self.task.post_constraint:
            data = mjx.rne_postconstraint(self.sys, data)  # cfrc_ext, as gymnasium's mj_rnePostConstraint
        if self.task.derived_after == "step1":
            data = step1(self.sys, data)
        obs, reward, terminated = self.task.outcome(before, data.qpos[None], data.qvel[None], self._derived(data, goal),
                                                    ctrl[None], jnp)
        return state.replace(pipeline_state=WithGoal(data, goal) if self.task.goal_size else data,
                             obs=obs[0].astype(jnp.float32), reward=reward[0].astype(jnp.float32),
                             done=terminated[0].astype(jnp.float32))


@contextlib.contextmanager
def process_local_devices() -> Iterator[None]:
    """mjx.put_model places the model on jax.devices()[0], which in a multi-process (jax.distributed) run
    is process 0's device; while an env is built, let jax.devices() name this process's devices."""
    if jax.process_count() == 1:
        yield
        return
    original = jax.devices
    jax.devices = lambda backend=None: jax.local_devices(backend=backend)
    try:
        yield
    finally:
        jax.devices = original
