"""Brax's MJX variants of the gym locomotion tasks (Brax's registry, backend 'mjx'); MuJoCo C ports of all but
inverted_double_pendulum in envs/brax_ports.py."""

from typing import TYPE_CHECKING, Any, Optional

from envs.families.record import TaskRecord, c_backend, mujoco_side, quiet_brax
from envs.names import BRAX_TASKS
from envs.physics import Physics

if TYPE_CHECKING:
    import mujoco
    from brax.envs.base import Env

    from envs.task import Task


class BraxVariant(TaskRecord):
    """One of Brax's MJX variants; where it has a MuJoCo C port (a task definition), MuJoCo C steps that."""

    family = "brax"
    _port = None

    @property
    def has_c(self) -> bool:
        return self.name in mujoco_side().ports.BRAX_PORTS

    def port(self) -> "Task":
        """A new instance of the task's MuJoCo C port, a task definition (envs/brax_ports.py's BRAX_PORTS)."""
        task = mujoco_side().ports.BRAX_PORTS[self.name]()
        task.name = self.name
        return task

    def model(self) -> "mujoco.MjModel":
        if self.has_c:
            if self._port is None:  # read only (sizes, records): one per record
                self._port = self.port()
            return self._port.model
        return mujoco_side().ports.brax_model(self.name)

    def c_definition(self) -> "Optional[Task]":
        return self.port() if self.has_c else None

    def mujoco_c_label(self) -> str:
        return "MuJoCo C (our port)"

    def make_mjx(self) -> "Env":
        return quiet_brax().get_environment(self.name, backend="mjx")

    def make_c_backend(self, physics: Physics) -> "Env":
        if not self.has_c:
            return super().make_c_backend(physics)
        return c_backend().TaskCEnv(self.name, physics, self.port())

    def make_c(self) -> Any:
        if not self.has_c:
            return super().make_c()
        return mujoco_side().task.TaskC(self.port())

    def observation_layout(self) -> list:
        return self.port().observation_layout() if self.has_c else list(mujoco_side().ports.IDP_LAYOUT)


ENTRIES = {name: BraxVariant for name in BRAX_TASKS}
