"""MuJoCo C ports of Brax's MJX locomotion tasks (hopper, walker2d, halfcheetah, ant: their defaults on backend
'mjx') as task definitions (envs/task.py): the same MJCF and solver options, reset noise, observation, reward
and termination, so both backends and plain MuJoCo C step them as they step every task definition. Brax's records
(envs/families/brax_variant.py) read BRAX_PORTS; tests/test_mujoco_c.py checks the ports step for step against the
MJX environments. Nothing here imports JAX (brax's MJCFs are found without importing brax).
"""

import importlib.util
import os

import mujoco
import numpy as np

from envs.task import Task, coordinate_names


def brax_asset(name):
    """Path of an MJCF shipped with brax, found without importing brax (which imports JAX)."""
    spec = importlib.util.find_spec("brax")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the brax package is not installed")
    return os.path.join(spec.submodule_search_locations[0], "envs", "assets", name)


class BraxTask(Task):
    """A Brax locomotion task (its defaults, backend 'mjx') as a task definition (envs/task.py): the same MJCF and
    solver options, reset noise, observation, reward and termination, so both backends and plain MuJoCo C step it
    as they step every task definition. Subclasses set the task's constants and `observe_state` /
    `healthy_state`, written over (qpos [..., nq], qvel [..., nv], torso position [..., 3]) for NumPy and
    jax.numpy alike, batched or not; `observation(m, d)` reads them from one MjData, so they also apply to another
    simulator's model of the same robot (gsa_jax.deployment.gymnasium_rollout checks layouts with them).

    The torso is body 1 (Brax's x.pos[0]), read as mj_step leaves it (before the step's last substep, as MJX
    holds it); the forward reward is its x velocity over the env step."""

    asset = ""
    options = {}  # MjOption overrides that Brax applies for backend 'mjx'
    ctrl_cost = 0.0
    healthy_reward = 0.0
    derived = ("xpos",)

    def load_model(self):
        model = mujoco.MjModel.from_xml_path(brax_asset(self.asset))
        for k, v in self.options.items():
            setattr(model.opt, k, v)
        return model

    @staticmethod
    def observe_state(qpos, qvel, torso, xp=np):
        """Observation [..., d] from qpos, qvel and the torso's position (Brax's x.pos[0])."""
        raise NotImplementedError

    @staticmethod
    def healthy_state(qpos, qvel, torso, xp=np):
        """Whether the episode goes on [...] (bool), from the same arrays as observe_state."""
        return xp.ones(torso.shape[:-1], bool)

    def before(self, qpos, derived, xp=np):
        """[n, 1] the torso's x position before a step."""
        return derived["xpos"][:, 1, :1] + 0.0

    def observe(self, qpos, qvel, derived, xp=np):
        return self.observe_state(qpos, qvel, derived["xpos"][:, 1], xp)

    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        """Forward velocity of the torso over the env step + healthy reward - control cost; done when unhealthy."""
        torso = derived["xpos"][:, 1]
        reward = (torso[:, 0] - before[:, 0]) / self.dt + self.healthy_reward - self.ctrl_cost * xp.sum(action * action, axis=1)
        return self.observe(qpos, qvel, derived, xp), reward, ~self.healthy_state(qpos, qvel, torso, xp)

    def observation(self, m, d):
        """[d] float32: the observation of one MjData (of this model or another simulator's of the same robot)."""
        return self.observe_state(d.qpos, d.qvel, d.xpos[1], np).astype(np.float32)

    # the observation layout: `first` entries, the positions of qpos[pos_from:], then every velocity
    first, pos_from, vel_label = (), 2, "{} velocity"

    def observation_layout(self):
        qpos, qvel = coordinate_names(self.model)
        return list(self.first) + [f"{p} position" for p in qpos[self.pos_from:]] + [self.vel_label.format(v) for v in qvel]


