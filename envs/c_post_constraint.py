"""Physics backend 'c', the host side of a task whose derived fields are read after mj_rnePostConstraint
(Task.post_constraint: cacc, cfrc_int, cfrc_ext, which mujoco.batch does not compute): one MjData per thread, each
env stepped with mj_step and mj_rnePostConstraint, bit-identical to the plain MuJoCo C task. No JAX here."""

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import mujoco
import numpy as np

from envs.c_hosts import LIVE_HOSTS, CLOCK_FIELDS, STATE_SPEC
from envs.physics import resolve_threads


class PostConstraintHost:
    """A task definition whose observation needs mj_rnePostConstraint after the step (Ant-v5's contact forces),
    which mujoco.batch does not run: each call loads every simulation's row into one MjData per thread,
    steps it as gymnasium does (ctrl, mj_step frame_skip times, mj_rnePostConstraint) and saves it back.
    A row is the float64 mjSTATE_INTEGRATION row followed by the task's `before` values after the call
    (the main body's xy that the next step's velocity starts from, as gymnasium reads it then); extra as
    TaskHost's. The same interface as HostBatches (nstate, n_extra, clock, reset, step)."""

    def __init__(self, task: Any, threads: int) -> None:
        self.task, self.model, self.threads = task, task.model, resolve_threads(threads)
        self.n_mj = mujoco.mj_stateSize(self.model, STATE_SPEC)
        self.n_carry = task.before(np.zeros((1, self.model.nq)), self._derived(mujoco.MjData(self.model))).shape[1]
        self.nstate = self.n_mj + self.n_carry
        self.n_obs = int(task.observation_size)
        self.n_extra = self.n_obs + 2
        self._datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self._lock, self._clock_lock, self._pool = threading.Lock(), threading.Lock(), None
        self.clock = dict.fromkeys(CLOCK_FIELDS, 0)
        LIVE_HOSTS.add(self)

    def _derived(self, d: mujoco.MjData) -> dict:
        return {f: getattr(d, f)[None].copy() for f in self.task.derived}

    def _each(self, n: int, fn: Callable) -> list:
        """fn(data, i) for i < n, split over the threads, part k on MjData k -> list of results in order."""
        with self._lock:  # one call at a time on the MjData
            if self.threads <= 1 or n < 2:
                return [fn(self._datas[0], i) for i in range(n)]
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="mujoco_c")
            parts = np.array_split(np.arange(n), self.threads)
            chunks = self._pool.map(lambda k: [fn(self._datas[k], int(i)) for i in parts[k]], range(self.threads))
            return [r for chunk in chunks for r in chunk]

    def _read(self, d: mujoco.MjData, row_out: np.ndarray) -> tuple:
        mujoco.mj_getState(self.model, d, row_out[: self.n_mj], STATE_SPEC)
        return d.qpos.copy(), d.qvel.copy(), self._derived(d)

    def _finish(self, lead: tuple, results: list, obs: np.ndarray, reward: np.ndarray,
                terminated: np.ndarray) -> tuple:
        rows = np.stack([r[0] for r in results])
        qpos, qvel = np.stack([r[1] for r in results]), np.stack([r[2] for r in results])
        extra = np.concatenate([obs, reward[:, None], terminated[:, None].astype(np.float64)], axis=1)
        return (rows.view(np.uint32).reshape(*lead, 2 * self.nstate), qpos.astype(np.float32).reshape(*lead, -1),
                qvel.astype(np.float32).reshape(*lead, -1), extra.astype(np.float32).reshape(*lead, self.n_extra))

    def _gather(self, results: list) -> tuple:
        derived = {f: np.concatenate([r[3][f] for r in results]) for f in self.task.derived}
        qpos, qvel = np.stack([r[1] for r in results]), np.stack([r[2] for r in results])
        return qpos, qvel, derived

    def reset(self, dq: np.ndarray, dv: np.ndarray) -> tuple:
        """Rows at start_qpos + dq [..., nq], qvel dv [..., nv] after mj_resetData and mj_forward -> SimState fields."""
        t0 = time.perf_counter()
        m, lead = self.model, dq.shape[:-1]
        dq, dv = np.asarray(dq, np.float64).reshape(-1, m.nq), np.asarray(dv, np.float64).reshape(-1, m.nv)

        def one(d, i):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = self.task.start_qpos + dq[i], dv[i]
            mujoco.mj_forward(m, d)
            row = np.zeros(self.nstate)
            qpos, qvel, derived = self._read(d, row)
            row[self.n_mj:] = self.task.before(qpos[None], derived)[0]
            return row, qpos, qvel, derived

        results = self._each(len(dq), one)
        qpos, qvel, derived = self._gather(results)
        obs = self.task.observe(qpos, qvel, derived)
        out = self._finish(lead, results, obs, np.zeros(len(dq)), np.zeros(len(dq), bool))
        self._count(time.perf_counter() - t0, 0.0)
        return out

    def step(self, rows: np.ndarray, ctrl: np.ndarray) -> tuple:
        """n_frames mj_steps and mj_rnePostConstraint of every row [..., 2 nstate] with controls ctrl [..., nu]."""
        t0 = time.perf_counter()
        m, lead = self.model, rows.shape[:-1]
        # a copy: XLA's buffer need not be 8-byte aligned, and MuJoCo C reads the rows as doubles
        rows = np.array(rows, np.uint32).reshape(-1, 2 * self.nstate).view(np.float64)
        u = self.task.controls(np.asarray(ctrl, np.float64).reshape(-1, m.nu))

        def one(d, i):
            mujoco.mj_setState(m, d, rows[i, : self.n_mj], STATE_SPEC)
            d.ctrl[:] = u[i]
            mujoco.mj_step(m, d, nstep=self.task.frame_skip)
            mujoco.mj_rnePostConstraint(m, d)
            row = np.zeros(self.nstate)
            qpos, qvel, derived = self._read(d, row)
            row[self.n_mj:] = self.task.before(qpos[None], derived)[0]
            return row, qpos, qvel, derived

        t1 = time.perf_counter()
        results = self._each(len(rows), one)
        t2 = time.perf_counter()
        qpos, qvel, derived = self._gather(results)
        obs, reward, terminated = self.task.outcome(rows[:, self.n_mj:], qpos, qvel, derived, u)
        out = self._finish(lead, results, obs, reward, terminated)
        self._count(time.perf_counter() - t0, t2 - t1)
        return out

    def _count(self, host_s: float, mujoco_s: float) -> None:
        with self._clock_lock:
            self.clock["calls"] += 1
            self.clock["host_s"] += host_s
            self.clock["mujoco_c_s"] += mujoco_s
