"""Physics backend 'c', its host side: MuJoCo C batches that step, reset and read every env of a vmapped batch
(runs x envs) on a thread pool, in float64, bit-identical to mujoco.mj_step on one MjData per env. envs/c_backend.py
calls them from inside the compiled program (one host call per step, envs/host_call.py); this module loads no JAX.

HostBatches (mujoco.batch.Batch per batch size), NoisyStartHost (a start noise around the model's qpos0), AllegroHost
(allegro_cylinder's PD targets and tactile values, as envs/allegro_task.step_mujoco computes them), TaskHost (a task
definition's observations, rewards and terminations on the host, envs/task.py; PostConstraintHost, for a task whose
derived fields are read after the constraint solve, is envs/c_post_constraint.py's); host_seconds: where the host
calls' time went.
"""

import threading
import time
import weakref
from typing import Any, Callable

import mujoco
import numpy as np
from mujoco import batch as mj_batch

from envs import allegro_task
from envs.physics import resolve_threads
from envs.randomization import scaled_values

STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
LIVE_HOSTS = weakref.WeakSet()  # this process's live hosts, read by host_seconds()
CLOCK_FIELDS = ("calls", "host_s", "mujoco_c_s")


def host_seconds() -> dict:
    """{"calls", "host_s", "mujoco_c_s"} summed over this process's live hosts since they were made: host calls
    run, seconds inside them (the host function: state copies in and out, the task's derived values) and,
    of those, inside MuJoCo C. For benchmarks (gsa_jax.bench splits a sweep's time with it); no result
    depends on it."""
    total = dict.fromkeys(CLOCK_FIELDS, 0)
    for host in list(LIVE_HOSTS):
        for k, v in host.clock.items():
            total[k] += v
    return total


