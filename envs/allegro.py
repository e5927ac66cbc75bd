"""`allegro_cylinder`: the paper's tactile in-hand manipulation task (Sec. V-B) on MJX.

An Allegro hand (right) pinches a cylinder between index finger and thumb; only those two fingers
move (8 joints, PD position servos). The task: turn the cylinder counter-clockwise as much as
possible. The cylinder turns on a hinge along its own axis; counter-clockwise is positive about that
axis (the hinge's +z, pointing from the thumb side toward the index side of the hand, i.e. the
direction of the index flexion axis) -- as seen by a camera looking down the axis from its + end.

Control: 100 Hz. An action a (8,) is clipped to [-1, 1] and moves the current PD joint targets by
ACTION_SCALE * a rad, clipped to the joint ranges; the simulator then runs SUBSTEPS steps of
TIMESTEP (= one 10 ms control step).
Observation (10,): the 8 joint positions (index j0..j3, thumb j0..j3, rad) and one tactile value
per finger: the contact normal force on the fingertip (N) averaged over its 18 taxels, i.e. the
fingertip's total normal force / 18 (the taxels tile the pad; a single contact loads them all).
Reward: the cylinder's mean angular velocity over the control step (rad/s, counter-clockwise
positive) minus ACTION_COST * |a|^2.
Start: the keyframe "grasp" (index and thumb touching the cylinder from opposite sides, PD targets
2 mm inside it; experiments/fig3_allegro/allegro_grasp.py), with the PD targets jittered by N(0, TARGET_NOISE^2) rad
and the cylinder's angle uniform (it is symmetric, so only the angle the reward never sees changes).
There is no termination (the cylinder cannot fall off its hinge); the time limit is
DEFAULT_EPISODE_LENGTH steps (2 s), set by envs.make.
"""

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx

from envs.allegro_task import (  # noqa: F401 - re-exported: the task's constants and MuJoCo C reference
    ACTION_COST, ACTION_SCALE, ASSET, DEFAULT_EPISODE_LENGTH, FINGER_TIPS, SUBSTEPS, TARGET_NOISE, TAXELS, TIMESTEP,
    finger_qpos, hinge_qpos, load_mj_model, observe_mujoco, step_mujoco, tactile_numpy,
)


class AllegroCylinder(Env):
    """Single-environment Brax interface over MJX; batch with jax.vmap. pipeline_state is mjx.Data."""

    def __init__(self):
        self.mj_model = load_mj_model()
        self.sys = mjx.put_model(self.mj_model)
        m = self.mj_model
        key = m.key("grasp")
        self._qpos0 = jnp.asarray(key.qpos, jnp.float32)
        self._ctrl0 = jnp.asarray(key.ctrl, jnp.float32)
        self._ctrl_lo, self._ctrl_hi = (jnp.asarray(x, jnp.float32) for x in m.actuator_ctrlrange.T)
        self._hinge_qpos, self._finger_qpos = hinge_qpos(m), finger_qpos(m)
        self._tip_ids = jnp.array([m.geom(n).id for n in FINGER_TIPS])
        self._data0 = mjx.make_data(self.sys)

    @property
    def observation_size(self):
        return self.mj_model.nu + len(FINGER_TIPS)

    @property
    def action_size(self):
        return self.mj_model.nu

    @property
    def backend(self):
        return "mjx"

    @property
    def dt(self):
        return TIMESTEP * SUBSTEPS

    @property
    def n_frames(self):
        return SUBSTEPS

    def tactile(self, data):
        """Per-fingertip normal contact force / TAXELS from the constraint forces of `data`. (2,)

        Contact rows are a fixed layout in MJX (contact.efc_address, contact.dim are static); with the
        pyramidal cone a contact's normal force is the sum of its 2*(condim-1) facet forces."""
        contact = data._impl.contact
        rows = [np.arange(a, a + 2 * (dim - 1)) if dim > 1 else np.array([a]) for a, dim in zip(contact.efc_address, contact.dim)]
        normal = jnp.stack([data._impl.efc_force[r].sum() for r in rows])  # (ncon,)
        normal = normal * jnp.asarray(np.asarray(contact.efc_address) >= 0)
        on_tip = (contact.geom[:, None, :] == self._tip_ids[None, :, None]).any(-1)  # (ncon, 2)
        return (normal[:, None] * on_tip).sum(0) / TAXELS

    def observe(self, data):
        return jnp.concatenate([data.qpos[self._finger_qpos], self.tactile(data)])

    def reset(self, rng):
        k_targets, k_angle = jax.random.split(rng)
        ctrl = self._ctrl0 + TARGET_NOISE * jax.random.normal(k_targets, self._ctrl0.shape)
        ctrl = jnp.clip(ctrl, self._ctrl_lo, self._ctrl_hi)
        qpos = self._qpos0.at[self._hinge_qpos].set(jax.random.uniform(k_angle, (), minval=-jnp.pi, maxval=jnp.pi))
        data = mjx.forward(self.sys, self._data0.replace(qpos=qpos, ctrl=ctrl))
        zero = jnp.zeros((), jnp.float32)
        metrics = {"angular_velocity": zero, "action_cost": zero}
        return State(data, self.observe(data), zero, zero, metrics, {})

    def step(self, state, action):
        if action.shape[-1:] != (self.action_size,):
            raise ValueError(f"action has shape {action.shape}; allegro_cylinder takes ({self.action_size},)")
        a = jnp.clip(action, -1.0, 1.0)
        data = state.pipeline_state
        ctrl = jnp.clip(data.ctrl + ACTION_SCALE * a, self._ctrl_lo, self._ctrl_hi)
        angle0 = data.qpos[self._hinge_qpos]
        data = data.replace(ctrl=ctrl)
        for _ in range(SUBSTEPS):
            data = mjx.step(self.sys, data)
        omega = (data.qpos[self._hinge_qpos] - angle0) / self.dt
        cost = ACTION_COST * jnp.sum(a * a)
        state.metrics.update(angular_velocity=omega, action_cost=cost)
        return state.replace(pipeline_state=data, obs=self.observe(data), reward=omega - cost, done=jnp.zeros_like(state.done))
