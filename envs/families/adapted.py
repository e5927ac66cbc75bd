"""What the families of another library's environments share (Adapted): MJX only, the MjModel read from the built
environment, the library's version in the results."""

from importlib import metadata
from typing import TYPE_CHECKING, Any, Optional

from envs.families.record import TaskRecord
from envs.physics import Physics, mj_model

if TYPE_CHECKING:
    import mujoco
    from brax.envs.base import Env


class Adapted(TaskRecord):
    """Another library's environment, '<library>:<their name>' (MJX only): its MjModel is read from the built
    environment (seconds), so once per record."""

    builtin = False
    library = ""
    version_of = ""  # the distribution whose version the results record

    def __init__(self, name: str):
        super().__init__(name)
        self.theirs = name.partition(":")[2]
        self._model = None

    def model(self) -> "mujoco.MjModel":
        if self._model is None:
            self._model = mj_model(self.mjx_env())  # as envs.make_base(self) builds it (the default physics)
        return self._model

    def observation_layout(self) -> list:
        return [f"obs[{i}]" for i in range(int(self.make_mjx().observation_size))]

    def source(self) -> dict:
        return {"task": self.name, "builtin": False, "library": self.library, "name": self.theirs,
                "action_size": int(self.model().nu), "version": installed_version(self.version_of)}

    def make_c_backend(self, physics: Physics) -> "Env":
        raise ValueError(f"physics backend 'c' does not step {self.name!r}: another library's environments step "
                         "in JAX only; use backend 'mjx'")

    def make_c(self) -> Any:
        raise ValueError(f"no MuJoCo C version of {self.name!r}: another library's environments step in JAX only "
                         "(gsa_jax.deploy --compare-mjx RUN_DIR runs its controller in MJX)")


def installed_version(dist: str) -> Optional[str]:
    """The installed version of distribution `dist`, or None."""
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None