class HostBatches:
    """The host side: one mujoco.batch.Batch per batch size the program calls with, made on first use.
    Subclasses say what a reset and a step write into the rows and which derived values come back."""

    n_extra = 0
    n_carry = 0  # float64 values a row carries after the mjSTATE_INTEGRATION state (carry())
    bound = ()  # derived MjData fields the batch copies out after every call
    keyframe = None  # the keyframe resets start from (None: mj_resetData's state)

    def __init__(self, model: mujoco.MjModel, n_frames: int, threads: int) -> None:
        self.model, self.n_frames, self.threads = model, int(n_frames), resolve_threads(threads)
        self.n_mj = mujoco.mj_stateSize(model, STATE_SPEC)
        self.nstate = self.n_mj + self.n_carry
        self.template = self.reset_row()
        self._batches, self._lock = {}, threading.Lock()
        self.clock = dict.fromkeys(CLOCK_FIELDS, 0)  # see host_seconds()
        LIVE_HOSTS.add(self)

    def reset_row(self) -> np.ndarray:
        """The mjSTATE_INTEGRATION row every reset starts from [n_mj]: mj_resetData's state, or the keyframe's."""
        data = mujoco.MjData(self.model)
        if self.keyframe is not None:
            mujoco.mj_resetDataKeyframe(self.model, data, self.model.key(self.keyframe).id)
        row = np.zeros(self.n_mj)
        mujoco.mj_getState(self.model, data, row, STATE_SPEC)
        return row

    def carry(self, b: mj_batch.Batch, before: Any) -> np.ndarray:
        """float64 [nsim, n_carry]: what each row carries to the next call, from the batch after a call (before: what
        the call's write returned)."""
        return np.zeros((b.state.shape[0], 0))

    variant_fields = ()  # ((MjModel field, column or None, scale index), ...): enable_variants
    push_body = None  # the body a step's push acts on (None: no pushes)

    def enable_variants(self, spec: Any, push_body: "int | None") -> None:
        """Step each simulation with its own model fields (envs/randomization.py's spec.model_fields scaled by the
        scales a call passes) and pushes on push_body: per-simulation fields of the batch (Batch.expand), written
        only for the simulations whose scales changed, then mj_setConst for them where a field feeds it."""
        self.variant_fields, self.n_scales = spec.model_fields, len(spec.scales)
        self.nominal = {f: np.array(getattr(self.model, f)) for f, _, _ in self.variant_fields}
        self.setconst = any(f in mujoco.MjModel._setconst_inputs for f, _, _ in self.variant_fields)
        self.push_body = push_body if spec.push else None
        self._held = {}  # nsim -> float64 [nsim, n_scales]: the scales each simulation of that batch holds

    def apply_variants(self, b: mj_batch.Batch, scales: np.ndarray) -> None:
        """Give batch b's simulations the model fields of scales [nsim, n_scales] (writes only what changed)."""
        if not self.variant_fields:
            return
        scales = np.asarray(scales, np.float64).reshape(-1, self.n_scales)
        held = self._held.setdefault(len(scales), np.ones_like(scales))
        changed = np.flatnonzero((scales != held).any(axis=1))
        if changed.size:
            for field, col, i in self.variant_fields:
                b.expand(field)[changed] = scaled_values(self.nominal[field], col, scales[changed, i])
            if self.setconst:
                b.set_const(changed)
            held[changed] = scales[changed]

    def set_push(self, b: mj_batch.Batch, push: np.ndarray) -> None:
        """Horizontal forces push [nsim, 2] on the push body for the coming call (zeros: none)."""
        if self.push_body is not None:
            b.xfrc_applied[:, self.push_body, :2] = np.asarray(push, np.float64).reshape(-1, 2)

    def _get(self, nsim: int) -> tuple:
        with self._lock:
            if nsim not in self._batches:
                b = mj_batch.Batch(self.model, nsim=nsim, nthread=self.threads)
                for name in self.bound:
                    b.bind(name)  # a derived field is copied out by the calls after it is bound
                self._batches[nsim] = (b, threading.Lock())
            return self._batches[nsim]

    def extra(self, b: mj_batch.Batch, before: Any) -> np.ndarray:
        """float64 [nsim, n_extra] derived values after a call; before: what the call's write returned."""
        raise NotImplementedError

    def _run(self, lead: tuple, write: Callable, call: Callable) -> tuple:
        """Load a batch of prod(lead) sims with before = write(b), run call(b) -> SimState fields shaped lead."""
        t0 = time.perf_counter()
        b, lock = self._get(int(np.prod(lead, dtype=int)))
        m = self.model
        with lock:
            before = write(b)
            t1 = time.perf_counter()
            call(b)
            t2 = time.perf_counter()
            rows = np.concatenate([b.state, self.carry(b, before)], axis=1) if self.n_carry else b.state
            out = (rows.view(np.uint32).reshape(*lead, 2 * self.nstate), b.qpos.astype(np.float32).reshape(*lead, m.nq),
                   b.qvel.astype(np.float32).reshape(*lead, m.nv),
                   self.extra(b, before).astype(np.float32).reshape(*lead, self.n_extra))
        with self._lock:
            self.clock["calls"] += 1
            self.clock["host_s"] += time.perf_counter() - t0
            self.clock["mujoco_c_s"] += t2 - t1
        return out

    stage = 0  # mjtStage computed at the new state after a step (mjSTAGE_VEL: as mj_step1, Task.derived_after)

    def step_rows(self, rows: np.ndarray, action: np.ndarray, fn: Callable, variant: "tuple | None" = None) -> tuple:
        """n_frames mj_steps of every row [..., 2 nstate], after fn(b, action [nsim, nu] float64, carried
        [nsim, n_carry] float64) set the controls; fn's return value is passed to extra(). variant: (scales
        [..., n_scales], push [..., 2]) the simulations step with (enable_variants), the push for this call only."""
        lead = rows.shape[:-1]

        def write(b):
            full = np.ascontiguousarray(rows).reshape(-1, 2 * self.nstate).view(np.float64)
            b.state[:] = full[:, : self.n_mj]
            if variant is not None:
                self.apply_variants(b, variant[0])
                self.set_push(b, variant[1])
            return fn(b, np.asarray(action, np.float64).reshape(-1, self.model.nu), full[:, self.n_mj:])

        def call(b):
            b.step(nstep=self.n_frames, stage=self.stage)
            if variant is not None:
                self.set_push(b, np.zeros((len(b.state), 2)))  # the push lasts this call; no row carries it

        return self._run(lead, write, call)


