"""Versioned records: every file gsa_jax saves (a run's config.json, a sweep's sweep.json and its groups'
config.json, an exported controller .npz, answer.json, verify.json) carries `format_version`, and this module
alone reads an older one into the current layout, one step per version (STEPS), so every reader sees one layout.

A record without the field is version 0 (written before it existed). A record newer than this gsa_jax, or one of
an older layout it cannot carry over, is a FormatError in one line. Loads without JAX (NumPy only): reading a
controller must not need JAX. docs/library.md lists what each version changed.
"""

import collections
import copy
import json
import os
from typing import Callable, Mapping, Sequence

import numpy as np

from envs.physics import nest_physics
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.errors import UserError

FORMAT_VERSION = 1  # the version this gsa_jax writes
VERSION_KEY = "format_version"
KINDS = ("run", "sweep", "controller", "answer", "verify")
GROUP_COLUMNS = ("env", "policy", "subpolicy", "partition", "value_target")  # a run row's group (running.spec)
LAYOUT_FILE = "runs.csv"  # what marks a group directory (a run directory of an older layout has none)


class FormatError(UserError):
    """A file written by a gsa_jax of another file format: intact, so no fallback to its previous version; the
    message says how to go on."""


def stamped(record: dict) -> dict:
    """A JSON record with this version's format_version first."""
    return {VERSION_KEY: FORMAT_VERSION, **{k: v for k, v in record.items() if k != VERSION_KEY}}


def stamped_arrays(arrays: Mapping) -> dict:
    """Controller arrays with this version's format_version (a 0-d int32 array)."""
    return {**arrays, VERSION_KEY: np.array(FORMAT_VERSION, np.int32)}


def version_of(record: Mapping, what: str) -> int:
    """A record's format_version (0 where it has none); FormatError for one newer than this gsa_jax or not an
    integer."""
    raw = record.get(VERSION_KEY, 0)
    value = np.asarray(raw)
    version = int(value.item()) if value.shape == () and value.dtype.kind in "iu" else None  # no bool, float, str
    if version is None or version < 0:
        raise FormatError(f"{what} has format_version {raw!r}, not a version number")
    if version > FORMAT_VERSION:
        raise FormatError(f"{what} was written by a newer gsa_jax (format_version {version}; this one reads up to "
                          f"{FORMAT_VERSION}): read it with a newer gsa_jax")
    return version


# ----------------------------------------------------------------------------------------------- version 0 -> 1
def physics_nested(what: str, config: dict) -> dict:
    """A config record with its physics options as one record (the flat fields of version 0 moved in)."""
    try:
        return nest_physics(config)
    except ValueError as e:
        raise FormatError(f"{what}: {e}") from None


def run_from_0(record: dict, what: str) -> dict:
    """A run's (or a sweep group's) config.json: physics options nested; a run's eval_seed (0) and tensorboard
    (on), which version 0 left out at those values."""
    out = dict(record)
    if isinstance(out.get("config"), dict):
        out["config"] = physics_nested(what, out["config"])
    if "runs" not in out and "iterations" in out:  # a run directory's own record, not a group's
        out.setdefault("eval_seed", 0)
        out.setdefault("tensorboard", True)
    return out


def sweep_from_0(record: dict, what: str) -> dict:
    """sweep.json: the spec's config with its physics nested; pad_runs (runs per program of version 0, which
    trained a group larger than it whole) as runs_per_program, and where a group was larger its size as
    trained_whole (such a sweep reads, and resuming it is refused: parts would train that group again)."""
    out = dict(record)
    spec = out.get("spec")
    if isinstance(spec, dict) and isinstance(spec.get("config"), dict):
        out["spec"] = {**spec, "config": physics_nested(what, spec["config"])}
    if "pad_runs" in out:
        n = int(out.pop("pad_runs"))
        sizes = collections.Counter(tuple(r.get(c) for c in GROUP_COLUMNS) for r in out.get("runs", []))
        largest = max(sizes.values(), default=0)
        if n and largest > n:
            out["trained_whole"] = largest
        out["runs_per_program"] = n
    out.setdefault("runs_per_program", 0)
    return out


def controller_from_0(arrays: dict, what: str) -> dict:
    """An exported controller: a mixture's partition ('mlp', the only class then) and sub-policy ('linear');
    the task it names and its definition's sha256 ('' where none was stored)."""
    out = dict(arrays)
    if str(out.get("kind", "")) == MIXTURE:
        out.setdefault("partition", np.array("mlp"))
        out.setdefault("subpolicy", np.array("linear"))
    out.setdefault("task", np.array(""))
    out.setdefault("task_sha256", np.array(""))
    return out


