"""The deployed controller in plain NumPy (no JAX needed): load(path).act(obs), .cluster(obs).

A mixture controller is piecewise simple: normalize the observation, pick the most probable
cluster of the partition (eps-uniform exploration does not change the argmax; gsa_jax.algorithm.partitions: a tanh
MLP, or one affine layer W z + c for the linear class), apply
that cluster's L_c phi(z) + b_c, where phi is the sub-policy class (gsa_jax.algorithm.subpolicies): [] (constant),
z (linear), [z, z_i z_j for i <= j] (quadratic). An MLP controller applies its tanh MLP to the normalized observation.
`act` then clips that raw action to the task's action bounds (action_low, action_high: envs.action_bounds, what
training clips to), so it can go straight into the task's step (gymnasium's v5 tasks charge their control cost on
the action they are given); `act(obs, clip=False)` is the raw action, for analysis.

File format (written by `gsa export`): kind ('mixture'|'mlp'), obs_mean, obs_var,
obs_clip, n_layers, w{i}/b{i} for i < n_layers (partition or policy MLP), action_low, action_high [d_a],
config_json (the run's config: its task is config.env), task (its name), obs_size (d_s), task_sha256 (the sha256 of
the file that defined the task, '' for a built-in one; envs.task_source), ctrl_low, ctrl_high [d_a] where the task maps
its actions onto its actuators' ctrlrange (envs/task.py's ctrl_range 'model': controls(action)), action_space
('controls' where that map is applied in the file: the actions are the controls; absent: actions in [-1, 1]; see
unit_actions), format_version (running.formats), and for mixtures subpolicy
('constant'|'linear'|'quadratic'), partition ('mlp'|'linear'; 'single': a K = 1 mixture exported with no partition
network, n_layers 0: its one piece acts everywhere, cluster() is 0), L [K, d_a, d_phi], b [K, d_a] of the K active
clusters. `load` reads a file of an older format_version into this layout (running.formats.read_controller); files
exported before the bounds were stored get their task's (`action_bounds`); docs/deploy.md lists every key.
`load(path, task=NAME)` refuses (TaskMismatch, one line) a controller that does not fit that task as it is now
(check_task).
"""

import json
import warnings
from typing import TYPE_CHECKING, Mapping

import numpy as np

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.errors import UserError
from gsa_jax.running.formats import read_controller

if TYPE_CHECKING:
    from envs.families.record import TaskRecord


def task_name(arrays: Mapping) -> str | None:
    """The task an exported controller was trained on (config_json's config.env), or None."""
    try:
        return str(json.loads(str(arrays["config_json"]))["config"]["env"])
    except (KeyError, TypeError, ValueError):
        return None


def action_size(arrays: Mapping) -> int:
    """d_a of an exported controller's arrays."""
    if str(arrays["kind"]) == MIXTURE:
        return int(np.shape(arrays["b"])[-1])
    return int(np.shape(arrays[f"b{int(arrays['n_layers']) - 1}"])[-1])


def controller_task(arrays: Mapping) -> "TaskRecord | None":
    """The record of the task an exported controller names (config_json's config.env; envs/registry.py), or None
    where it names none: the one place a controller file's task name becomes its record (ValueError / ImportError,
    one line, where the name does not resolve on this machine)."""
    name = task_name(arrays)
    if name is None:
        return None
    import envs  # no JAX: the task registry

    return envs.resolve(name)


def action_bounds(arrays: Mapping) -> tuple | None:
    """(low [d_a], high [d_a]) float32 of an exported controller: its own action_low / action_high, else (files
    exported before they were stored) those of the task it names (TaskRecord.action_bounds), else None."""
    if "action_low" in arrays:
        return np.asarray(arrays["action_low"], np.float32), np.asarray(arrays["action_high"], np.float32)
    try:
        task = controller_task(arrays)
    except (ValueError, ImportError):  # a name that does not resolve here: no bounds
        return None
    return None if task is None else task.action_bounds(action_size(arrays))


class TaskMismatch(UserError, ValueError):
    """An exported controller that does not fit the task it is asked to run (one line)."""


class ControllerClassError(UserError, ValueError):
    """An exported controller of a sub-policy or partition class this version does not know, or whose arrays do not
    fit its class (one line)."""


def stored_sha256(arrays: Mapping) -> str | None:
    """The sha256 of the task definition an exported controller was trained on, or None where it has none."""
    return str(arrays["task_sha256"]) or None


