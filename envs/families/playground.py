"""'playground:<Name>': any environment of MuJoCo Playground's registry, on MJX (envs/playground_adapter.py)."""

from typing import TYPE_CHECKING

from envs.families.adapted import Adapted
from envs.families.record import playground
from envs.names import DEFAULT_EPISODE_LENGTH
from envs.physics import Physics

if TYPE_CHECKING:
    from brax.envs.base import Env


class PlaygroundAdapted(Adapted):
    """One environment of MuJoCo Playground's registry, with Playground's own solver settings and randomizer."""

    family, library, version_of = "playground", "playground", "playground"
    mjx_variants = False  # not a Brax PipelineEnv

    def check(self) -> None:
        playground().check_name(self.name)

    def episode_length(self) -> int:
        config = playground().registry().get_default_config(self.theirs)
        return int(config.get("episode_length", DEFAULT_EPISODE_LENGTH))

    def check_physics(self, physics: Physics) -> None:
        super().check_physics(physics)
        if physics.solver_iterations is not None or physics.ls_iterations is not None:
            raise ValueError(f"{self.name!r} runs with Playground's own solver settings; solver_iterations and "
                             "ls_iterations do not apply")

    def make_mjx(self) -> "Env":
        return playground().PlaygroundEnv(self.name)

    def check_randomizer(self) -> None:
        """ValueError (one line) unless Playground's registry has a domain randomizer for this environment."""
        playground().domain_randomizer(self.name)


PREFIX = "playground:"
