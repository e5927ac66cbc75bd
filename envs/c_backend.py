"""Physics backend 'c': MuJoCo C stepped from inside the compiled trainer.

    env = envs.make("hopper", physics=Physics(backend="c"))     # a Brax-style env, like the MJX one

The classes are built by the tasks' records (envs/families/): TaskCEnv, AllegroCTask; their host side, which steps
MuJoCo C, is envs/c_hosts.py.

Each env's simulation state is its float64 mjSTATE_INTEGRATION row (time, qpos, qvel, act, solver
warmstart, ctrl, ...) followed by what the task carries to its next step (n_carry values: its `before`), carried through the JAX program bit for bit as uint32 pairs (the program runs
float32). A step is one host call (envs/host_call.py) into mujoco.batch.Batch, which steps every env of the vmapped
batch (runs x envs) on a thread pool, bit-identical to mujoco.mj_step on one MjData per env. The state
never leaves the program, so runs stay pure, vmappable, checkpointable and resumable.

Tasks: every task definition (envs/task.py: gymnasium's v5 tasks, envs/v5_tasks.py; Brax's locomotion tasks,
envs.brax_ports.BRAX_PORTS; and a user's), whose observations, rewards and terminations are computed on the host
in float64 by the task's own functions (for the v5 tasks, the ones checked against gymnasium); and
allegro_cylinder, whose PD-target
update, reward and tactile values (MuJoCo contact sensors on the fingertips, envs/allegro_task.py) are
computed on the host in float64 as envs/allegro_task.step_mujoco computes them.
"""

import contextlib
from typing import Any, Callable, Iterator, NamedTuple

import jax
import jax.numpy as jnp

from envs import allegro_task
from envs.c_hosts import AllegroHost, TaskHost
from envs.c_post_constraint import PostConstraintHost
from envs.host_call import host_call
from envs.interface import Env, State
from envs.physics import Physics
from envs.starts import task_start_noise


class SimState(NamedTuple):
    """An env's simulation state inside the program (a pytree)."""

    rows: jax.Array  # uint32 [2 nstate]: the float64 mjSTATE_INTEGRATION row (and what the host carries), bit for bit
    qpos: jax.Array  # float32 [nq]
    qvel: jax.Array  # float32 [nv]
    extra: jax.Array  # float32 [n_extra]: the task's derived values (HostBatches.extra)


class CTask(Env):
    """A task as a single env with Brax's interface (envs/interface.py) stepped by MuJoCo C (subclasses: the task's JAX side)."""

    def __init__(self, name: str, physics: Physics, port: Any, host: Any) -> None:
        self.name, self.physics, self.port, self.host = name, physics, port, host
        self.mj_model = port.model  # the task's own model (physics records, deployment)
        m = self.mj_model
        f32 = jnp.float32
        self._shapes = (jax.ShapeDtypeStruct((2 * host.nstate,), jnp.uint32), jax.ShapeDtypeStruct((m.nq,), f32),
                        jax.ShapeDtypeStruct((m.nv,), f32), jax.ShapeDtypeStruct((host.n_extra,), f32))

    @property
    def observation_size(self) -> int:
        return int(jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs.shape[-1])

    @property
    def action_size(self) -> int:
        return int(self.mj_model.nu)

    @property
    def backend(self) -> str:
        return "c"

    def _call(self, fn: Callable, *args: jax.Array) -> SimState:
        return SimState(*host_call(fn, self._shapes, *args))

    def _check_action(self, action: jax.Array) -> None:
        if action.shape[-1:] != (self.action_size,):
            raise ValueError(f"action has shape {action.shape}; this environment takes ({self.action_size},)")


