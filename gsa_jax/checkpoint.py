"""Pytrees to and from .npz files, written atomically (temp file + rename), so a kill never leaves a torn file."""

import os
import tempfile

import jax
import numpy as np


def _flat(tree):
    leaves, treedef = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): np.asarray(x) for path, x in leaves}, treedef


def save_pytree(path, tree, **extra):
    """Save every leaf under its key path (e.g. "['policy']['L']"); extra arrays are stored as given."""
    arrays, _ = _flat(tree)
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
