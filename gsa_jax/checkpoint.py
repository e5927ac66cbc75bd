"""Pytrees to and from .npz files, written atomically (temp file + rename), so a kill never leaves a torn file."""

import io
import os

import jax
import numpy as np


def _flat(tree):
    leaves, treedef = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): np.asarray(x) for path, x in leaves}, treedef


def write_atomic(path, data, mode="w"):
    """Write text or bytes to a temp file in the same directory, fsync, then rename over `path`."""
    tmp = path + ".tmp"
    try:
        with open(tmp, mode) as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_npz_atomic(path, **arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, buf.getvalue(), "wb")


def save_pytree(path, tree, **extra):
    """Save every leaf under its key path (e.g. "['policy']['L']"); extra arrays are stored as given."""
    arrays, _ = _flat(tree)
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    save_npz_atomic(path, **arrays)


def load_pytree(path, like):
    """Load arrays saved by save_pytree into the structure of `like` (shapes and dtypes must match)."""
    with np.load(path) as data:
        leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
        out = []
        for p, ref in leaves:
            key = jax.tree_util.keystr(p)
            if key not in data:
                raise KeyError(f"{path}: missing array {key}")
            arr = data[key]
            if arr.shape != np.shape(ref):
                raise ValueError(f"{path}: {key} has shape {arr.shape}, expected {np.shape(ref)}")
            out.append(arr.astype(np.asarray(ref).dtype))
    return jax.tree_util.tree_unflatten(treedef, out)