def check_task(arrays: Mapping, task: "TaskRecord", force: bool = False, name: str = "the controller") -> None:
    """TaskMismatch (one line) unless the controller fits `task` (its record, envs/registry.py) as its definition is
    now: the same observation size, and (unless force) the same task name and, where both are recorded, the same
    definition sha256 (TaskRecord.source(), what `train --resume` compares)."""
    d_s = int(np.shape(arrays["obs_mean"])[0])
    mine = str(arrays["task"]) or task_name(arrays)  # task: as exported
    size = task.observation_size()
    if size != d_s:
        raise TaskMismatch(f"{name} takes {d_s} observation values and task {task.name!r} now observes {size}: it "
                           f"was trained on {'task ' + repr(mine) if mine else 'another task'} as it was then; export "
                           "it again from a run of the task as it is")
    if force:
        return
    sha = task.source().get("sha256")
    if mine is not None and mine != task.name:
        raise TaskMismatch(f"{name} is for task {mine!r}, not {task.name!r} (pass --force / force=True to run it "
                           "anyway)")
    if stored_sha256(arrays) and sha and stored_sha256(arrays) != sha:
        raise TaskMismatch(f"the definition of task {task.name!r} changed since {name} was trained (sha256 "
                           f"{stored_sha256(arrays)[:12]}... then, {sha[:12]}... now); pass --force / force=True to "
                           "run it anyway")


def inward_float32(low: np.ndarray, high: np.ndarray) -> tuple:
    """(low, high) as float32 inside [low, high]: a bound float32 rounds outward is moved one step in, so an action
    clipped to them is inside the float64 range too (dm_control checks actions against its action_spec's)."""
    lo, hi = np.asarray(low, np.float32), np.asarray(high, np.float32)
    lo = np.where(lo.astype(np.float64) < low, np.nextafter(lo, np.float32(np.inf)), lo)
    hi = np.where(hi.astype(np.float64) > high, np.nextafter(hi, np.float32(-np.inf)), hi)
    return lo.astype(np.float32), hi.astype(np.float32)


def map_actions(arrays: Mapping, scale: np.ndarray, offset: np.ndarray, low: np.ndarray, high: np.ndarray) -> dict:
    """The controller arrays with every action a replaced by offset + scale * a (scale > 0, per action) and its bounds
    by [low, high]: the last affine step (a mixture's L, b; an MLP's last layer) absorbs the map, so the cluster
    choice is unchanged and, the map being increasing, clipping commutes with it."""
    scale, offset = np.asarray(scale, np.float64), np.asarray(offset, np.float64)
    out = dict(arrays)
    if str(arrays["kind"]) == MIXTURE:
        out["L"] = (np.asarray(arrays["L"], np.float64) * scale[:, None]).astype(np.float32)
        out["b"] = (offset + scale * np.asarray(arrays["b"], np.float64)).astype(np.float32)
    else:
        last = int(arrays["n_layers"]) - 1
        out[f"w{last}"] = (np.asarray(arrays[f"w{last}"], np.float64) * scale).astype(np.float32)
        out[f"b{last}"] = (offset + scale * np.asarray(arrays[f"b{last}"], np.float64)).astype(np.float32)
    out["action_low"], out["action_high"] = inward_float32(low, high)
    return out


SINGLE = "single"  # a K = 1 mixture's partition in an export: no network (n_layers 0), its one piece everywhere


def partition_class(arrays: Mapping, layers: list, name: str = "the controller") -> str:
    """The partition class of a mixture's arrays (SINGLE: no network, one piece): ControllerClassError (one line) for
    a class this version does not know or whose layer sizes are not that class's."""
    partition = str(arrays["partition"])
    if partition not in (*partitions.PARTITIONS, SINGLE):
        raise ControllerClassError(f"{name} has an unknown partition class {partition!r}; this version knows "
                                   f"{', '.join(partitions.PARTITIONS)}, {SINGLE} (K = 1)")
    if partition == SINGLE or not layers:  # no network: a single piece, and only it, has none
        if partition != SINGLE or layers or np.shape(arrays["L"])[0] != 1:
            raise ControllerClassError(f"{name} names partition class {partition!r} but has {len(layers)} partition "
                                       f"layers and K = {np.shape(arrays['L'])[0]} (class {SINGLE!r}: none, K = 1)")
        return partition
    sizes = (layers[0][0].shape[0], *(w.shape[1] for w, _ in layers))  # (d_s, hidden widths..., K)
    if tuple(partitions.get(partition).sizes(sizes[0], sizes[1:-1], sizes[-1])) != sizes:
        raise ControllerClassError(f"{name} names partition class {partition!r} but its layers have sizes {sizes}")
    return partition


