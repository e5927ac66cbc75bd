"""A sweep's runs seen as trained runs: their addresses (SWEEP_DIR/<run label>, which every single-run tool
reads: inspect, export, deploy, render --run), every finished run's exported controller, and a sweep's results
copied for committing (tidy metrics gzipped, sweep.json, failed runs, controllers); `gsa extract`."""

import glob
import gzip
import json
import os

from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment.exporting import controller_arrays, save_controller
from gsa_jax.errors import UserError
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.formats import FormatError
from gsa_jax.running.trained import RunNotFound, finished_runs


class ExtractError(UserError):
    pass


def sweep_runs(sweep_dir: str) -> list:
    """[(label, group dir, index, runs.csv row)] of a sweep's finished runs; ExtractError if it is no sweep."""
    try:
        return finished_runs(sweep_dir)
    except (RunNotFound, FormatError) as e:
        raise ExtractError(str(e)) from None


def select(sweep_dir: str, env: str, policy: str, k: int, seed: int) -> str:
    """The address (SWEEP_DIR/<run label>) of the one finished run of a cell and seed (a sweep without swept
    hyperparameters or group axes)."""
    def matches(row):
        return ((row["env"], row["policy"], row["seed"]) == (env, policy, str(seed))
                and (policy != MIXTURE or row["K"] == str(k)))

    hits = [label for label, _, _, row in sweep_runs(sweep_dir) if matches(row)]
    if len(hits) != 1:
        raise ExtractError(f"{len(hits)} finished runs with env={env} policy={policy} K={k} seed={seed} in {sweep_dir!r}")
    return os.path.join(sweep_dir, hits[0])


def export_controllers(sweep_dir: str, out_dir: str) -> list:
    """Write every finished run's deterministic controller to out_dir/<run label>.npz -> [paths]."""
    runs = sweep_runs(sweep_dir)
    if not runs:
        raise ExtractError(f"{sweep_dir!r} holds no finished run")
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for label, *_ in runs:
        paths.append(os.path.join(out_dir, label + ".npz"))
        save_controller(paths[-1], controller_arrays(os.path.join(sweep_dir, label)))
    return paths


def collect_results(sweep_dir: str, out_dir: str) -> list:
    """Copy a sweep's results into out_dir -- sweep.json, each worker's tidy metrics.csv gzipped
    (metrics[-process-<i>].csv.gz), failed_runs.json, controllers/ (export_controllers) -- and no training
    state. Returns the paths written."""
    if not os.path.exists(os.path.join(sweep_dir, "sweep.json")):
        raise ExtractError(f"{sweep_dir!r} is not a sweep directory (no sweep.json)")
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(sweep_dir, "sweep.json")) as f:
        meta = f.read()
    written = [os.path.join(out_dir, "sweep.json")]
    write_atomic(written[0], meta)
    failed = []
    for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "metrics.csv"), recursive=True)):
        rel = os.path.relpath(os.path.dirname(path), sweep_dir)
        if "groups" in rel.split(os.sep):
            continue
        name = "metrics.csv.gz" if rel == "." else f"metrics-{rel.replace(os.sep, '-')}.csv.gz"
        with open(path, "rb") as f:
            write_atomic(os.path.join(out_dir, name), gzip.compress(f.read(), mtime=0), "wb")
        written.append(os.path.join(out_dir, name))
        runs_json = os.path.join(os.path.dirname(path), "failed_runs.json")
        if os.path.exists(runs_json):
            with open(runs_json) as f:
                failed += json.load(f)
    write_atomic(os.path.join(out_dir, "failed_runs.json"), json.dumps(failed))
    return written + export_controllers(sweep_dir, os.path.join(out_dir, "controllers"))
