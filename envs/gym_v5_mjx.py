"""gymnasium's v5 tasks (envs/gym_v5.py) on MJX: the same MJCF (its integrator and solver options), reset
noise law, observation, reward and termination (the task's functions with jax.numpy), so the same
program runs on an accelerator. MJX steps float32 and is another implementation of MuJoCo's physics:
it agrees with MuJoCo C (backend 'c', gymnasium's numbers) within the tolerance tests/test_gym_v5.py
states, not bit for bit. Ant-v5's contact forces come from MJX's rne_postconstraint after the step, as
gymnasium's from mj_rnePostConstraint. A contact that MuJoCo C makes or breaks at a distance within float32
rounding of the geoms' margin can go the other way in MJX, so trajectories with contacts part after such an
event (Ant-v5 from ~3 env steps on); from a shared state one env step agrees (tests/test_gym_v5.py).
"""

import jax
import jax.numpy as jnp
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf
from mujoco import mjx

from envs import gym_v5


def start_noise(rng, m, noise, law):
    """(dq [nq], dv [nv]) of a reset drawn from rng: dq ~ U(-noise, noise); dv ~ U(-noise, noise) ('uniform')
    or noise * N(0, 1) ('normal'). The C backend's resets draw the same."""
    k_q, k_v = jax.random.split(rng)
    dq = jax.random.uniform(k_q, (m.nq,), minval=-noise, maxval=noise)
    if law == "uniform":
        return dq, jax.random.uniform(k_v, (m.nv,), minval=-noise, maxval=noise)
    return dq, noise * jax.random.normal(k_v, (m.nv,))


class GymV5Mjx(PipelineEnv):
    """A v5 task as a single-env Brax environment on MJX."""

    def __init__(self, env_id):
        self.task = gym_v5.make_task(env_id)
        super().__init__(mjcf.load_model(self.task.model), backend="mjx", n_frames=self.task.frame_skip)

    def _derived(self, data):
        return {f: getattr(data, f)[None] for f in self.task.derived}

    def reset(self, rng):
        m, task = self.sys.mj_model, self.task
        dq, dv = start_noise(rng, m, task.noise, task.qvel_noise)
        data = self.pipeline_init(jnp.asarray(m.qpos0, jnp.float32) + dq, dv)
        obs = task.observe(data.qpos[None], data.qvel[None], self._derived(data), jnp)[0]
        zero = jnp.zeros((), jnp.float32)
        return State(data, obs.astype(jnp.float32), zero, zero, {}, {})

    def step(self, state, action):
        d0 = state.pipeline_state
        before = self.task.before(d0.qpos[None], self._derived(d0), jnp)
        data = self.pipeline_step(d0, action)
        if self.task.post_constraint:
            data = mjx.rne_postconstraint(self.sys, data)  # cfrc_ext, as gymnasium's mj_rnePostConstraint
        obs, reward, terminated = self.task.outcome(before, data.qpos[None], data.qvel[None], self._derived(data),
                                                    action[None], jnp)
        return state.replace(pipeline_state=data, obs=obs[0].astype(jnp.float32), reward=reward[0].astype(jnp.float32),
                             done=terminated[0].astype(jnp.float32))
