"""The user-error base class (envs/errors.py, below both packages: envs/ imports nothing of gsa_jax/) and the exit
status of a full disk. `gsa` prints a UserError as one line and exits with its status (gsa_jax.cli.run_command)."""

from envs.errors import UserError

EXIT_DISK_FULL = 4  # a command's exit status where a write ran out of space (running/checkpoint.py's DiskFullError)

__all__ = ["EXIT_DISK_FULL", "UserError"]
