"""The public API: what the `gsa` commands do, from Python, re-exported by `gsa_jax` (docs/library.md, "Python API").

    import gsa_jax
    run = gsa_jax.train_run("dmc:cartpole-balance", "runs/cp", policy="mixture", clusters=2, steps=100_000)
    sweep = gsa_jax.run_sweep("experiments/fig1_v5/hopper.toml", "runs/hopper")
    state = gsa_jax.answer_task("dmc:cartpole-balance", "runs/answer", budget_minutes=30)
    ctrl = gsa_jax.load_controller("runs/cp/controller.npz")      # act(obs) in NumPy
    scored = gsa_jax.score_controller("runs/cp/controller.npz", episodes=100)  # MuJoCo C, fixed start seeds
    doc = gsa_jax.verify_controller("runs/cp/controller.npz", "runs/cp/verify", quick=True)
    gsa_jax.export_controller("runs/cp", "runs/cp/controller.npz")       # gsa export
    state = gsa_jax.read_record("runs/answer/answer.json", "answer")    # any saved record, an older one's too
    curves = gsa_jax.load_sweep("runs/hopper")           # {cell: {seed: {column: [T]}}}, as gsa plot reads them
    run = gsa_jax.select_run("runs/hopper", "Hopper-v5", "mixture", 2, 0)   # one run's folder in a sweep
    gsa_jax.iqm_ci({"mixture": x, "flat": y})            # rliable's IQM and 95% interval, as every table reports

train_run, run_sweep, export_controller, answer_task and verify_controller run the command itself with the keyword options as its flags
(options_argv: the same checks, files and resumption as on the command line); a bad input raises
gsa_jax.errors.UserError (one line). The names are not the commands' own (gsa_jax.train, gsa_jax.verify, ... are the
`python -m` modules and packages, which an import binds on the package).
"""

import os
from typing import Any

from gsa_jax.errors import UserError

__all__ = ["answer_task", "export_controller", "improvement_probability", "iqm", "iqm_ci", "load_controller",
           "load_sweep", "options_argv", "read_csv", "read_record", "run_metadata", "run_sweep", "score_controller",
           "select_run", "sweep_runs", "train_run", "verify_controller", "write_csv"]


def options_argv(options: dict) -> list:
    """The command-line flags of keyword options: name -> --name-with-dashes VALUE; True -> the bare flag; False or
    None -> left out; a list or tuple -> its items joined by commas."""
    argv = []
    for name, value in options.items():
        flag = "--" + name.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif value is not False and value is not None:
            argv += [flag, ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)]
    return argv


def ran(name: str, status: int) -> None:
    """UserError where a command ended with a nonzero status."""
    if status:
        raise UserError(f"gsa {name} ended with status {status}", exit_status=int(status))


def train_run(env: str, out: str, **options: Any) -> str:
    """`gsa train --env ENV --out OUT [options]` (resumes where OUT holds a run) -> OUT."""
    from gsa_jax.commands.train import train as command

    ran("train", command(["--env", env, "--out", out, *options_argv(options)]))
    return out


def run_sweep(experiment: str, out: str, **options: Any) -> str:
    """`gsa sweep EXPERIMENT --out OUT [options]` (EXPERIMENT: a spec .toml) -> OUT."""
    from gsa_jax.commands.sweep import sweep as command

    ran("sweep", command([experiment, "--out", out, *options_argv(options)]))
    return out


def answer_task(env: str, out: str, **options: Any) -> dict:
    """`gsa answer --env ENV --out OUT [options]` -> its state (OUT/answer.json: the verdicts, the constructive answer,
    the step budget, the rounds)."""
    from gsa_jax.commands.answer import answer as command

    ran("answer", command(["--env", env, "--out", out, *options_argv(options)]))
    from gsa_jax.running.formats import read_json

    return read_json(os.path.join(out, "answer.json"), "answer")


def verify_controller(controller: str, out: str, **options: Any) -> dict:
    """`gsa verify CONTROLLER --out OUT [options]` (quick=True, certify=True, ...) -> OUT/verify.json's record."""
    from gsa_jax.commands.verify import verify_controller as command

    ran("verify", command([controller, "--out", out, *options_argv(options)]))
    from gsa_jax.running.formats import read_json

    return read_json(os.path.join(out, "verify.json"), "verify")


def export_controller(run: str, out: str, **options: Any) -> str:
    """`gsa export RUN --out OUT [options]` (RUN: a run directory or SWEEP_DIR/<run label>; OUT's suffix the format:
    .npz, .onnx, .h) -> OUT."""
    from gsa_jax.commands.export import export_controller as command

    ran("export", command([run, "--out", out, *options_argv(options)]))
    return out


