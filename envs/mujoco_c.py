"""Tasks in plain MuJoCo C (the `mujoco` package: no MJX, no JAX) on the same MJCF as their MJX
versions, for running an exported controller outside the simulator it was trained in.

    task = make_c("hopper")          # or "allegro_cylinder"
    obs = task.reset(seed)
    obs, reward, done = task.step(action)

Each task ports its MJX environment's reset distribution, observation, reward and termination to
NumPy (hopper: Brax's `hopper` with its defaults; allegro_cylinder: envs/allegro.py). Nothing here
imports JAX; tests/test_mujoco_c.py checks the ports step for step against the MJX environments.
"""

import importlib.util
import os

import mujoco
import numpy as np

C_TASKS = ("hopper", "allegro_cylinder")


def brax_asset(name):
    """Path of an MJCF shipped with brax, found without importing brax (which imports JAX)."""
    spec = importlib.util.find_spec("brax")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the brax package is not installed")
    return os.path.join(spec.submodule_search_locations[0], "envs", "assets", name)


class HopperC:
    """Brax's `hopper` (defaults: 4 substeps of 2 ms, healthy z > 0.7, |angle| < 0.2, |state| < 100,
    reward = forward velocity + 1 - 1e-3 |a|^2, observation [z, angles, clip(qvel, -10, 10)], reset noise
    U(-5e-3, 5e-3) on qpos and qvel) in MuJoCo C."""

    n_frames = 4
    noise = 5e-3

    def __init__(self):
        self.model = mujoco.MjModel.from_xml_path(brax_asset("hopper.xml"))
        self.data = mujoco.MjData(self.model)
        self.dt = self.model.opt.timestep * self.n_frames

    @property
    def action_size(self):
        return self.model.nu

    def observe(self):
        d = self.data
        pos = d.qpos.copy()
        pos[1] = d.xpos[1, 2]  # torso height (Brax: x.pos[0, 2])
        return np.concatenate([pos[1:], np.clip(d.qvel, -10.0, 10.0)]).astype(np.float32)

    def reset(self, seed):
        rng = np.random.default_rng(seed)
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = m.qpos0 + rng.uniform(-self.noise, self.noise, m.nq)
        d.qvel[:] = rng.uniform(-self.noise, self.noise, m.nv)
        mujoco.mj_forward(m, d)
        return self.observe()

    def step(self, action):
        a = np.asarray(action, np.float64)
        if a.shape != (self.model.nu,):
            raise ValueError(f"action has shape {a.shape}; hopper takes ({self.model.nu},)")
        m, d = self.model, self.data
        x0 = d.xpos[1, 0]
        d.ctrl[:] = a
        mujoco.mj_step(m, d, nstep=self.n_frames)
        x_velocity = (d.xpos[1, 0] - x0) / self.dt
        z, angle = d.xpos[1, 2], d.qpos[2]
        state = np.concatenate([d.qpos[2:], d.qvel])
        healthy = np.all(np.abs(state) < 100.0) and 0.7 < z and -0.2 < angle < 0.2
        reward = x_velocity + 1.0 - 1e-3 * float(a @ a)
        return self.observe(), float(reward), not healthy

    def set_state(self, qpos, qvel):
        self.data.qpos[:], self.data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.model, self.data)


class AllegroC:
    """envs/allegro.py's allegro_cylinder in MuJoCo C (no termination; the time limit is the caller's)."""

    def __init__(self):
        from envs import allegro_task as allegro  # NumPy + MuJoCo C only

        self._allegro = allegro
        self.model = allegro.load_mj_model()
        self.data = mujoco.MjData(self.model)
        self.dt = allegro.TIMESTEP * allegro.SUBSTEPS

    @property
    def action_size(self):
        return self.model.nu

    def reset(self, seed):
        rng = np.random.default_rng(seed)
        m, d = self.model, self.data
        mujoco.mj_resetDataKeyframe(m, d, m.key("grasp").id)
        lo, hi = m.actuator_ctrlrange.T
        d.ctrl[:] = np.clip(d.ctrl + self._allegro.TARGET_NOISE * rng.normal(size=m.nu), lo, hi)
        d.qpos[m.jnt_qposadr[m.joint("object_hinge").id]] = rng.uniform(-np.pi, np.pi)
        mujoco.mj_forward(m, d)
        return self._allegro.observe_mujoco(m, d)

    def step(self, action):
        obs, reward = self._allegro.step_mujoco(self.model, self.data, action)
        return obs, reward, False


def make_c(name):
    if name == "hopper":
        return HopperC()
    if name == "allegro_cylinder":
        return AllegroC()
    raise ValueError(f"no MuJoCo C port of {name!r}; ported: {', '.join(C_TASKS)}")


def run_episodes(task, controller, episodes, episode_length, seed=0):
    """Deterministic controller (gsa_jax.numpy_policy) in the C task: returns [episodes], lengths [episodes].
    Actions are clipped to [-1, 1] as in training."""
    returns, lengths = [], []
    for e in range(episodes):
        obs = task.reset(seed + e)
        total, t = 0.0, 0
        for t in range(1, episode_length + 1):
            obs, r, done = task.step(np.clip(controller.act(obs), -1.0, 1.0))
            total += r
            if done:
                break
        returns.append(total)
        lengths.append(t)
    return np.array(returns), np.array(lengths)
