"""'brax:<name>': any environment of Brax's registry, on MJX."""

import difflib
from typing import TYPE_CHECKING

from envs.families.adapted import Adapted
from envs.families.record import quiet_brax

if TYPE_CHECKING:
    from brax.envs.base import Env


class BraxAdapted(Adapted):
    """One environment of Brax's registry, made with backend 'mjx'."""

    family, library, version_of = "brax_adapter", "brax", "brax"

    def check(self) -> None:
        known = sorted(quiet_brax()._envs)
        if self.theirs not in known:
            close = difflib.get_close_matches(self.theirs, known, n=3)
            raise ValueError(f"unknown env {self.name!r}: Brax registers {', '.join(known)}"
                             + (f"; did you mean {', '.join('brax:' + c for c in close)}?" if close else ""))

    def make_mjx(self) -> "Env":
        return quiet_brax().get_environment(self.theirs, backend="mjx")


PREFIX = "brax:"