def read_record(path: str, kind: str) -> dict:
    """A saved record of `kind` ('run', 'sweep', 'answer', 'verify': a JSON file; 'controller': an exported .npz's
    arrays) in the current layout, an older file's too (gsa_jax.running.formats; a newer one is a FormatError)."""
    from gsa_jax.running.formats import read_controller, read_json

    return read_controller(path) if kind == "controller" else read_json(path, kind)


def load_controller(path: str) -> Any:
    """An exported controller (gsa export's .npz) as a NumPy controller: act(obs [..., d_s]) -> actions, cluster(obs)
    (gsa_jax.deployment.numpy_policy.Controller; no JAX)."""
    from gsa_jax.deployment import numpy_policy

    return numpy_policy.load(path)


def score_controller(controller: str, episodes: int = 10, start_seed: "int | None" = None) -> dict:
    """The controller's deterministic episodes in MuJoCo C from start seeds start_seed .. + episodes - 1 (default
    gsa score's), as gsa score and the answer's fresh starts run them -> {"returns" [episodes], "lengths", "mean",
    "sha256", "label", "start_seed"}."""
    from gsa_jax.analysis.sweeps import controller_scores

    seed = controller_scores.START_SEED if start_seed is None else int(start_seed)
    ident, returns, lengths = controller_scores.controller_episodes(controller, int(episodes), seed)
    return {"returns": [float(r) for r in returns], "lengths": [int(n) for n in lengths],
            "mean": float(sum(returns) / len(returns)), "sha256": ident["sha256"], "label": ident["label"],
            "start_seed": seed}


def read_csv(path: str) -> list:
    """Rows (dicts of strings) of a CSV file, gzipped where its name ends in .gz; [] where it does not exist."""
    from gsa_jax.analysis.sweeps.results import read_csv as read

    return read(path)


def write_csv(path: str, rows: list, columns: "list | None" = None) -> None:
    """rows (dicts) as a CSV file, written atomically; columns: their order (default: as first seen)."""
    from gsa_jax.analysis.sweeps.results import write_csv as write

    write(path, rows, columns)


def run_metadata() -> dict:
    """What a result records of where it ran: versions (jax, jaxlib, mujoco, MJX, brax, numpy, Python), the git
    commit, platform, devices, XLA flags and options, the start time (gsa_jax.running.runinfo.run_metadata; loads
    JAX)."""
    from gsa_jax.running.runinfo import run_metadata as metadata

    return metadata()


def load_sweep(sweep_dir: str, columns: "list | None" = None) -> dict:
    """A sweep's learning curves, as gsa plot and the tables read them: {Cell: {seed: {column: [T]}}} (columns:
    default env_steps, episode_return, episodes, eval_return, eval_failures; any tidy metric name)."""
    from gsa_jax.analysis.sweeps.results import load_sweep as load

    return load(sweep_dir) if columns is None else load(sweep_dir, columns)


def sweep_runs(sweep_dir: str) -> list:
    """[(run label, group folder, index in its group, runs.csv row)] of a sweep's finished runs."""
    from gsa_jax.analysis.sweeps.extraction import sweep_runs as runs

    return runs(sweep_dir)


def select_run(sweep_dir: str, env: str, policy: str, clusters: int, seed: int) -> str:
    """The folder of the one finished run of (env, policy, K = clusters, seed) in a sweep without swept
    hyperparameters (gsa export and gsa deploy take it); UserError where there is not exactly one."""
    from gsa_jax.analysis.sweeps.extraction import select

    return select(sweep_dir, env, policy, clusters, seed)


def iqm(scores: Any) -> float:
    """The interquartile mean of scores [runs, tasks] or [runs] (rliable), the point every table reports."""
    from gsa_jax.analysis.sweeps import stats

    return stats.iqm(scores)


def iqm_ci(scores: dict, seed: int = 0, reps: "int | None" = None) -> dict:
    """{name: (IQM, low, high)} of score matrices {name: [runs, tasks]}: rliable's 95% stratified bootstrap
    interval, with the tables' number of resamples unless reps is given."""
    from gsa_jax.analysis.sweeps import stats

    return stats.iqm_ci(scores, seed, stats.REPS if reps is None else reps)


def improvement_probability(pairs: dict, seed: int = 0, reps: "int | None" = None) -> dict:
    """{name: (P(X > Y), low, high)} for pairs {name: (X [runs, tasks], Y [runs, tasks])}: rliable's probability
    of improvement (ties count half) with its 95% stratified bootstrap interval."""
    from gsa_jax.analysis.sweeps import stats

    return stats.improvement_probability(pairs, seed, stats.REPS if reps is None else reps)
