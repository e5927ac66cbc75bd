"""A run's deterministic controller as arrays (npz), one ONNX graph or a C99 header; `gsa export` is its
command."""

import json
import os
import zipfile
from typing import TYPE_CHECKING, Mapping

import numpy as np

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment.export_c import cost, to_source
from gsa_jax.deployment.numpy_policy import SINGLE, action_bounds, controller_task, map_actions, task_name
from gsa_jax.errors import UserError
from gsa_jax.running.checkpoint import save_npz_atomic
from gsa_jax.running.formats import FormatError, read_controller, stamped_arrays
from gsa_jax.running.trained import RunNotFound, read_run

if TYPE_CHECKING:
    from envs.families.record import TaskRecord


class ExportError(UserError):
    pass


def with_bounds(arrays: Mapping, source: str) -> dict:
    """The controller arrays with action_low / action_high [d_a] (numpy_policy.action_bounds: the stored ones, else
    the named task's), in the task's own action space (in_task_action_space) and with what it was trained on
    (identity_arrays); ExportError where there are no bounds."""
    bounds = action_bounds(arrays)
    if bounds is None:
        raise ExportError(f"{source!r} names no known task ({task_name(arrays)!r}), so no action bounds to export")
    if "action_space" not in arrays:
        arrays = {**arrays, "action_low": bounds[0], "action_high": bounds[1]}
        arrays = in_task_action_space({**arrays, **control_range_arrays(known_task(arrays))})
    return {**arrays, **identity_arrays(arrays)}


def in_task_action_space(arrays: dict) -> dict:
    """Where the task maps its actions in [-1, 1] onto its actuators' ctrlrange [ctrl_low, ctrl_high] (dm_control's
    quadruped), the controller with that map applied (numpy_policy.map_actions): its actions are the controls, in the
    task's own action space (dm_control's action_spec), marked action_space 'controls'; else unchanged."""
    if "ctrl_low" not in arrays:
        return arrays
    low, high = np.asarray(arrays["ctrl_low"], np.float64), np.asarray(arrays["ctrl_high"], np.float64)
    half = 0.5 * (high - low)
    return {**map_actions(arrays, half, low + half, low, high), "action_space": np.array("controls")}


def identity_arrays(arrays: Mapping) -> dict:
    """{task, obs_size, task_sha256}: what the controller was trained on (numpy_policy.check_task compares them with
    the task as it is); task_sha256 as stored (a run's: its config.json's), else '' (a built-in task, or a file
    exported before it was stored)."""
    return {"task": np.array(task_name(arrays) or ""), "obs_size": np.array(int(np.shape(arrays["obs_mean"])[0])),
            "task_sha256": np.array(str(arrays["task_sha256"]))}


def known_task(arrays: Mapping) -> "TaskRecord | None":
    """The record of the task a controller's arrays name (numpy_policy.controller_task), None where they name none or
    it does not resolve here."""
    try:
        return controller_task(arrays)
    except (ValueError, ImportError):
        return None


def control_range_arrays(task: "TaskRecord | None") -> dict:
    """{ctrl_low, ctrl_high} where the task (its record) maps actions onto its actuators' ctrlrange
    (TaskRecord.control_range), else {}."""
    ranges = None if task is None else task.control_range()
    return {} if ranges is None else {"ctrl_low": ranges[0], "ctrl_high": ranges[1]}


def controller_arrays(address: str) -> dict:
    """The controller arrays (see numpy_policy) of a trained run: a run directory or SWEEP_DIR/<run label>
    (gsa_jax.running.trained), with its task's action bounds."""
    try:
        run = read_run(address)
    except (RunNotFound, FormatError) as e:
        raise ExportError(str(e)) from None
    meta, arrays = run.meta, run.params
    kind = meta["config"]["policy"]
    prefix = "['params']['policy']"
    net = "partition" if kind == MIXTURE else "mlp"
    n_layers = 0
    while f"{prefix}['{net}'][{n_layers}]['w']" in arrays:
        n_layers += 1
    out = {
        "kind": np.array(kind),
        "obs_mean": arrays["['obs_stats']['mean']"],
        "obs_var": arrays["['obs_stats']['var']"],
        "obs_clip": np.array(10.0, np.float32),
        "n_layers": np.array(n_layers),
        "config_json": np.array(json.dumps({k: meta[k] for k in ("config", "hparams", "seed", "git_commit") if k in meta})),
    }
    if not meta["config"].get("normalize_obs", True):
        out["obs_mean"] = np.zeros_like(out["obs_mean"])
        out["obs_var"] = np.ones_like(out["obs_var"]) - 1e-8
        out["obs_clip"] = np.array(np.inf, np.float32)
    for i in range(n_layers):
        out[f"w{i}"] = arrays[f"{prefix}['{net}'][{i}]['w']"]
        out[f"b{i}"] = arrays[f"{prefix}['{net}'][{i}]['b']"]
    if kind == MIXTURE:
        out["subpolicy"] = np.array(meta["config"].get("subpolicy", subpolicies.DEFAULT))
        out["partition"] = np.array(meta["config"].get("partition", partitions.DEFAULT))
        k = int(meta["hparams"]["K"])
        out["L"] = arrays[f"{prefix}['L']"][:k]
        out["b"] = arrays[f"{prefix}['b']"][:k]
        out = active_partition(out)
    out["task_sha256"] = np.array((meta.get("task") or {}).get("sha256") or "")
    return with_bounds(out, address)


