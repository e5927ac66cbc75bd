"""A trained run's settings and parameters, read by one function wherever the run is stored: a run
directory (gsa train; a group of one) or one run of a sweep, addressed as SWEEP_DIR/<run label>, e.g.
runs/sweeps/fig1_small/hopper-mixture-K2-s0 (`gsa extract SWEEP_DIR --list` names them).

Both are group directories (gsa_jax.running.store): runs.csv (the run axis), config.json (what the runs
compute; a group's lists each run's seed and hyperparameters under "runs") and params.npz [R, ...]. Loads
without JAX: reading and deploying a controller need only NumPy.
"""

import csv
import glob
import json
import os
import re
from typing import NamedTuple

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.errors import UserError
from gsa_jax.running.formats import LAYOUT_FILE, check_group_directory, check_run_directory, read_json


class RunNotFound(UserError, ValueError):
    """An address that is neither a run directory nor a finished run of a sweep."""


class TrainedRun(NamedTuple):
    """address: as given; meta: the run's settings as a run directory's config.json holds them (config,
    hparams, seed, iterations, chunk, eval_every, result, versions, git_commit, ...); params: params.npz's
    entries of this run without the run axis ("['params']['policy']['L']", "['obs_stats']['mean']", ...)."""

    address: str
    meta: dict
    params: dict


def read_rows(root: str) -> list:
    """The runs.csv rows of a group directory (dicts of strings), in run-axis order."""
    with open(os.path.join(root, LAYOUT_FILE)) as f:
        return list(csv.DictReader(f))


def path_part(name: str) -> str:
    """A task name as one part of a file name on any system: a task named 'module:Class' or 'dir/file.py:Class'
    without ':' or separators ('module.Class', 'dir_file.py.Class')."""
    return str(name).replace(":", ".").replace("/", "_").replace("\\", "_")


def run_label(row: dict) -> str:
    """A run's name in file, TensorBoard and address names, from its grid row or runs.csv row (the same name):
    env-policy[-K<k>][-<sub-policy>][-<critic>][-<hparam>=<value>...][-hparam_set=<i>]-s<seed>. The hyperparameters
    of a set (the columns after 'hparam_set') are named by the set's index alone: a file name stays short."""
    fixed = ("env", "policy", "K", "seed", "run")
    parts = [path_part(row["env"]), row["policy"]] + ([f"K{row['K']}"] if row["policy"] == MIXTURE else [])
    for c, v in row.items():
        if c not in fixed and v not in ("", None):
            parts.append(f"{c}={v}" if c not in ("subpolicy", "value_target") else str(v))
            if c == "hparam_set":
                break
    return "-".join(parts + [f"s{row['seed']}"])


PART = re.compile(r"(.*)-part([2-9]|[1-9]\d+)")  # a group's later parts: <group>-part2, ... (part_dir)


def part_dir(group: str, index: int) -> str:
    """The directory of part `index` (0-based) of a group trained in parts (gsa sweep --runs-per-program): the
    group's own name, then <group>-part2, <group>-part3, ..."""
    return group if index == 0 else f"{group}-part{index + 1}"


def group_order(path: str) -> tuple:
    """Sort key of a file in a group directory: its parent path, the group, its part (<group> before <group>-part2
    before <group>-part10), then the path itself."""
    group_dir = os.path.dirname(path)
    m = PART.fullmatch(os.path.basename(group_dir))
    name, part = (m.group(1), int(m.group(2))) if m else (os.path.basename(group_dir), 1)
    return os.path.dirname(group_dir), name, part, path


def finished_runs(sweep_dir: str) -> list:
    """[(label, group dir, index on the run axis, runs.csv row)] of every run of a sweep whose group finished
    (DONE), in group order."""
    if not os.path.exists(os.path.join(sweep_dir, "sweep.json")):
        raise RunNotFound(f"{sweep_dir!r} is not a sweep directory (no sweep.json)")
    out = []
    for runs_csv in sorted(glob.glob(os.path.join(sweep_dir, "**", "groups", "*", LAYOUT_FILE), recursive=True),
                           key=group_order):
        root = os.path.dirname(runs_csv)
        if os.path.exists(os.path.join(root, "DONE")):
            check_group_directory(root, sweep_dir)
            out.extend((run_label(row), root, i, row) for i, row in enumerate(read_rows(root)))
    return out


def group_meta(root: str, index: int) -> dict:
    """The settings of run `index` of a group directory: its config.json with the run's own entry of
    "runs" (seed, hparams) merged in, and its result (finished, or stopped at a NaN/inf: failed.json), in the current
    layout (running.formats)."""
    meta = read_json(os.path.join(root, "config.json"), "run")
    meta.pop("format_version")
    per_run = meta.pop("runs", None)
    if per_run is None:  # a run directory: config.json is the run's own
        return meta
    meta.update(per_run[index])
    row = read_rows(root)[index]
    with open(os.path.join(root, "failed.json")) as f:
        failed = [r for r in json.load(f) if str(r.get("run")) == row.get("run")]
    done = failed[0]["failed_at"] - 1 if failed else meta["iterations"]
    meta["result"] = {"iterations_done": done, "status": "nan" if failed else "finished"}
    meta["run"] = row
    return meta


def read_params(root: str, index: int) -> dict:
    """params.npz's entries of run `index`, without the run axis."""
    with np.load(os.path.join(root, "params.npz")) as p:
        return {k: p[k][index] for k in p.files}


def locate(address: str) -> tuple:
    """(group directory, index) of a run directory or of SWEEP_DIR/<run label>."""
    address = os.path.normpath(address)
    if os.path.isdir(address) and os.path.exists(os.path.join(address, "config.json")):
        check_run_directory(address)
        return address, 0
    sweep_dir, label = os.path.split(address)
    if os.path.exists(os.path.join(sweep_dir, "sweep.json")):
        runs = finished_runs(sweep_dir)
        hits = [(root, i) for name, root, i, _ in runs if name == label]
        if hits:
            return hits[0]
        raise RunNotFound(f"{sweep_dir!r} holds no finished run {label!r}; its finished runs: "
                          + (", ".join(name for name, *_ in runs[:6]) + (", ..." if len(runs) > 6 else "") or "none"))
    raise RunNotFound(f"{address!r} is not a gsa_jax run: neither a run directory (config.json) nor SWEEP_DIR/<run label>")


def read_run(address: str) -> TrainedRun:
    """The TrainedRun at `address`: a run directory, or SWEEP_DIR/<run label>."""
    root, index = locate(address)
    if not os.path.exists(os.path.join(root, "params.npz")):
        raise RunNotFound(f"{address!r} is not a gsa_jax run: params.npz is missing")
    return TrainedRun(address, group_meta(root, index), read_params(root, index))