class HopperC(BraxTask):
    """Brax's `hopper`: 4 substeps of 2 ms; healthy while z > 0.7, |angle| < 0.2, |qpos[2:], qvel| < 100;
    reward = forward velocity + 1 - 1e-3 |a|^2; observation [torso z, qpos[2:], clip(qvel, -10, 10)];
    reset noise U(-5e-3, 5e-3) on qpos and qvel."""

    planar = True

    asset, frame_skip, noise, ctrl_cost, healthy_reward = "hopper.xml", 4, 5e-3, 1e-3, 1.0
    first, vel_label = ("torso height",), "{} velocity (clipped to +-10)"

    @staticmethod
    def observe_state(qpos, qvel, torso, xp=np):
        # qpos[1] replaced by the torso height (Brax: x.pos[0, 2])
        return xp.concatenate([torso[..., 2:3], qpos[..., 2:], xp.clip(qvel, -10.0, 10.0)], axis=-1)

    @staticmethod
    def healthy_state(qpos, qvel, torso, xp=np):
        z, angle = torso[..., 2], qpos[..., 2]
        state = xp.concatenate([qpos[..., 2:], qvel], axis=-1)
        return xp.all(xp.abs(state) < 100.0, axis=-1) & (z > 0.7) & (angle > -0.2) & (angle < 0.2)


class Walker2dC(HopperC):
    """Brax's `walker2d`: 4 substeps of 2 ms; healthy while 0.8 < z < 2 and -1 < angle < 1; reward =
    forward velocity + 1 - 1e-3 |a|^2; observation as hopper's; reset noise U(-5e-3, 5e-3)."""

    asset = "walker2d.xml"

    @staticmethod
    def healthy_state(qpos, qvel, torso, xp=np):
        z, angle = torso[..., 2], qpos[..., 2]
        return (z > 0.8) & (z < 2.0) & (angle > -1.0) & (angle < 1.0)


class HalfCheetahC(BraxTask):
    """Brax's `halfcheetah`: 5 substeps of 10 ms; no termination; reward = forward velocity - 0.1 |a|^2;
    observation [qpos[1:], qvel]; reset noise U(-0.1, 0.1) on qpos, 0.1 N(0, 1) on qvel."""

    planar = True

    asset, frame_skip, noise, qvel_noise, ctrl_cost = "half_cheetah.xml", 5, 0.1, "normal", 0.1
    pos_from = 1

    @staticmethod
    def observe_state(qpos, qvel, torso, xp=np):
        return xp.concatenate([qpos[..., 1:], qvel], axis=-1)


class AntC(BraxTask):
    """Brax's `ant` on MJX: 5 substeps of 10 ms with Brax's MJX solver options (Newton, 1 iteration,
    4 line-search iterations, Euler damping off); healthy while 0.2 <= torso z <= 1; reward = forward
    velocity + 1 - 0.5 |a|^2 (no contact cost); observation [qpos[2:], qvel]; reset noise U(-0.1, 0.1)
    on qpos, 0.1 N(0, 1) on qvel."""

    asset, frame_skip, noise, qvel_noise, ctrl_cost, healthy_reward = "ant.xml", 5, 0.1, "normal", 0.5, 1.0
    options = {"solver": int(mujoco.mjtSolver.mjSOL_NEWTON), "disableflags": int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP),
               "iterations": 1, "ls_iterations": 4}

    @staticmethod
    def observe_state(qpos, qvel, torso, xp=np):
        return xp.concatenate([qpos[..., 2:], qvel], axis=-1)

    @staticmethod
    def healthy_state(qpos, qvel, torso, xp=np):
        return (torso[..., 2] >= 0.2) & (torso[..., 2] <= 1.0)


BRAX_PORTS = {"hopper": HopperC, "walker2d": Walker2dC, "halfcheetah": HalfCheetahC, "ant": AntC}  # task definitions


def brax_model(name):
    """The MjModel of brax's MJCF `name` (e.g. 'inverted_double_pendulum') as the file says it (no port's options)."""
    return mujoco.MjModel.from_xml_path(brax_asset(name + ".xml"))


IDP_LAYOUT = ["cart x", "sin(hinge)", "sin(hinge2)", "cos(hinge)", "cos(hinge2)",
              "cart velocity (clipped to +-10)", "hinge velocity (clipped)", "hinge2 velocity (clipped)"]
