"""Pytrees to and from .npz files, written atomically (temp file + rename), so a kill never leaves a torn file.

Checkpoints (keep_previous=True, read_with_fallback) keep the previous version next to the current one
(`state.npz` -> `state.prev.npz`): a file that is unreadable on resume (truncated, garbage) falls back
to the previous one. A full disk raises DiskFullError (no temp file left behind) naming the
directory and the space the write needed.
"""

import errno
import io
import os
import re
import zipfile
from typing import Any, Callable

import numpy as np

from gsa_jax.errors import EXIT_DISK_FULL, UserError


def _flat(tree):
    import jax  # here and in load_pytree, which walk pytrees: the rest loads without JAX (a command's --help)

    leaves, treedef = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): np.asarray(x) for path, x in leaves}, treedef


class DiskFullError(UserError, OSError):
    """A write ran out of space (ENOSPC / EDQUOT); the file it replaces is intact. An OSError, and a UserError with
    exit status 4, so a command that does not name the intact checkpoint (errors.disk_full does) still ends in one line."""

    exit_status = EXIT_DISK_FULL

    def __init__(self, path: str, needed: int) -> None:
        super().__init__(errno.ENOSPC, f"no space left writing {path}")
        self.path, self.needed = path, needed

    def describe(self, last_intact: str) -> str:
        """One line for the user: directory, space needed, last intact checkpoint ('iteration N ...'), what to do."""
        need = max(self.needed, 1) / 2**20
        return (f"disk full: writing {os.path.dirname(os.path.abspath(self.path))} needs about {need:.1f} MiB more "
                f"free space; the last intact checkpoint is {last_intact}; free space and run the same "
                f"command with --resume (sweeps: the same command) to continue")


class CheckpointError(UserError, ValueError):
    """Neither a checkpoint nor its previous version can be read."""


def _write_file(path, data, mode):
    """Write and fsync one file (the single place files are written; tests inject faults here)."""
    with open(path, mode) as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def previous_path(path: str) -> str:
    """state.npz -> state.prev.npz: where a checkpoint keeps the version before the current one."""
    root, ext = os.path.splitext(path)
    return root + ".prev" + ext


def write_atomic(path: str, data: "str | bytes", mode: str = "w", keep_previous: bool = False) -> None:
    """Write text or bytes to a temp file in the same directory, fsync, then rename over `path`
    (keep_previous: first rename the current file to previous_path(path); renames only, so a kill
    at any point leaves an intact current or previous file). A full disk raises DiskFullError; the
    temp file is removed in every case."""
    tmp = path + ".tmp"
    try:
        _write_file(tmp, data, mode)
        if keep_previous and os.path.exists(path):
            os.replace(path, previous_path(path))
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT) and not isinstance(e, DiskFullError):
            raise DiskFullError(path, len(data)) from None
        raise


UNREADABLE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)


def read_with_fallback(path: str, read: Callable, log: Callable = print) -> tuple:
    """read(p) of `path`, or of its previous version if `path` is missing or unreadable (one line says
    which and why). Returns (value, path read). Raises CheckpointError if neither can be read."""
    prev = previous_path(path)
    errors = []
    for p in (path, prev):
        if not os.path.exists(p):
            errors.append(f"{os.path.basename(p)} is missing")
            continue
        try:
            value = read(p)
        except UNREADABLE as e:
            errors.append(f"{os.path.basename(p)} is unreadable ({type(e).__name__}: {str(e)[:80]})")
            continue
        if p == prev:
            log(f"warning: {errors[0]}; resuming from the previous checkpoint {p}")
        return value, p
    raise CheckpointError(f"cannot resume from {os.path.dirname(os.path.abspath(path))}: " + "; ".join(errors)
                          + "; delete the directory to start over")


def npz_bytes(**arrays: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def save_npz_atomic(path: str, keep_previous: bool = False, **arrays: np.ndarray) -> None:
    write_atomic(path, npz_bytes(**arrays), "wb", keep_previous)


def save_pytree(path: str, tree: Any, keep_previous: bool = False, **extra: np.ndarray) -> None:
    """Save every leaf under its key path (e.g. "['policy']['L']"); extra arrays are stored as given.
    keep_previous: keep the file it replaces as previous_path(path) (checkpoints)."""
    arrays, _ = _flat(tree)
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    save_npz_atomic(path, keep_previous, **arrays)


def dict_spelling(key: str) -> str:
    """A NamedTuple field's key path ".name[...]" spelled as a dict's: "['name'][...]"."""
    m = re.match(r"\.(\w+)(.*)", key)
    return f"['{m.group(1)}']{m.group(2)}" if m else key


def load_pytree(path: str, like: Any) -> Any:
    """Load arrays saved by save_pytree into the structure of `like` (shapes and dtypes must match)."""
    import jax

    with np.load(path) as data:
        leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
        out = []
        for p, ref in leaves:
            key = jax.tree_util.keystr(p)
            if key not in data:  # a checkpoint written when the state was a dict of the same fields
                key = dict_spelling(key)
            if key not in data:
                raise KeyError(f"{path}: missing array {jax.tree_util.keystr(p)}")
            arr = data[key]
            if arr.shape != np.shape(ref):
                raise ValueError(f"{path}: {key} has shape {arr.shape}, expected {np.shape(ref)}")
            out.append(arr.astype(np.asarray(ref).dtype))
    return jax.tree_util.tree_unflatten(treedef, out)
