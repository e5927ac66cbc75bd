"""allegro_cylinder: the paper's Allegro-hand tactile task (envs/allegro.py; MuJoCo C: envs/allegro_task.py)."""

from typing import TYPE_CHECKING, Any

from envs.families.record import TaskRecord, c_backend, mjx_side, mujoco_side
from envs.physics import Physics

if TYPE_CHECKING:
    import mujoco
    from brax.envs.base import Env


class AllegroRecord(TaskRecord):
    """The Allegro hand holding a cylinder: its own MJX environment and its own MuJoCo C twin."""

    family = "allegro"
    has_c = True

    def episode_length(self) -> int:
        return mujoco_side().allegro.DEFAULT_EPISODE_LENGTH  # 2 s at 100 Hz

    def model(self) -> "mujoco.MjModel":
        return mujoco_side().allegro.load_mj_model()

    def mujoco_c_label(self) -> str:
        return "MuJoCo C (our port)"

    def make_mjx(self) -> "Env":
        return mjx_side().allegro.AllegroCylinder()

    def make_c_backend(self, physics: Physics) -> "Env":
        return c_backend().AllegroCTask(self.name, physics)

    def make_c(self) -> Any:
        return mujoco_side().allegro.AllegroC()

    def observation_layout(self) -> list:
        return mujoco_side().allegro.allegro_layout(self.model())


ENTRIES = {"allegro_cylinder": AllegroRecord}
