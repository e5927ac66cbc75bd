"""gymnasium's MuJoCo v5 tasks (gymnasium 1.4's defaults for those ids) on MuJoCo C, with no JAX.

    task = envs.resolve("Hopper-v5").make_c()  # envs.task.TaskC: one MjData in MuJoCo C
    obs = task.reset(seed)                    # or task.set_start(qpos, qvel)
    obs, reward, terminated = task.step(action)

The paper's Figure 1 and every published score table (CleanRL, SB3, EnvPool) are on gym's tasks, which
Brax's ports (envs.BRAX_TASKS) only resemble: another integrator, fewer solver iterations, other
frictions and observations. These are gymnasium's own: the MJCF read from the installed gymnasium
package, its frame skip, reset noise law, observation layout, every reward term and its termination.

Each task's observation, reward and termination are written once, over batches of simulations
(`outcome`, arrays with a leading batch axis, NumPy or jax.numpy), from the state and the derived MjData
fields `derived` names *as mj_step leaves them* (one substep behind the state, as gymnasium reads them).
Each is a task definition (envs/task.py), stepped with no code of its own: the C physics backend
(envs/c_backend.py) evaluates them in float64 on mujoco.batch's arrays inside the trainer; envs.task.TaskC steps
one MjData exactly as gymnasium's MujocoEnv does; envs/task_mjx.py evaluates them with jax.numpy on MJX's data.
tests/test_gym_v5.py checks the first two against gymnasium.make(id) step for step, and MJX against MuJoCo C
within a tolerance.

Ant-v5's observation holds the contact forces mj_rnePostConstraint computes after the step (from the
last Runge-Kutta stage's quantities), which mujoco.batch does not run: the C backend steps it one MjData
per thread instead (envs/c_backend.py).
"""

import importlib.util
import os

import mujoco
import numpy as np

from envs.task import Task, coordinate_names

EPISODE_LENGTH = 1000  # gymnasium's max_episode_steps for the five ids (a truncation, not a termination)


def gym_asset(name):
    """Path of an MJCF shipped with the installed gymnasium package (found without importing it)."""
    spec = importlib.util.find_spec("gymnasium")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("gymnasium is not installed (pip install 'gymnasium[mujoco]')")
    return os.path.join(spec.submodule_search_locations[0], "envs", "mujoco", "assets", name)


class V5Task(Task):
    """A v5 task (envs/task.py's definition): gymnasium's MJCF, frame skip and reset noise law (noise;
    qvel_noise 'uniform': qvel ~ U(-noise, noise), 'normal': noise * N(0, 1); qpos ~ qpos0 + U(-noise, noise)
    for every task, gymnasium drawing qpos first, then qvel), and the reward's root x position before a step."""

    env_id = ""
    episode_length = EPISODE_LENGTH

    def load_model(self):
        return mujoco.MjModel.from_xml_path(gym_asset(self.xml))

    def before(self, qpos, derived, xp=np):
        """[n, 1] the x position of the root (qpos[:, 0]) before a step."""
        return qpos[:, :1] + 0.0

    def observation_layout(self):
        """One short description per observation entry (for exported controllers' docs)."""
        qpos, qvel = coordinate_names(self.model)
        if self.env_id == "InvertedDoublePendulum-v5":
            hinges = qpos[1:]
            return (["cart x"] + [f"sin({h})" for h in hinges] + [f"cos({h})" for h in hinges]
                    + [f"{v} velocity (clipped to +-10)" for v in qvel] + ["cart constraint force (clipped to +-10)"])
        clipped = " (clipped to +-10)" if self.env_id != "HalfCheetah-v5" else ""
        return [f"{p} position" for p in qpos[1:]] + [f"{v} velocity{clipped}" for v in qvel]


class HopperV5(V5Task):
    """Hopper-v5: reward = x velocity + 1 (while healthy) - 1e-3 |a|^2; healthy while every element of
    qpos[2:], qvel lies in (-100, 100), 0.7 < z and -0.2 < angle < 0.2; obs [qpos[1:], clip(qvel, +-10)]."""

    planar = True

    env_id, xml, frame_skip, noise = "Hopper-v5", "hopper.xml", 4, 5e-3
    ctrl_cost = 1e-3

    def observe(self, qpos, qvel, derived, xp=np):
        return xp.concatenate([qpos[:, 1:], xp.clip(qvel, -10.0, 10.0)], axis=1)

    def healthy(self, qpos, qvel, xp=np):
        state = xp.concatenate([qpos[:, 2:], qvel], axis=1)
        z, angle = qpos[:, 1], qpos[:, 2]
        return xp.all((-100.0 < state) & (state < 100.0), axis=1) & (0.7 < z) & (-0.2 < angle) & (angle < 0.2)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        healthy = self.healthy(qpos, qvel, xp)
        x_velocity = (qpos[:, 0] - before[:, 0]) / self.dt
        reward = x_velocity + xp.where(healthy, 1.0, 0.0) - self.ctrl_cost * xp.sum(xp.square(action), axis=1)
        return self.observe(qpos, qvel, derived, xp), reward, ~healthy


class Walker2dV5(HopperV5):
    """Walker2d-v5 (its own walker2d_v5.xml: both feet with friction 0.9): as Hopper-v5, healthy while
    0.8 < z < 2 and -1 < angle < 1."""

    env_id, xml = "Walker2d-v5", "walker2d_v5.xml"

    def healthy(self, qpos, qvel, xp=np):
        z, angle = qpos[:, 1], qpos[:, 2]
        return (0.8 < z) & (z < 2.0) & (-1.0 < angle) & (angle < 1.0)