class NoisyStartHost(HostBatches):
    """A locomotion task whose resets add noise to a start pose (start_qpos, default qpos0) and set qvel."""

    start_qpos = None

    def reset(self, dq: np.ndarray, dv: np.ndarray, scales: "np.ndarray | None" = None) -> tuple:
        """Rows at start_qpos + dq [..., nq], qvel dv [..., nv] after mj_forward (under the model variant of scales
        [..., n_scales], enable_variants) -> SimState fields."""
        m = self.model
        start = m.qpos0 if self.start_qpos is None else self.start_qpos

        def write(b):
            if scales is not None:
                self.apply_variants(b, scales)
            b.state[:] = self.template
            b.qpos[:] = start + np.asarray(dq, np.float64).reshape(-1, m.nq)
            b.qvel[:] = np.asarray(dv, np.float64).reshape(-1, m.nv)

        return self._run(dq.shape[:-1], write, lambda b: b.forward())


class AllegroHost(HostBatches):
    """allegro_cylinder: resets start from the "grasp" keyframe, actions move the PD targets (ctrl);
    extra = [index tactile, thumb tactile, the cylinder's angular velocity over the step] in float64
    before the float32 cast, as envs/allegro_task.step_mujoco computes them."""

    n_extra = 3
    bound = ("sensordata",)
    keyframe = "grasp"

    def __init__(self, threads: int) -> None:
        model, self.slots = allegro_task.load_tactile_model()
        self.hinge = allegro_task.hinge_qpos(model)
        self.lo, self.hi = model.actuator_ctrlrange.T.copy()
        super().__init__(model, allegro_task.SUBSTEPS, threads)

    def extra(self, b: mj_batch.Batch, before: np.ndarray) -> np.ndarray:
        """before: the hinge angles [nsim] the call started from."""
        omega = (b.qpos[:, self.hinge] - before) / (allegro_task.TIMESTEP * allegro_task.SUBSTEPS)
        return np.concatenate([allegro_task.tactile_from_sensordata(b.sensordata, self.slots), omega[:, None]], 1)

    def reset(self, noise: np.ndarray, angle: np.ndarray) -> tuple:
        """Rows at the keyframe with PD targets ctrl0 + TARGET_NOISE * noise [..., nu] (clipped) and the
        cylinder at `angle` [...], after mj_forward -> SimState fields."""
        m = self.model

        def write(b):
            b.state[:] = self.template
            b.ctrl[:] = np.clip(b.ctrl + allegro_task.TARGET_NOISE * np.asarray(noise, np.float64).reshape(-1, m.nu),
                                self.lo, self.hi)
            b.qpos[:, self.hinge] = np.asarray(angle, np.float64).reshape(-1)
            return b.qpos[:, self.hinge].copy()

        return self._run(angle.shape, write, lambda b: b.forward())

    def step(self, rows: np.ndarray, action: np.ndarray) -> tuple:
        """action [..., nu], already clipped to [-1, 1], moves the PD targets by ACTION_SCALE per unit."""
        def move_targets(b, a, carried):
            b.ctrl[:] = np.clip(b.ctrl + allegro_task.ACTION_SCALE * a, self.lo, self.hi)
            return b.qpos[:, self.hinge].copy()

        return self.step_rows(rows, action, move_targets)


