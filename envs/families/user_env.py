"""A user's environment class of another library, named 'module:Class' or registered: a `brax.envs.Env` subclass or
a MuJoCo Playground `MjxEnv` subclass (MJX only)."""

import contextlib
import inspect
import io
from typing import TYPE_CHECKING, Any, Optional

from envs.families.adapted import Adapted
from envs.families.record import mujoco_side, playground
from envs.names import DEFAULT_EPISODE_LENGTH

if TYPE_CHECKING:
    from brax.envs.base import Env


class UserEnv(Adapted):
    """A `brax.envs.Env` subclass (made as Brax's registry makes its own, with backend='mjx' where the class takes a
    backend) or a Playground `MjxEnv` subclass (made with impl 'jax'); built once when checked."""

    family = "user_env"
    mjx_variants = False  # not a Brax PipelineEnv

    def __init__(self, name: str, cls: type, library: str):
        super().__init__(name)
        self.cls, self.library, self.version_of = cls, library, library
        self.theirs = f"{cls.__module__}.{cls.__qualname__}"
        self._length = None

    def check(self) -> None:
        self.model()

    def episode_length(self) -> int:
        if self.library != "playground":
            return DEFAULT_EPISODE_LENGTH
        if self._length is None:  # building the env takes seconds: once per record
            self._length = int(self.make_mjx().episode_length)
        return self._length

    def make_mjx(self) -> "Env":
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                if self.library == "playground":
                    return playground().PlaygroundEnv(self.name, make_playground(self.cls))
                env = make_brax(self.cls)
        except Exception as e:  # the user's constructor, or the library's: one line naming the task
            raise ValueError(f"task {self.name!r}: making it failed: {type(e).__name__}: "
                             f"{' '.join(str(e).split())[:200]}") from None
        on_mjx = hasattr(env, "mj_model") or hasattr(getattr(env, "sys", None), "mj_model")
        if getattr(env, "backend", "mjx") != "mjx" or not on_mjx:
            raise ValueError(f"task {self.name!r}: a Brax environment here steps on MJX (a PipelineEnv with backend "
                             f"'mjx'); {self.theirs} has backend {getattr(env, 'backend', None)!r}")
        return env

    def source(self) -> dict:
        return {**super().source(), **mujoco_side().task.source_record(self.cls)}


def make_brax(cls: type) -> Any:
    """A brax.envs.Env subclass made as Brax's registry makes one: backend='mjx' where its constructor takes one."""
    takes = inspect.signature(cls.__init__).parameters
    if "backend" in takes or any(p.kind is p.VAR_KEYWORD for p in takes.values()):
        return cls(backend="mjx")
    return cls()


def make_playground(cls: type) -> Any:
    """A Playground MjxEnv subclass made as its registry makes one, with impl 'jax' (MJX) where its constructor
    takes config_overrides."""
    if "config_overrides" in inspect.signature(cls.__init__).parameters:
        return cls(config_overrides={"impl": "jax"})
    return cls()


def library_of(obj: Any) -> Optional[str]:
    """'brax' for a brax.envs.Env subclass, 'playground' for a MuJoCo Playground MjxEnv subclass, else None (read
    from the class's bases, so nothing is imported)."""
    if not isinstance(obj, type):
        return None
    bases = {(c.__module__, c.__name__) for c in obj.__mro__}
    if ("brax.envs.base", "Env") in bases:
        return "brax"
    if ("mujoco_playground._src.mjx_env", "MjxEnv") in bases:
        return "playground"
    return None
