"""Exported controllers under shifted conditions in MuJoCo C: the task's own model with a physical
parameter scaled, the other simulator of the same robot, noisy observations, late actions or pushes.
Every shift is an explicit argument applied to a fresh task of its own (no model or process state is
patched), and every episode starts from the same fixed start states as the nominal ones.

    Shift("mass", 1.25)       every body's mass and inertia x 1.25 (the same shapes, denser)
    Shift("friction", 0.5)    every geom's sliding friction x 0.5
    Shift("gear", 0.8)        every actuator's gear x 0.8 (weaker motors)
    Shift("obs_noise", 0.1)   Gaussian noise of 0.1 x each observation's running std (the controller's
                              normalizer statistics) added to what the controller sees
    Shift("action_delay", 1)  each action applied one control step late (zero action first)
    Shift("push", 0.25)       horizontal pushes on the task's push body (1: the torso), each a force of
                              level x total mass / dt for one env step dt: an impulse of level x total mass,
                              the momentum of a `level` m/s velocity change of the whole robot as one rigid
                              body (not a velocity set on the root joint),
                              at each env step with probability DEFAULT_PUSH_RATE (envs/randomization.py), in a random horizontal direction
                              (+-x for planar robots)
    Shift("simulator", 0)     the same robot in the other task family: gymnasium's v5 task <-> Brax's
                              variant (envs.mujoco_c ports), where their observation layouts match
"""

from typing import Any, NamedTuple

import numpy as np

from envs.randomization import DEFAULT_PUSH_RATE, push_force

OTHER_SIMULATOR = {"Hopper-v5": "hopper", "Walker2d-v5": "walker2d", "HalfCheetah-v5": "halfcheetah",
                   "hopper": "Hopper-v5", "walker2d": "Walker2d-v5", "halfcheetah": "HalfCheetah-v5"}
KINDS = ("nominal", "simulator", "mass", "friction", "gear", "obs_noise", "action_delay", "push")


class Shift(NamedTuple):
    kind: str
    level: float = 0.0

    @property
    def name(self) -> str:
        return self.kind if self.kind in ("nominal", "simulator") else f"{self.kind} {self.level:g}"


DEFAULT_SHIFTS = (Shift("nominal"), Shift("simulator"), Shift("mass", 0.8), Shift("mass", 1.25),
                  Shift("friction", 0.5), Shift("friction", 1.5), Shift("gear", 0.8), Shift("obs_noise", 0.05),
                  Shift("obs_noise", 0.1), Shift("action_delay", 1), Shift("push", 0.25))


def applies(env_name: str, shift: Shift) -> bool:
    """Whether a shift exists for the task (the other simulator only where the layouts match)."""
    if shift.kind not in KINDS:
        raise ValueError(f"unknown shift {shift.kind!r}; choose one of {', '.join(KINDS)}")
    return shift.kind != "simulator" or env_name in OTHER_SIMULATOR


def shifted_task(env_name: str, shift: Shift) -> Any:
    """A fresh MuJoCo C task (envs.mujoco_c.make_c: reset(seed), step(action), .model, .data) of env_name
    with the shift's model change; derived constants recomputed (mj_setConst)."""
    import mujoco  # here, where a task is made: the shifts' names load without MuJoCo (`gsa robustness --help`)

    from envs.mujoco_c import make_c

    task = make_c(OTHER_SIMULATOR[env_name] if shift.kind == "simulator" else env_name)
    m = task.model
    if shift.kind == "mass":
        m.body_mass[:] *= shift.level
        m.body_inertia[:] *= shift.level
    elif shift.kind == "friction":
        m.geom_friction[:, 0] *= shift.level
    elif shift.kind == "gear":
        m.actuator_gear[:, 0] *= shift.level
    mujoco.mj_setConst(m, task.data)
    return task


def push_schedule(rng: np.random.Generator, length: int, planar: bool) -> np.ndarray:
    """[length, 2] horizontal push directions (unit vectors; zero where no push) of one episode."""
    hit = rng.random(length) < DEFAULT_PUSH_RATE
    angle = np.where(rng.random(length) < 0.5, 0.0, np.pi) if planar else rng.uniform(0, 2 * np.pi, length)
    return hit[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)


def is_planar(task: Any) -> bool:
    """Whether a MuJoCo C task's robot moves in the x-z plane (pushes then act along +-x): its definition's
    `planar` (envs/task.py; False for a task without one)."""
    return bool(getattr(getattr(task, "task", None), "planar", False))


def push_body(task: Any) -> int:
    """The body a push acts on in a MuJoCo C task: its definition's push_body (envs/task.py), else body 1."""
    definition = getattr(task, "task", None)
    return definition.push_body_id() if definition is not None else 1


def step_task(task: Any, action: np.ndarray, push_force: np.ndarray) -> tuple:
    """One env step of a MuJoCo C task, with a horizontal force [2] on its push body during it (zero: none)."""
    if not push_force.any():
        return task.step(action)
    body = push_body(task)
    task.data.xfrc_applied[body, :2] = push_force
    try:
        return task.step(action)
    finally:
        task.data.xfrc_applied[body, :2] = 0.0


def task_step_seconds(task: Any) -> float:
    """Simulated seconds per env step of a MuJoCo C task."""
    return task.model.opt.timestep * task.n_frames


def run_shifted(ctrl: Any, env_name: str, shift: Shift, seeds: np.ndarray, length: int = 1000,
                record: bool = False) -> tuple:
    """Deterministic episodes of the controller (gsa_jax.deployment.numpy_policy) under the shift, one per start seed,
    stepped together -> (returns [E], lengths [E], observations the controller saw [N, d_s] if record)."""
    tasks = [shifted_task(env_name, shift) for _ in seeds]
    obs = np.stack([t.reset(int(s)) for t, s in zip(tasks, seeds)]).astype(np.float64)
    rng = np.random.default_rng([int(s) for s in seeds] + [KINDS.index(shift.kind)])
    std = np.asarray(ctrl.obs_std, np.float64)
    pushes = np.stack([push_schedule(rng, length, is_planar(tasks[0])) for _ in seeds]) if shift.kind == "push" else None
    impulse = push_force(shift.level, tasks[0].model, task_step_seconds(tasks[0]))
    alive, returns, lengths = np.ones(len(seeds), bool), np.zeros(len(seeds)), np.zeros(len(seeds), int)
    prev, seen = np.zeros((len(seeds), tasks[0].model.nu)), []
    for t in range(length):
        seen_obs = obs + (shift.level * std * rng.standard_normal(obs.shape) if shift.kind == "obs_noise" else 0.0)
        if record:
            seen.append(seen_obs[alive])
        action = ctrl.act(seen_obs.astype(np.float32)).astype(np.float64)  # inside the task's action bounds
        applied, prev = (prev, action) if shift.kind == "action_delay" else (action, action)
        for e in np.flatnonzero(alive):
            force = impulse * pushes[e, t] if pushes is not None else np.zeros(2)
            o, r, done = step_task(tasks[e], applied[e], force)
            obs[e], returns[e], lengths[e] = o, returns[e] + r, t + 1
            alive[e] = not done
        if not alive.any():
            break
    return returns, lengths, (np.concatenate(seen) if record else None)