class TaskHost(NoisyStartHost):
    """A task definition (envs/task.py; gymnasium's v5 tasks, Brax's locomotion tasks, a user's): actions are the
    controls; extra = [observation, reward, terminated], computed in float64 by the task's own functions on the
    batch's arrays (the derived fields as mj_step leaves them, as gymnasium reads them) before the float32 cast.
    A row carries the task's `before` values after each call (what the next step's reward starts from), so a
    step depends on its row alone: not on what the batch held before, and the same after a resume."""

    def __init__(self, task: Any, threads: int) -> None:
        self.task, self.start_qpos = task, task.start_qpos
        self.bound = task.derived
        self.stage = int(mujoco.mjtStage.mjSTAGE_VEL) if task.derived_after == "step1" else 0
        self.n_obs = int(task.observation_size)
        self.n_extra = self.n_obs + 2
        self._init_data, self._init_lock = mujoco.MjData(task.model), threading.Lock()  # initialize() resets
        data = self._init_data
        self.n_before = task.before(data.qpos[None], self._goal_derived(data, np.zeros((1, task.goal_size)))).shape[1]
        self.n_carry = self.n_before + task.goal_size  # a row carries [before values, goal]
        super().__init__(task.model, task.frame_skip, threads)

    def _goal_derived(self, arrays: Any, goal: np.ndarray, lead: Callable = lambda x: x[None]) -> dict:
        """{field: [n, ...]} of the task's derived fields of `arrays` (a batch, or an MjData with lead), and its goal."""
        derived = {f: lead(getattr(arrays, f)) for f in self.task.derived}
        return {**derived, "goal": goal} if self.task.goal_size else derived

    def _goals(self, before: "tuple | None", nsim: int) -> np.ndarray:
        """[nsim, goal_size] the goals the call's rows carried (zeros after a noise-law reset)."""
        return np.zeros((nsim, self.task.goal_size)) if before is None else before[0][:, self.n_before:]

    def carry(self, b: mj_batch.Batch, before: "tuple | None") -> np.ndarray:
        goal = self._goals(before, b.qpos.shape[0])
        return np.concatenate([self.task.before(b.qpos, self._goal_derived(b, goal, lambda x: x)), goal], axis=1)

    def extra(self, b: mj_batch.Batch, before: "tuple | None") -> np.ndarray:
        """before: (the carried values [n, n_carry], action [n, nu] float64); None after a reset."""
        derived = self._goal_derived(b, self._goals(before, b.qpos.shape[0]), lambda x: x)
        if before is None:
            obs = self.task.observe(b.qpos, b.qvel, derived)
            return np.concatenate([obs, np.zeros((len(obs), 2))], axis=1)
        obs, reward, terminated = self.task.outcome(before[0][:, : self.n_before], b.qpos, b.qvel, derived, before[1])
        return np.concatenate([obs, reward[:, None], terminated[:, None].astype(np.float64)], axis=1)

    def reset_init(self, seeds: np.ndarray, needed: np.ndarray) -> tuple:
        """Resets by the task's initialize() (envs/task.py) from seeds [..., 2] uint32, on the host's own MjData, for
        the envs where needed [...] is nonzero (the others get the template row, which the caller discards)
        -> SimState fields."""
        t0 = time.perf_counter()
        m, lead = self.model, np.shape(needed)
        seeds, needed = np.asarray(seeds).reshape(-1, 2), np.asarray(needed).reshape(-1)
        n = len(seeds)
        rows = np.tile(np.concatenate([self.template, np.zeros(self.n_carry)]), (n, 1))
        qpos, qvel, obs = np.tile(m.qpos0, (n, 1)), np.zeros((n, m.nv)), np.zeros((n, self.n_obs))
        with self._init_lock:
            d = self._init_data
            for i in np.flatnonzero(needed):
                goal = self.task.start(d, seeds[i])[None]
                derived = self._goal_derived(d, goal)
                mujoco.mj_getState(m, d, rows[i, : self.n_mj], STATE_SPEC)
                rows[i, self.n_mj:] = np.concatenate([self.task.before(d.qpos[None], derived), goal], axis=1)[0]
                qpos[i], qvel[i] = d.qpos, d.qvel
                obs[i] = self.task.observe(d.qpos[None], d.qvel[None], derived)[0]
        extra = np.concatenate([obs, np.zeros((n, 2))], axis=1)
        with self._lock:
            self.clock["calls"] += 1
            self.clock["host_s"] += time.perf_counter() - t0
        return (rows.view(np.uint32).reshape(*lead, 2 * self.nstate), qpos.astype(np.float32).reshape(*lead, m.nq),
                qvel.astype(np.float32).reshape(*lead, m.nv), extra.astype(np.float32).reshape(*lead, self.n_extra))

    def step(self, rows: np.ndarray, action: np.ndarray, scales: "np.ndarray | None" = None,
             push: "np.ndarray | None" = None) -> tuple:
        """Every row [..., 2 nstate] one env step with controls from action [..., nu] (and the model variant of
        scales [..., n_scales] with pushes push [..., 2]: enable_variants)."""
        def set_ctrl(b, a, carried):
            u = self.task.controls(a)
            b.ctrl[:] = u
            return carried, u

        return self.step_rows(rows, action, set_ctrl, None if scales is None else (scales, push))


def float64_rows(rows: np.ndarray) -> np.ndarray:
    """The float64 rows [..., nstate] of SimState.rows [..., 2 nstate] (host arrays): the mjSTATE_INTEGRATION row,
    then what the host carries (HostBatches.n_carry)."""
    return np.ascontiguousarray(np.asarray(rows)).view(np.float64)
