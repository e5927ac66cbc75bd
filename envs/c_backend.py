"""Physics backend 'c': MuJoCo C stepped from inside the compiled trainer.

    env = envs.make("hopper", physics=Physics(backend="c"))     # a Brax-style env, like the MJX one

Each env's simulation state is its float64 mjSTATE_INTEGRATION row (time, qpos, qvel, act, solver
warmstart, ctrl, ...), carried through the JAX program bit for bit as uint32 pairs (the program runs
float32). A step is one jax.pure_callback into mujoco.batch.Batch, which steps every env of the vmapped
batch (runs x envs) on a thread pool, bit-identical to mujoco.mj_step on one MjData per env. The state
never leaves the program, so runs stay pure, vmappable, checkpointable and resumable.

Observations, rewards and terminations are envs/mujoco_c.py's definitions (written once for NumPy and
jax.numpy), evaluated here with jax.numpy on the float32 qpos, qvel and torso position the callback
returns. Tasks: the MuJoCo C ports of hopper, walker2d, halfcheetah and ant (BRAX_PORTS).
"""

import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import batch as mj_batch

from envs import mujoco_c

STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


class SimState(NamedTuple):
    """An env's simulation state inside the program (a pytree)."""

    rows: jax.Array  # uint32 [2 nstate]: the float64 mjSTATE_INTEGRATION row, bit for bit
    qpos: jax.Array  # float32 [nq]
    qvel: jax.Array  # float32 [nv]
    torso: jax.Array  # float32 [3]: body 1's position, as mj_step leaves xpos (before its last substep)


class HostBatches:
    """The host side: one mujoco.batch.Batch per batch size the program calls with, made on first use."""

    def __init__(self, model, n_frames, threads):
        self.model, self.n_frames, self.threads = model, int(n_frames), int(threads)
        data = mujoco.MjData(model)
        self.nstate = mujoco.mj_stateSize(model, STATE_SPEC)
        self.template = np.zeros(self.nstate)  # the reset state's row (mj_resetData)
        mujoco.mj_getState(model, data, self.template, STATE_SPEC)
        self._batches, self._lock = {}, threading.Lock()

    def _get(self, nsim):
        with self._lock:
            if nsim not in self._batches:
                b = mj_batch.Batch(self.model, nsim=nsim, nthread=self.threads)
                b.bind("xpos")  # a derived field is copied out by the calls after it is bound
                self._batches[nsim] = (b, threading.Lock())
            return self._batches[nsim]

    def _outputs(self, b, lead):
        m = self.model
        return (b.state.view(np.uint32).reshape(*lead, 2 * self.nstate), b.qpos.astype(np.float32).reshape(*lead, m.nq),
                b.qvel.astype(np.float32).reshape(*lead, m.nv), b.xpos[:, 1].astype(np.float32).reshape(*lead, 3))

    def reset(self, dq, dv):
        """Rows at qpos0 + dq [..., nq], qvel dv [..., nv] after mj_forward -> SimState fields."""
        lead = dq.shape[:-1]
        b, lock = self._get(int(np.prod(lead, dtype=int)))
        with lock:
            b.state[:] = self.template
            b.qpos[:] = self.model.qpos0 + np.asarray(dq, np.float64).reshape(-1, self.model.nq)
            b.qvel[:] = np.asarray(dv, np.float64).reshape(-1, self.model.nv)
            b.forward()
            return self._outputs(b, lead)

    def step(self, rows, ctrl):
        """n_frames mj_steps of every row [..., 2 nstate] under ctrl [..., nu] -> SimState fields."""
        lead = rows.shape[:-1]
        b, lock = self._get(int(np.prod(lead, dtype=int)))
        with lock:
            b.state[:] = np.ascontiguousarray(rows).reshape(-1, 2 * self.nstate).view(np.float64)
            b.ctrl[:] = np.asarray(ctrl, np.float64).reshape(-1, self.model.nu)
            b.step(nstep=self.n_frames)
            return self._outputs(b, lead)


class CTask(Env):
    """A BraxTaskC task (envs/mujoco_c.py) as a single-env Brax environment stepped by MuJoCo C."""

    def __init__(self, name, physics):
        self.name, self.physics = name, physics
        self.port = mujoco_c.BRAX_PORTS[name]()
        self.mj_model = self.port.model
        self.n_frames, self.dt = self.port.n_frames, self.port.dt
        self.host = HostBatches(self.mj_model, self.n_frames, physics.threads)
        m = self.mj_model
        f32 = jnp.float32
        self._shapes = (jax.ShapeDtypeStruct((2 * self.host.nstate,), jnp.uint32), jax.ShapeDtypeStruct((m.nq,), f32),
                        jax.ShapeDtypeStruct((m.nv,), f32), jax.ShapeDtypeStruct((3,), f32))

    @property
    def observation_size(self):
        m = self.mj_model
        return int(self.port.observe_state(np.zeros(m.nq), np.zeros(m.nv), np.zeros(3)).shape[-1])

    @property
    def action_size(self):
        return int(self.mj_model.nu)

    @property
    def backend(self):
        return "c"

    def _call(self, fn, *args):
        return SimState(*jax.pure_callback(fn, self._shapes, *args, vmap_method="broadcast_all"))

    def _observe(self, sim):
        return self.port.observe_state(sim.qpos, sim.qvel, sim.torso, jnp).astype(jnp.float32)

    def reset(self, rng):
        """Brax's reset noise for the task (port.noise, port.qvel_noise), drawn here from rng."""
        m, port = self.mj_model, self.port
        k_q, k_v = jax.random.split(rng)
        dq = jax.random.uniform(k_q, (m.nq,), minval=-port.noise, maxval=port.noise)
        if port.qvel_noise == "uniform":
            dv = jax.random.uniform(k_v, (m.nv,), minval=-port.noise, maxval=port.noise)
        else:
            dv = port.noise * jax.random.normal(k_v, (m.nv,))
        sim = self._call(self.host.reset, dq, dv)
        zero = jnp.zeros((), jnp.float32)
        return State(sim, self._observe(sim), zero, zero, {}, {})

    def step(self, state, action):
        if action.shape[-1:] != (self.action_size,):
            raise ValueError(f"action has shape {action.shape}; this environment takes ({self.action_size},)")
        sim = self._call(self.host.step, state.pipeline_state.rows, action.astype(jnp.float32))
        reward = self.port.reward_state(state.pipeline_state.torso, sim.torso, action, jnp)
        healthy = self.port.healthy_state(sim.qpos, sim.qvel, sim.torso, jnp)
        return state.replace(pipeline_state=sim, obs=self._observe(sim), reward=reward.astype(jnp.float32),
                             done=1.0 - healthy.astype(jnp.float32))


def float64_rows(rows):
    """The float64 mjSTATE_INTEGRATION rows [..., nstate] of SimState.rows [..., 2 nstate] (host arrays)."""
    return np.ascontiguousarray(np.asarray(rows)).view(np.float64)