class HalfCheetahV5(V5Task):
    """HalfCheetah-v5: reward = x velocity - 0.1 |a|^2, never terminates; obs [qpos[1:], qvel];
    reset noise U(-0.1, 0.1) on qpos, 0.1 N(0, 1) on qvel."""

    planar = True

    env_id, xml, frame_skip, noise, qvel_noise = "HalfCheetah-v5", "half_cheetah.xml", 5, 0.1, "normal"

    def observe(self, qpos, qvel, derived, xp=np):
        return xp.concatenate([qpos[:, 1:], qvel], axis=1)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        x_velocity = (qpos[:, 0] - before[:, 0]) / self.dt
        reward = x_velocity - 0.1 * xp.sum(xp.square(action), axis=1)
        return self.observe(qpos, qvel, derived, xp), reward, xp.zeros(qpos.shape[:1], bool)


class InvertedDoublePendulumV5(V5Task):
    """InvertedDoublePendulum-v5: obs [cart x, sin, cos of the two hinges, clip(qvel, +-10),
    clip(qfrc_constraint[0], +-10)] (9); the tip site at (x, _, y) ends the episode when y <= 1;
    reward = 10 (unless terminated) - 0.01 x^2 - (y - 2)^2 - 1e-3 v1^2 - 5e-3 v2^2."""

    planar = True

    env_id, xml, frame_skip, noise, qvel_noise = "InvertedDoublePendulum-v5", "inverted_double_pendulum.xml", 5, 0.1, "normal"
    derived = ("site_xpos", "qfrc_constraint")
    equilibrium_qpos = (0.0, 0.0, 0.0)  # cart centred, both poles upright

    def observe(self, qpos, qvel, derived, xp=np):
        force = xp.clip(derived["qfrc_constraint"], -10.0, 10.0)[:, :1]
        return xp.concatenate([qpos[:, :1], xp.sin(qpos[:, 1:]), xp.cos(qpos[:, 1:]), xp.clip(qvel, -10.0, 10.0), force],
                              axis=1)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        x, y = derived["site_xpos"][:, 0, 0], derived["site_xpos"][:, 0, 2]
        terminated = y <= 1.0
        v1, v2 = qvel[:, 1], qvel[:, 2]
        reward = (xp.where(terminated, 0.0, 10.0) - (0.01 * x**2 + (y - 2.0) ** 2)) - (1e-3 * v1**2 + 5e-3 * v2**2)
        return self.observe(qpos, qvel, derived, xp), reward, terminated

    def termination_margin(self, qpos, qvel, derived, xp=np):
        """[n] the tip's height above 1 m (m): the episode ends where it is <= 0."""
        return derived["site_xpos"][:, 0, 2] - 1.0


class AntV5(V5Task):
    """Ant-v5: obs [qpos[2:], qvel, clip(cfrc_ext[1:], +-1)] (105: the contact forces mj_rnePostConstraint
    computes after the step); reward = x velocity of the torso (body 1's xpos over the step) + 1 (while
    healthy) - 0.5 |a|^2 - 5e-4 |clip(cfrc_ext, +-1)|^2; healthy while qpos, qvel are finite and
    0.2 <= z <= 1; reset noise U(-0.1, 0.1) on qpos, 0.1 N(0, 1) on qvel."""

    env_id, xml, frame_skip, noise, qvel_noise = "Ant-v5", "ant.xml", 5, 0.1, "normal"
    derived = ("xpos", "cfrc_ext")
    post_constraint = True  # cfrc_ext needs mj_rnePostConstraint after mj_step

    def before(self, qpos, derived, xp=np):
        return derived["xpos"][:, 1, :2] + 0.0

    def observation_layout(self):
        """qpos[2:], qvel, then each body's (but the world's) 6 clipped contact-force components."""
        qpos, qvel = coordinate_names(self.model)
        bodies = [self.model.body(i).name for i in range(1, self.model.nbody)]
        forces = [f"{b} contact force {c} (clipped to +-1)" for b in bodies for c in ("tx", "ty", "tz", "fx", "fy", "fz")]
        return [f"{p} position" for p in qpos[2:]] + [f"{v} velocity" for v in qvel] + forces

    def _forces(self, derived, xp):
        f = xp.clip(derived["cfrc_ext"], -1.0, 1.0)
        return f.reshape(f.shape[0], -1)

    def observe(self, qpos, qvel, derived, xp=np):
        return xp.concatenate([qpos[:, 2:], qvel, self._forces(derived, xp)[:, 6:]], axis=1)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        x_velocity = (derived["xpos"][:, 1, 0] - before[:, 0]) / self.dt
        state = xp.concatenate([qpos, qvel], axis=1)
        healthy = xp.all(xp.isfinite(state), axis=1) & (0.2 <= qpos[:, 2]) & (qpos[:, 2] <= 1.0)
        contact_cost = 5e-4 * xp.sum(xp.square(self._forces(derived, xp)), axis=1)
        reward = (x_velocity + xp.where(healthy, 1.0, 0.0)) - (0.5 * xp.sum(xp.square(action), axis=1) + contact_cost)
        return self.observe(qpos, qvel, derived, xp), reward, ~healthy


V5_TASKS = {t.env_id: t for t in (HopperV5, Walker2dV5, HalfCheetahV5, AntV5, InvertedDoublePendulumV5)}
