"""dm_control's cartpole (suite/cartpole.py): balance and swingup, one pole, 1000 steps of 0.01 s (RK4).

Observation: position [cart x, pole xmat zz, pole xmat xz] (3), velocity qvel (2). Reward (smooth): the pole's
upright cosine mapped to [0, 1] x small control x small angular velocity x centred cart."""

import types

import numpy as np

from envs.dmc.base import XMAT, DmcTask, tolerance


class Cartpole(DmcTask):
    domain, time_limit = "cartpole", 10.0
    derived = ("xmat",)
    observation_keys = (("position", 3), ("velocity", 2))
    qvel_noise, vel_noise = "normal", 0.01  # qvel = 0.01 * N(0, 1)
    push_body = "cart"
    equilibrium_qpos = (0.0, 0.0)  # cart centred, pole upright

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        pole = derived["xmat"][:, 2]
        return xp.concatenate([qpos[:, :1], pole[:, XMAT["zz"], None], pole[:, XMAT["xz"], None], qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        upright = (derived["xmat"][:, 2, XMAT["zz"]] + 1) / 2
        centered = (1 + tolerance(qpos[:, 0], margin=2, xp=xp)) / 2
        small_control = (4 + tolerance(action[:, 0], margin=1, value_at_margin=0, sigmoid="quadratic", xp=xp)) / 5
        small_velocity = (1 + tolerance(qvel[:, 1], margin=5, xp=xp)) / 2
        return upright * small_control * small_velocity * centered


class Balance(Cartpole):
    """cartpole-balance: the cart uniform in [-0.1, 0.1], the pole within 0.034 rad of upright."""

    init_qpos, noise = (0.0, 0.0), (0.1, 0.034)


class Swingup(Cartpole):
    """cartpole-swingup: the pole hanging down, cart and pole 0.01 * N(0, 1) away."""

    init_qpos, noise, qpos_noise = (0.0, np.pi), 0.01, "normal"
