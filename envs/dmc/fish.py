"""dm_control's fish (suite/fish.py): swim; 1000 steps of 0.04 s (10 physics steps of 0.004 s).

No gravity, no constraints (collisions and limits are off): the fish moves by the fluid's forces (density 5000) on
its bodies. At reset the root's orientation is a normalized N(0, I) quaternion (its position stays qpos0), the seven
tail and fin joints U(-0.2, 0.2) each, and the target is drawn (x, y ~ U(-0.4, 0.4), z ~ U(0.1, 0.3)); dm_control
writes it into the model (geom_pos of the world's 'target' geom, which no physics reads: a world geom, with
constraints off), here it is the task's goal [x, y, z], carried in the state (the world geom's geom_xpos is its
geom_pos exactly, so the goal stands for data.geom_xpos['target']).

Observation: joint_angles (7), upright (torso xmat zz, 1), target (mouth to target in the mouth geom's frame:
(target - geom_xpos[mouth]) . geom_xmat[mouth], 3), velocity (qvel, 13). Reward: (7 in_target + upright') / 8 with
in_target = tolerance(|mouth to target|, (0, r), margin 2 r), r = the mouth's and the target's radii, and
upright' = (1 + torso zz) / 2."""

import types

import mujoco
import numpy as np

from envs.dmc.base import XMAT, DmcTask, tolerance

JOINTS = ("tail1", "tail_twist", "tail2", "finright_roll", "finright_pitch", "finleft_roll", "finleft_pitch")


class Swim(DmcTask):
    domain, control_timestep, time_limit = "fish", 0.04, 40.0
    derived = ("xmat", "geom_xpos", "geom_xmat")
    observation_keys = (("joint_angles", 7), ("upright", 1), ("target", 3), ("velocity", 13))
    goal_size = 3
    push_body = "torso"

    def __init__(self):
        super().__init__()
        self.joint_qpos = np.array([self.model.jnt_qposadr[self.id("joint", j)] for j in JOINTS])
        self.root_quat = int(self.model.jnt_qposadr[self.id("joint", "root")]) + 3

    def initialize(self, data: mujoco.MjData, rng: np.random.Generator) -> "np.ndarray | None":
        quat = rng.standard_normal(4)
        data.qpos[self.root_quat: self.root_quat + 4] = quat / np.linalg.norm(quat)
        for adr in self.joint_qpos:
            data.qpos[adr] = rng.uniform(-0.2, 0.2)
        return np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(0.1, 0.3)])

    def upright(self, derived: dict) -> np.ndarray:
        return derived["xmat"][:, self.id("body", "torso"), XMAT["zz"]]

    def mouth_to_target(self, derived: dict, xp: types.ModuleType) -> np.ndarray:
        """[n, 3] (target - mouth) in the mouth geom's frame: dm_control's vector . geom_xmat (row vector times R)."""
        mouth = self.id("geom", "mouth")
        d = derived["goal"] - derived["geom_xpos"][:, mouth]
        r = derived["geom_xmat"][:, mouth].reshape(-1, 3, 3)
        return xp.stack([d[:, 0] * r[:, 0, j] + d[:, 1] * r[:, 1, j] + d[:, 2] * r[:, 2, j] for j in range(3)], axis=1)

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, xp: types.ModuleType = np) -> np.ndarray:
        return xp.concatenate([qpos[:, self.joint_qpos], self.upright(derived)[:, None],
                               self.mouth_to_target(derived, xp), qvel], axis=1)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, derived: dict, action: np.ndarray,
               xp: types.ModuleType = np) -> np.ndarray:
        radii = float(self.model.geom_size[[self.id("geom", "mouth"), self.id("geom", "target")], 0].sum())
        distance = xp.linalg.norm(self.mouth_to_target(derived, xp), axis=-1)
        in_target = tolerance(distance, bounds=(0, radii), margin=2 * radii, xp=xp)
        is_upright = 0.5 * (self.upright(derived) + 1)
        return (7 * in_target + is_upright) / 8
