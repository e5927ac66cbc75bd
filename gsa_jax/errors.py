"""The user-error base class (envs/errors.py, below both packages: envs/ imports nothing of gsa_jax/), the exit
status of a full disk, and how a process reports them: a command, or a worker process of one, prints a UserError as
one line and exits with its status (run_command)."""

import sys
from typing import Callable

from envs.errors import UserError

EXIT_DISK_FULL = 4  # a command's exit status where a write ran out of space (running/checkpoint.py's DiskFullError)

__all__ = ["EXIT_DISK_FULL", "UserError", "disk_full", "run_command"]


def disk_full(e: OSError, intact: str) -> UserError:
    """A full disk (running/checkpoint.py's DiskFullError) as a command's one-line error with exit status 4, naming
    the checkpoint left intact."""
    return UserError(e.describe(intact), exit_status=EXIT_DISK_FULL)


def run_command(name: str, body: Callable[[], int]) -> int:
    """Run a command's body and return its exit status: a UserError is one line on stderr and its status, an
    interrupt 130."""
    try:
        return body()
    except UserError as e:
        print(f"gsa {name}: error: {e}", file=sys.stderr)
        return e.exit_status
    except KeyboardInterrupt:
        print(f"gsa {name}: interrupted", file=sys.stderr)
        return 130

