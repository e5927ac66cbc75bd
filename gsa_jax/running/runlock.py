"""One writer per output directory: a lock file naming the owner's pid and host.

    with hold(out, "sweep fig1"):   # raises LockError if a live process holds `out`
        ...

A lock whose owner is gone (same host, pid not running: a kill -9) is taken over with a note; a lock
held on another host cannot be checked from here and is refused with what to do.
"""

import json
import os
import socket
import time
from contextlib import contextmanager
from typing import Callable, Iterator

from gsa_jax.errors import UserError

LOCK_NAME = "LOCK"


class LockError(UserError, RuntimeError):
    pass


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def acquire(directory: str, what: str, log: Callable = print) -> str:
    """Create directory/LOCK for this process, or raise LockError naming the holder."""
    path = os.path.join(directory, LOCK_NAME)
    me = {"pid": os.getpid(), "host": socket.gethostname(), "what": what, "since": time.strftime("%Y-%m-%d %H:%M:%S")}
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = _read(path)
            if owner and owner.get("host") == me["host"] and not _alive(int(owner.get("pid", -1))):
                log(f"note: taking over {path} from pid {owner.get('pid')} ({owner.get('what')}), which is no longer running")
                os.unlink(path)
                continue
            who = (f"pid {owner.get('pid')} on host {owner.get('host')} ({owner.get('what')}, since {owner.get('since')})"
                   if owner else "another process")
            raise LockError(f"{directory} is in use by {who}; wait for it, use another output directory, or delete "
                            f"{path} if that process is gone") from None
        with os.fdopen(fd, "w") as f:
            json.dump(me, f)
        return path
    raise LockError(f"could not lock {directory}")


def release(path: str) -> None:
    owner = _read(path)
    if owner and owner.get("pid") == os.getpid() and os.path.exists(path):
        os.unlink(path)


@contextmanager
def hold(directory: str, what: str, log: Callable = print) -> Iterator[str]:
    path = acquire(directory, what, log)
    try:
        yield path
    finally:
        release(path)
