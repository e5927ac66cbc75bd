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

train_run, run_sweep, export_controller, answer_task and verify_controller run the command itself with the keyword options as its flags
(options_argv: the same checks, files and resumption as on the command line); a bad input raises
gsa_jax.errors.UserError (one line). The names are not the commands' own (gsa_jax.train, gsa_jax.verify, ... are the
`python -m` modules and packages, which an import binds on the package).
"""

import os
from typing import Any

from gsa_jax.errors import UserError

__all__ = ["answer_task", "export_controller", "load_controller", "options_argv", "read_csv", "read_record",
           "run_metadata", "run_sweep", "score_controller", "train_run", "verify_controller", "write_csv"]


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