class Controller:
    def __init__(self, arrays, name="the controller"):
        self.arrays = arrays
        self.kind = str(arrays["kind"])
        self.obs_mean = np.asarray(arrays["obs_mean"], np.float32)
        self.obs_std = np.sqrt(np.asarray(arrays["obs_var"], np.float32) + np.float32(1e-8))
        self.obs_clip = float(arrays["obs_clip"])
        n = int(arrays["n_layers"])
        self.layers = [(np.asarray(arrays[f"w{i}"], np.float32), np.asarray(arrays[f"b{i}"], np.float32)) for i in range(n)]
        if self.kind == MIXTURE:
            self.subpolicy = str(arrays["subpolicy"])
            if self.subpolicy not in subpolicies.SUBPOLICIES:
                raise ControllerClassError(f"{name} has an unknown sub-policy class {self.subpolicy!r}; this version "
                                           f"knows {', '.join(subpolicies.SUBPOLICIES)}")
            self.partition = partition_class(arrays, self.layers, name)
            self.L = np.asarray(arrays["L"], np.float32)
            self.b = np.asarray(arrays["b"], np.float32)
        elif self.kind != MLP:
            raise ValueError(f"unknown controller kind {self.kind!r}")
        self.action_size = action_size(arrays)
        self.action_low, self.action_high = action_bounds(arrays) or (None, None)
        self.ctrl_range = ((np.asarray(arrays["ctrl_low"], np.float64), np.asarray(arrays["ctrl_high"], np.float64))
                           if "ctrl_low" in arrays else None)
        # 'controls': the actions are the actuators' own controls, in their ctrlrange (the task's action space)
        self.action_space = str(arrays["action_space"]) if "action_space" in arrays else "unit"
        self.no_bounds = (f"{name} stores no action bounds and its task {task_name(arrays)!r} is not a known task: "
                          "act() returns raw, unclipped actions")
        if self.action_low is None:
            warnings.warn(self.no_bounds, stacklevel=2)

    def controls(self, action: np.ndarray) -> np.ndarray:
        """The actuator controls of an action from act(): the action itself (also where its actions are the controls
        already, action_space 'controls'), or its map onto the task's ctrlrange (ctrl = low + (a + 1) (high - low) / 2)
        where the task has one (ctrl_low, ctrl_high)."""
        if self.ctrl_range is None or self.action_space == "controls":
            return np.asarray(action)
        low, high = self.ctrl_range
        return low + (np.asarray(action, np.float64) + 1.0) * (0.5 * (high - low))

    def unit_actions(self) -> "Controller":
        """This controller with actions in [-1, 1] (what training acts in, and our MuJoCo C tasks' step() takes):
        itself, or, for one whose actions are its task's controls (action_space 'controls'), the map
        ctrl = low + (a + 1) (high - low) / 2 undone, with low and high as its ctrl_range."""
        if self.action_space != "controls":
            return self
        low, high = self.ctrl_range
        half = 0.5 * (high - low)
        arrays = map_actions(self.arrays, 1.0 / half, -(low + half) / half, -np.ones_like(low), np.ones_like(high))
        return Controller({k: v for k, v in arrays.items() if k != "action_space"})

    @property
    def num_clusters(self) -> int:
        return self.L.shape[0] if self.kind == MIXTURE else 1

    @property
    def single_piece(self) -> bool:
        """A mixture of K = 1: its one piece acts everywhere, whatever partition network the file may carry."""
        return self.kind == MIXTURE and self.num_clusters == 1

    def bounds(self) -> tuple:
        """(action_low [d_a], action_high [d_a]); ValueError where the controller has none."""
        if self.action_low is None:
            raise ValueError(self.no_bounds)
        return self.action_low, self.action_high

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        return np.clip((np.asarray(obs, np.float32) - self.obs_mean) / self.obs_std, -self.obs_clip, self.obs_clip)

    def _mlp(self, x):
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            if i < len(self.layers) - 1:
                x = np.tanh(x)
        return x

    def features(self, z: np.ndarray) -> np.ndarray:
        """phi(z) [..., d_phi] of normalized observations z [..., d_s] (the sub-policy class's features)."""
        return subpolicies.SUBPOLICIES[self.subpolicy].features(z, np)

    def cluster(self, obs: np.ndarray) -> np.ndarray:
        """Active cluster for obs [..., d_s] -> int array [...] (0 for an MLP controller and a single piece)."""
        z = self.normalize(obs)
        if self.kind == MLP or self.single_piece:  # one piece: the argmax over one logit, without the network
            return np.zeros(z.shape[:-1], np.int64)
        return np.argmax(self._mlp(z)[..., : self.num_clusters], axis=-1)

    def act(self, obs: np.ndarray, clip: bool = True) -> np.ndarray:
        """Deterministic action for obs [..., d_s] -> float32 [..., d_a], inside [action_low, action_high] (clip=False:
        the raw action; a controller without bounds, see load, always returns it)."""
        raw = self._raw_action(obs)
        if not clip or self.action_low is None:
            return raw
        return np.clip(raw, self.action_low, self.action_high)

    def _raw_action(self, obs):
        z = self.normalize(obs)
        if self.kind == MLP:
            return self._mlp(z)
        c = self.cluster(obs)
        if self.L.shape[-1] == 0:  # constant sub-policies (an empty contraction can come back uninitialized)
            return self.b[c].copy()
        return np.einsum("...ij,...j->...i", self.L[c], self.features(z)) + self.b[c]


def load(path: str, task: "str | TaskRecord | None" = None, force: bool = False) -> Controller:
    """The controller of an exported .npz; one warning line where it has no action bounds and names no known task.
    task: a task (its name, resolved here, or its record) it must fit (check_task: TaskMismatch, one line, where it
    does not; force: only its observation size is checked)."""
    arrays = read_controller(path)  # an older file in the current layout (running.formats)
    if task is not None:
        import envs

        check_task(arrays, envs.resolve(task), force, name=str(path))
    return Controller(arrays, name=str(path))