class AllegroCTask(CTask):
    """allegro_cylinder (envs/allegro.py) stepped by MuJoCo C: the same start distribution (the same
    draws from rng as the MJX task), action clipping, PD-target update, reward and observation."""

    def __init__(self, name: str, physics: Physics) -> None:
        port = allegro_task.AllegroC()
        super().__init__(name, physics, port, AllegroHost(physics.threads))
        m = self.mj_model
        self.n_frames, self.dt = allegro_task.SUBSTEPS, allegro_task.TIMESTEP * allegro_task.SUBSTEPS
        self._finger_qpos = allegro_task.finger_qpos(m)

    def _observe(self, sim: SimState) -> jax.Array:
        return jnp.concatenate([sim.qpos[self._finger_qpos], sim.extra[:2]])

    def reset(self, rng: jax.Array) -> State:
        k_targets, k_angle = jax.random.split(rng)
        noise = jax.random.normal(k_targets, (self.mj_model.nu,))
        angle = jax.random.uniform(k_angle, (), minval=-jnp.pi, maxval=jnp.pi)
        sim = self._call(self.host.reset, noise, angle)
        zero = jnp.zeros((), jnp.float32)
        return State(sim, self._observe(sim), zero, zero, {}, {})

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(action)
        a = jnp.clip(action.astype(jnp.float32), -1.0, 1.0)
        sim = self._call(self.host.step, state.pipeline_state.rows, a)
        reward = sim.extra[2] - allegro_task.ACTION_COST * jnp.sum(a * a)
        return state.replace(pipeline_state=sim, obs=self._observe(sim), reward=reward, done=jnp.zeros_like(state.done))


class TaskCEnv(CTask):
    """A task definition (envs/task.py) stepped by MuJoCo C: its start-state law drawn from rng; observation,
    reward and termination computed by its own functions in float64 on the host, then cast to float32."""

    def __init__(self, name: str, physics: Physics, task: Any) -> None:
        """task: the Task instance (envs/task.py) the record of `name` made (envs/registry.py)."""
        host = (PostConstraintHost if task.post_constraint else TaskHost)(task, physics.threads)
        super().__init__(name, physics, task, host)
        self.n_frames, self.dt = task.frame_skip, task.dt
        self._n_obs = self.host.n_obs
        self._nominal = None  # with variants enabled: (scales [P], push [2]) outside variant()
        self._active = None  # (scales, push) while variant() is open

    def enable_variants(self, spec: Any, push_body: "int | None") -> None:
        """Step with per-simulation model fields and pushes (envs/randomized_env.py); see TaskHost.enable_variants."""
        self.host.enable_variants(spec, push_body)
        self._nominal = (jnp.ones(len(spec.scales), jnp.float32), jnp.zeros(2, jnp.float32))

    @contextlib.contextmanager
    def variant(self, scales: jax.Array, push: "jax.Array | None") -> Iterator[None]:
        """Inside (while traced): resets and steps run the model variant of scales [P] and push [2] (None: none)."""
        self._active = (scales, self._nominal[1] if push is None else push)
        try:
            yield
        finally:
            self._active = None

    def _variant_args(self) -> tuple:
        """The (scales, push) of the call being traced: variant()'s, else the nominal ones; () without variants."""
        return () if self._nominal is None else (self._active or self._nominal)

    def reset(self, rng: jax.Array) -> State:
        task = self.port
        if task.has_initialize:
            return self.reset_where(rng, jnp.ones((), bool))
        sim = self._call(self.host.reset, *task_start_noise(rng, task), *self._variant_args()[:1])
        zero = jnp.zeros((), jnp.float32)
        return State(sim, sim.extra[: self._n_obs], zero, zero, {}, {})

    def reset_where(self, rng: jax.Array, needed: jax.Array) -> State:
        """A reset where `needed` (a bool) holds, else an unused placeholder state: a task whose start law is code
        (initialize()) runs it on the host only for the envs that restart (envs/wrappers.py's AutoReset)."""
        if not self.port.has_initialize:
            return self.reset(rng)
        seed = jax.random.bits(rng, (2,), jnp.uint32)  # 64 bits: start states do not repeat across many resets
        sim = self._call(self.host.reset_init, seed, needed.astype(jnp.int32))
        zero = jnp.zeros((), jnp.float32)
        return State(sim, sim.extra[: self._n_obs], zero, zero, {}, {})

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(action)
        sim = self._call(self.host.step, state.pipeline_state.rows, action.astype(jnp.float32), *self._variant_args())
        n = self._n_obs
        return state.replace(pipeline_state=sim, obs=sim.extra[:n], reward=sim.extra[n], done=sim.extra[n + 1])