def answer_from_0(state: dict, what: str) -> dict:
    """answer.json: the setup's max_steps (None: fixed steps) and futility (0: every K to the cap), marked
    before_futility (true) where it had none (its resume hint says so); every sweep's compile_wall_s (its
    compile_s); a step-budget record's candidate (its 'enough': the rule before the two-sided one)."""
    out = copy.deepcopy(state)
    setup = dict(out["setup"])
    if "futility" not in setup:
        out["before_futility"] = True
    out["setup"] = {"max_steps": None, "futility": 0.0, **setup}
    steps = out.get("steps") or {}
    for c in steps.get("calibration", []):
        if "enough" in c:
            c.setdefault("candidate", c["enough"])
    sweeps = [c["sweep"] for c in steps.get("calibration", []) if "sweep" in c]
    for s in sweeps + [s for r in out.get("rounds", []) for s in (r.get("sweeps") or {}).values()]:
        if "compile_s" in s:
            s.setdefault("compile_wall_s", s["compile_s"])
    return out


def verify_from_0(doc: dict, what: str) -> dict:
    """verify.json: its layout is its schema (docs/verify.md), unchanged by version 1."""
    return dict(doc)


STEPS: dict[str, list[Callable]] = {  # kind -> [the step from version i to i + 1]
    "run": [run_from_0], "sweep": [sweep_from_0], "controller": [controller_from_0], "answer": [answer_from_0],
    "verify": [verify_from_0],
}
assert all(len(steps) == FORMAT_VERSION for steps in STEPS.values()), "a step to the current version for every kind"


def current(record: dict, kind: str, what: str) -> dict:
    """A record of `kind` (KINDS) in this version's layout, with this version's format_version; FormatError where it
    is newer or cannot be carried over. `what` names it in messages (its path)."""
    version = version_of(record, what)
    out = {k: v for k, v in record.items() if k != VERSION_KEY}
    for step in STEPS[kind][version:]:
        try:
            out = step(out, what)
        except (KeyError, TypeError, ValueError, AttributeError) as e:  # a record of another kind, or cut short
            raise FormatError(f"{what} is not a gsa_jax {kind} record of format_version {version} "
                              f"({type(e).__name__}: {e})") from None
    return stamped_arrays(out) if kind == "controller" else stamped(out)


def read_json(path: str, kind: str) -> dict:
    """A JSON record of `kind` read from `path` into the current layout (current). OSError / ValueError as json
    raises them; FormatError for a newer or unreadable version."""
    with open(path) as f:
        record = json.load(f)
    if not isinstance(record, dict):
        raise FormatError(f"{path} is not a gsa_jax record (a JSON {type(record).__name__}, not an object)")
    return current(record, kind, path)


def read_controller(path: str) -> dict:
    """An exported controller .npz's arrays in the current layout (current). OSError / ValueError as np.load
    raises them."""
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    return current(arrays, "controller", path)


# ----------------------------------------------------------------------------------------------- layouts refused
def refuse_trained_whole(meta: dict, where: str, error: type) -> None:
    """`error` (one line) for a sweep.json of version 0 that trained a group larger than its pad_runs whole
    (trained_whole): parts would train that group's runs again."""
    if meta.get("trained_whole"):
        raise error(f"{where} was written by an older gsa_jax (pad_runs {meta['runs_per_program']}) and has a group of "
                    f"{meta['trained_whole']} runs, which it trained whole; resume it with its own commit "
                    f"(git_commit {meta.get('git_commit', '?')})")


def check_run_directory(root: str) -> None:
    """FormatError (one line) for a run directory written before runs were stored as groups of one."""
    if os.path.exists(os.path.join(root, "config.json")) and not os.path.exists(os.path.join(root, LAYOUT_FILE)):
        raise FormatError(f"{root} holds a run of an older gsa_jax (metrics.csv and params.npz without a run axis, "
                          "no runs.csv); read or continue it with the commit in its config.json (git_commit), or train "
                          "it again")


def check_group_directory(root: str, sweep_dir: str) -> None:
    """FormatError (one line) for a finished sweep group written before groups recorded their config.json."""
    if not os.path.exists(os.path.join(root, "config.json")):
        raise FormatError(f"{sweep_dir} was written by an older gsa_jax (its groups have no config.json); read "
                          "its runs with the commit in its sweep.json (git_commit)")


def check_metrics(path: str, names: Sequence[str], tracked: Sequence[str]) -> None:
    """FormatError (one line) for a metrics file written by a gsa_jax that tracked fewer metrics than `tracked`."""
    missing = [k for k in tracked if k not in names]
    if missing:
        raise FormatError(f"{path} was written by an older gsa_jax (no {', '.join(missing)}); finish it with the "
                          "commit in its sweep.json or config.json (git_commit), or start over in another --out")
