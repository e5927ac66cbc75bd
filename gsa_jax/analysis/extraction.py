"""A sweep's runs as single-run directories and exported controllers, and a sweep's results copied for
committing (tidy metrics gzipped, sweep.json, failed runs, controllers); `python -m gsa_jax.extract`."""

import csv
import dataclasses
import glob
import gzip
import json
import os
import tempfile

import numpy as np


class ExtractError(Exception):
    pass


def finished_runs(sweep_dir):
    """[(group dir, row index in the group, run dict)] of every run whose group finished (DONE)."""
    if not os.path.exists(os.path.join(sweep_dir, "sweep.json")):
        raise ExtractError(f"{sweep_dir!r} is not a sweep directory (no sweep.json)")
    out = []
    for runs_csv in sorted(glob.glob(os.path.join(sweep_dir, "**", "groups", "*", "runs.csv"), recursive=True)):
        gdir = os.path.dirname(runs_csv)
        if not os.path.exists(os.path.join(gdir, "DONE")) or not os.path.exists(os.path.join(gdir, "params.npz")):
            continue
        with open(runs_csv) as f:
            for i, row in enumerate(csv.DictReader(f)):
                out.append((gdir, i, row))
    return out


def select(runs, env, policy, k, seed, subpolicy=None, hparams=(), value_target=None):
    """The one finished run matching the arguments (hparams: [(name, value string)])."""

    def matches(row):
        if (row["env"], row["policy"], row["seed"]) != (env, policy, str(seed)):
            return False
        if policy == "mixture" and (row["K"] != str(k) or (subpolicy and (row.get("subpolicy") or "linear") != subpolicy)):
            return False
        if value_target and (row.get("value_target") or "gae") != value_target:
            return False
        return all(n in row and float(row[n]) == float(v) for n, v in hparams)

    hits = [(gdir, i, row) for gdir, i, row in runs if matches(row)]
    desc = f"env={env} policy={policy}" + (f" K={k}" if policy == "mixture" else "") + f" seed={seed}"
    if not hits:
        raise ExtractError(f"no finished run with {desc} (see --list)")
    if len(hits) > 1:
        raise ExtractError(f"{len(hits)} runs match {desc}; narrow it with --hparam NAME=VALUE, --subpolicy or --value-target (see --list)")
    return hits[0]


def extract(sweep_dir, gdir, index, row, out):
    """Write out/config.json and out/params.npz for run `index` of group `gdir`."""
    from gsa_jax.algorithm.ppo import HPARAM_DEFAULTS
    from gsa_jax.running.checkpoint import save_npz_atomic, write_atomic
    from gsa_jax.running.spec import Group, check_spec, default_chunk, group_config, group_iterations

    with open(os.path.join(sweep_dir, "sweep.json")) as f:
        meta = json.load(f)
    spec = check_spec(meta["spec"], source=os.path.join(sweep_dir, "sweep.json"))
    with open(os.path.join(gdir, "runs.csv")) as f:
        group_runs = [dict(r, K=int(r["K"])) for r in csv.DictReader(f)]
    cfg = group_config(spec, Group(row["env"], row["policy"], group_runs))
    chunk = default_chunk(spec, cfg)
    iterations = group_iterations(spec, cfg, chunk)
    hp = dict(HPARAM_DEFAULTS)
    hp.update({n: v[0] for n, v in spec.hparams.items()})
    hp.update({n: float(row[n]) for n in spec.hparams if n in row})
    hp.update(K=int(row["K"]) if row["policy"] == "mixture" else 1, total_iterations=iterations)
    with np.load(os.path.join(gdir, "params.npz")) as p:
        arrays = {k: p[k][index] for k in p.files}
    os.makedirs(out, exist_ok=True)
    save_npz_atomic(os.path.join(out, "params.npz"), **arrays)
    config = {"config": dataclasses.asdict(cfg), "hparams": hp, "seed": int(row["seed"]), "iterations": iterations,
              "chunk": chunk, "result": {"iterations_done": iterations, "status": "finished"},
              "extracted_from": {"sweep": os.path.abspath(sweep_dir), "group": os.path.relpath(gdir, sweep_dir),
                                 "row": index, "run": row, "git_commit": meta.get("git_commit")}}
    write_atomic(os.path.join(out, "config.json"), json.dumps(config, indent=2))
    return out


def export_controllers(sweep_dir, out_dir):
    """Write every finished run's deterministic controller to out_dir/<run_label>.npz -> [paths]."""
    from gsa_jax.deployment.exporting import controller_arrays
    from gsa_jax.running.checkpoint import save_npz_atomic
    from gsa_jax.running.spec import run_label

    runs = finished_runs(sweep_dir)
    if not runs:
        raise ExtractError(f"{sweep_dir!r} holds no finished run")
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for gdir, i, row in runs:
        with tempfile.TemporaryDirectory() as tmp:
            arrays = controller_arrays(extract(sweep_dir, gdir, i, row, tmp))
        paths.append(os.path.join(out_dir, run_label(row) + ".npz"))
        save_npz_atomic(paths[-1], **arrays)
    return paths


def collect_results(sweep_dir, out_dir):
    """Copy a sweep's results into out_dir -- sweep.json, each worker's tidy metrics.csv gzipped
    (metrics[-process-<i>].csv.gz), failed_runs.json, controllers/ (export_controllers) -- and no training
    state. Returns the paths written."""
    from gsa_jax.running.checkpoint import write_atomic

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
