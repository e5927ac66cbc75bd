"""The one store of trained runs: a group directory, the driver's store for a sweep's group and for a single
run alike (a single run is a group of one).

A group directory holds
  runs.csv          the runs' id columns, one row per run (its row order is the run axis of every array)
  config.json       what the runs compute (gsa_jax.running.trained reads a run's settings from it)
  metrics.npz       every tracked metric, [R, iterations done]          (after every chunk, keeps .prev)
  state.npz         the training state, [R, ...], and __done__           (after every chunk, keeps .prev)
  params.npz        parameters and observation statistics, [R, ...]      (after every chunk and at the end)
  failed.json, DONE at the end (the resume state is then dropped)
and for TensorBoard board_dir/<label>/ per run ([""]: board_dir itself). Checkpoints follow
gsa_jax.running.checkpoint (atomic, previous version kept); a file of another format is refused in one line.
"""

import json
import os
import sys
from typing import Any, Callable, Sequence

import jax
import numpy as np

from gsa_jax.running.checkpoint import load_pytree, read_with_fallback, save_npz_atomic, save_pytree, write_atomic
from gsa_jax.running.driver import Result, failed_mask
from gsa_jax.running.metrics import TIDY_METRICS
from gsa_jax.running.tensorboard import Board, follow
from gsa_jax.running.formats import LAYOUT_FILE, check_metrics, check_run_directory

# per run and iteration in metrics.npz: what resumes every view (failed_at is no CSV column; wall_s is a run's
# metrics.csv's wall clock, kept so a resumed run's table loses none of it)
TRACKED = TIDY_METRICS + ("failed_at", "wall_s")
STATE_FILES = ("state.npz", "state.prev.npz")


def warn(msg: str) -> None:
    """A line the user must see even with --quiet (stderr)."""
    print(msg, file=sys.stderr, flush=True)


def write_runs_table(root: str, runs: list, columns: Sequence[str]) -> None:
    """runs.csv: the id columns of every run, in run-axis order."""
    write_atomic(os.path.join(root, LAYOUT_FILE), "\n".join(
        [",".join(columns)] + [",".join(str(r[c]) for c in columns) for r in runs]) + "\n")


def failed_runs(runs: list, metrics: dict, upto: int) -> list:
    """[run dict + failed_at] of the runs that stopped at a NaN/inf."""
    failed = failed_mask(metrics, upto)
    return [{**r, "failed_at": int(metrics["failed_at"][i, upto - 1])} for i, r in enumerate(runs) if failed[i]]


def load_group_checkpoint(root: str, states: Any, iterations: int, log: Callable) -> tuple:
    """(states, metrics arrays [R, iterations], done) of a group's last intact checkpoint: state.npz
    (or state.prev.npz) and the metrics covering its iteration (metrics.npz or metrics.prev.npz)."""
    def read_state(p):
        with np.load(p) as f:
            done = int(f["__done__"])
        return load_pytree(p, states), done

    (states, done), _ = read_with_fallback(os.path.join(root, "state.npz"), read_state, log)

    def read_metrics(p):
        with np.load(p) as m:
            if int(m["__done__"]) < done:
                raise ValueError(f"holds {int(m['__done__'])} iterations, the state {done}")
            check_metrics(p, m.files, TRACKED)
            return {k: m[k][:, :done] for k in TRACKED}

    saved, _ = read_with_fallback(os.path.join(root, "metrics.npz"), read_metrics, log)
    metrics = {m: np.full((saved["iteration"].shape[0], iterations), np.nan, np.float64) for m in TRACKED}
    for k in TRACKED:
        metrics[k][:, :done] = saved[k]
    return states, metrics, done


def save_params(root: str, states: Any, runs: int) -> None:
    """params.npz: the first `runs` runs' parameters and observation statistics (a failed run's last finite ones)."""
    params = jax.device_get({"params": states.params, "obs_stats": states.obs_stats})
    save_pytree(os.path.join(root, "params.npz"), jax.tree.map(lambda x: x[:runs], params))


def finished_group(root: str, iterations: int) -> Result:
    """The driver Result of a group whose DONE marker exists, from its metrics.npz."""
    with np.load(os.path.join(root, "metrics.npz")) as m:
        check_metrics(os.path.join(root, "metrics.npz"), m.files, TRACKED)
        saved = {k: m[k] for k in m.files if k != "__done__"}
    done = saved["iteration"].shape[1]
    return Result(done, iterations, saved, "finished" if done >= iterations else "failed", {}, done)


class GroupStore:
    """The driver's store of one group in `root`: metrics.npz, params.npz and state.npz (last: the checkpoint
    is the state) after every chunk; at the end params.npz, failed.json and DONE. on_chunk(runs, metrics
    [len(runs), iterations], done) writes views of the metrics after every chunk (a sweep's tidy table, a
    single run's metrics.csv); on_finish(metrics, done, timing) once at the end, before DONE (a single run's
    result in its config.json). board: (directory, labels) of the runs' TensorBoard files, or None."""

    def __init__(self, root, runs, iterations, on_chunk=None, board=None, on_finish=None):
        self.root, self.runs, self.iterations = root, runs, iterations
        self.on_chunk, self.on_finish = on_chunk, on_finish
        self.board = Board(*board) if board and board[0] else None

    def path(self, name: str) -> str:
        return os.path.join(self.root, name)

    def has_checkpoint(self) -> bool:
        return any(os.path.exists(self.path(n)) for n in STATE_FILES)

    def load(self, template: Any) -> "tuple | None":
        """(state, metrics [R, done], done) of the checkpoint in root, or None if there is nothing to resume;
        the event files restart from it."""
        return follow(self.board, self.load_checkpoint(template) if self.has_checkpoint() else None)

    def load_checkpoint(self, template: Any) -> tuple:
        check_run_directory(self.root)
        return load_group_checkpoint(self.root, template, self.iterations, warn)

    def save(self, states: Any, metrics: dict, done: int) -> None:
        """Metrics (keeping its previous version), parameters, the views, then the state (keeping its previous
        version; it records `done`): a write that fails leaves the previous checkpoint whole."""
        save_npz_atomic(self.path("metrics.npz"), True, __done__=np.array(done),
                        **{k: metrics[k][:, :done] for k in TRACKED})
        save_params(self.root, states, len(self.runs))
        if self.board:
            self.board.append(metrics, done)
        if self.on_chunk:
            self.on_chunk(self.runs, {k: v[: len(self.runs)] for k, v in metrics.items()}, done)
        save_pytree(self.path("state.npz"), states, True, __done__=np.array(done))

    def finish(self, states: Any, metrics: dict, done: int, timing: dict) -> None:
        """Final parameters, failed.json, on_finish, DONE; drop the resume state (only needed to resume)."""
        save_params(self.root, states, len(self.runs))
        write_atomic(self.path("failed.json"), json.dumps(failed_runs(self.runs, metrics, done)))
        if self.on_finish:
            self.on_finish(metrics, done, timing)
        write_atomic(self.path("DONE"), json.dumps(timing))
        for name in STATE_FILES + ("metrics.prev.npz",):
            if os.path.exists(self.path(name)):
                os.unlink(self.path(name))
