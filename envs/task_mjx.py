"""A task definition (envs/task.py) on MJX: the same MJCF (its integrator and solver options), start-state
law, observation, reward and termination (the task's functions with jax.numpy), so the same program runs on an
accelerator. MJX steps float32 and is another implementation of MuJoCo's physics: it agrees with MuJoCo C
(backend 'c') within the tolerances tests state (tests/test_gym_v5.py for gymnasium's v5 tasks,
tests/test_your_task.py for a user's), not bit for bit. A derived field that needs mj_rnePostConstraint (Ant-v5's
contact forces) comes from MJX's rne_postconstraint after the step. A contact that MuJoCo C makes or breaks at a
distance within float32 rounding of the geoms' margin can go the other way in MJX, so trajectories with contacts
part after such an event (Ant-v5 from ~3 env steps on); from a shared state one env step agrees.
"""

import jax
import jax.numpy as jnp
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf
from mujoco import mjx


def start_noise(rng, m, noise, law, vel_noise=None, qpos_law="uniform"):
    """(dq [nq], dv [nv]) of a reset drawn from rng: dq ~ U(-noise, noise) (qpos_law 'uniform') or noise * N(0, 1)
    ('normal'); dv ~ U(-s, s) (law 'uniform') or s * N(0, 1) ('normal') with s = vel_noise (None: noise); scales
    are scalars or per-coordinate arrays. The C backend's resets draw the same."""
    k_q, k_v = jax.random.split(rng)
    s = noise if vel_noise is None else vel_noise
    if qpos_law == "uniform":
        dq = jax.random.uniform(k_q, (m.nq,), minval=-noise, maxval=noise)
    else:
        dq = noise * jax.random.normal(k_q, (m.nq,))
    if law == "uniform":
        return dq, jax.random.uniform(k_v, (m.nv,), minval=-s, maxval=s)
    return dq, s * jax.random.normal(k_v, (m.nv,))


def task_start_noise(rng, task):
    """start_noise with a Task's (envs/task.py) start-state law."""
    return start_noise(rng, task.model, task.noise, task.qvel_noise, task.vel_noise, task.qpos_noise)


def step1(sys, data):
    """mj_step1 on MJX: position- and velocity-dependent fields and sensors of the current state (acceleration
    sensors untouched), as dm_control's legacy step leaves them (Task.derived_after 'step1')."""
    data = mjx.fwd_position(sys, data)
    data = mjx.sensor_pos(sys, data)
    data = mjx.fwd_velocity(sys, data)
    return mjx.sensor_vel(sys, data)


def mjx_model(model):
    """The MjModel MJX steps: the task's, less its energy flag (dm_control's MJCFs enable it; it computes
    data.energy for display and changes no dynamics; MJX refuses it)."""
    import copy

    import mujoco

    energy = int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    if not model.opt.enableflags & energy:
        return model
    model = copy.deepcopy(model)
    model.opt.enableflags &= ~energy
    return model


class TaskMjx(PipelineEnv):
    """A Task (envs/task.py) as a single-env Brax environment on MJX."""

    def __init__(self, task):
        import mujoco

        self.task = task
        data = mujoco.MjData(task.model)
        self._shapes = {f: getattr(data, f).shape for f in task.derived}  # MuJoCo C's (xmat [nbody, 9], not [.., 3, 3])
        super().__init__(mjcf.load_model(mjx_model(task.model)), backend="mjx", n_frames=task.frame_skip)

    def _derived(self, data):
        return {f: getattr(data, f).reshape(self._shapes[f])[None] for f in self.task.derived}

    def reset(self, rng):
        task = self.task
        dq, dv = task_start_noise(rng, task)
        data = self.pipeline_init(jnp.asarray(task.start_qpos, jnp.float32) + dq, dv)
        obs = task.observe(data.qpos[None], data.qvel[None], self._derived(data), jnp)[0]
        zero = jnp.zeros((), jnp.float32)
        return State(data, obs.astype(jnp.float32), zero, zero, {}, {})

    def step(self, state, action):
        d0 = state.pipeline_state
        before = self.task.before(d0.qpos[None], self._derived(d0), jnp)
        data = self.pipeline_step(d0, action)
        if self.task.post_constraint:
            data = mjx.rne_postconstraint(self.sys, data)  # cfrc_ext, as gymnasium's mj_rnePostConstraint
        if self.task.derived_after == "step1":
            data = step1(self.sys, data)
        obs, reward, terminated = self.task.outcome(before, data.qpos[None], data.qvel[None], self._derived(data),
                                                    action[None], jnp)
        return state.replace(pipeline_state=data, obs=obs[0].astype(jnp.float32), reward=reward[0].astype(jnp.float32),
                             done=terminated[0].astype(jnp.float32))