def active_partition(arrays: dict) -> dict:
    """A mixture's arrays with the partition network's last layer cut to its K clusters' logits (training pads it to
    K_max; numpy_policy reads a padded file's first K); for K = 1, with no network at all (single_piece)."""
    if int(np.shape(arrays["L"])[0]) == 1:
        return single_piece(arrays)
    last, k = int(arrays["n_layers"]) - 1, int(np.shape(arrays["L"])[0])
    return {**arrays, f"w{last}": np.asarray(arrays[f"w{last}"])[:, :k], f"b{last}": np.asarray(arrays[f"b{last}"])[:k]}


def single_piece(arrays: dict) -> dict:
    """A K = 1 mixture's arrays without its partition network (it picks the one piece everywhere): n_layers 0, no
    w{i} / b{i}, partition 'single' (numpy_policy.SINGLE); the same actions, one affine (or quadratic) law."""
    n = int(arrays["n_layers"])
    layers = {f"{w}{i}" for i in range(n) for w in "wb"}
    return {**{key: v for key, v in arrays.items() if key not in layers}, "n_layers": np.array(0),
            "partition": np.array(SINGLE)}


SUFFIXES = {"npz": ".npz", "onnx": ".onnx", "c": ".h"}


def load_arrays(source: str) -> dict:
    """Controller arrays of a trained run (a run directory or SWEEP_DIR/<run label>) or of an exported
    controller .npz, with action bounds (a file exported before they were stored: its task's), what it was trained on
    (identity_arrays) and a mixture's partition cut to its K clusters (active_partition)."""
    if os.path.isfile(source) and source.endswith(".npz"):
        if not zipfile.is_zipfile(source):
            raise ExportError(f"{source!r} is not an exported controller (not an .npz archive)")
        try:
            arrays = read_controller(source)  # an older file in the current layout (running.formats)
        except (OSError, ValueError) as e:
            raise ExportError(f"{source!r} is not an exported controller ({e})") from None
        if "kind" not in arrays or "obs_mean" not in arrays:
            raise ExportError(f"{source!r} is not an exported controller (no 'kind' / 'obs_mean' arrays)")
        return with_bounds(active_partition(arrays) if str(arrays["kind"]) == MIXTURE else arrays, source)
    return controller_arrays(source)


def task_layout(arrays: Mapping) -> list | None:
    """The task's observation layout (names), or None for an unknown task."""
    task = known_task(arrays)
    try:
        layout = None if task is None else task.observation_layout()
    except (KeyError, ValueError):
        return None
    return layout if layout is not None and len(layout) == np.asarray(arrays["obs_mean"]).shape[0] else None


def save_controller(path: str, arrays: Mapping) -> None:
    """An exported controller .npz at `path` (atomic), stamped with this version's format_version."""
    save_npz_atomic(path, **stamped_arrays(arrays))


def write(arrays: dict, fmt: str, out: str) -> list:
    """Write the controller in `fmt`; returns the lines to print."""
    from gsa_jax.running.checkpoint import write_atomic

    if fmt == "npz":
        save_controller(out, arrays)
        return []
    layout = task_layout(arrays)
    if fmt == "onnx":
        try:
            from gsa_jax.deployment.export_onnx import to_bytes
        except ImportError as e:  # pragma: no cover - depends on the install
            raise ExportError(f"ONNX export needs the deploy extra: pip install 'gsa_jax[deploy]' ({e})") from None
        write_atomic(out, to_bytes(arrays, layout), "wb")
        return []
    write_atomic(out, to_source(arrays, layout))
    c = cost(arrays)
    return [f"C controller: {c['constants']} float constants ({c['bytes'] / 1024:.1f} KiB); per call "
            f"{c['multiply_adds']} multiply-adds, {c['tanh']} tanhf, {c['compares']} compares"]
