"""TensorBoard event files of training runs: the metrics already in metrics.csv, one event file per run,
so that `tensorboard --logdir DIR` shows and compares runs as SB3's and CleanRL's users are used to.

A single run writes DIR/tensorboard/events.out.tfevents.gsa_jax; a sweep writes
DIR/tensorboard/<env>-<policy>[-K<k>]-s<seed>/events.out.tfevents.gsa_jax (one TensorBoard run per sweep
run). The x axis is env steps. Scalars are grouped as returns/ (episode_return, eval_return,
eval_failures), schedule/ (epsilon, sigma_min, lr) and ppo/ (losses, KL, clip fraction, gradient norm,
partition entropy, clusters used). NaN entries (not evaluated, after a NaN/inf failure) are left out.

The files follow the stores' checkpoints: a run that resumes rewrites its event files from the checkpoint's
metrics, so a chunk lost to a kill appears once, not twice. Records are framed by tensorboardX's writer
(its CRC); the event protobufs are tensorboardX's.
"""

import os
import struct
import time
from collections import defaultdict

import numpy as np
from tensorboardX.proto.event_pb2 import Event
from tensorboardX.proto.summary_pb2 import Summary
from tensorboardX.record_writer import RecordWriter

from gsa_jax.running.metrics import TIDY_METRICS

FILE_NAME = "events.out.tfevents.gsa_jax"
SECTIONS = {"episode_return": "returns", "eval_return": "returns", "eval_failures": "returns",
            "epsilon": "schedule", "sigma_min": "schedule", "lr": "schedule"}
SCALARS = tuple(m for m in TIDY_METRICS if m not in ("iteration", "env_steps"))


def tag(metric: str) -> str:
    """The TensorBoard tag of a metric, e.g. 'returns/eval_return', 'ppo/value_loss'."""
    return f"{SECTIONS.get(metric, 'ppo')}/{metric}"


class _AppendingWriter(RecordWriter):
    """tensorboardX's record writer on a file opened for appending (its own opens a new file)."""

    def __init__(self, path):  # not super().__init__: it would truncate the file
        self.path, self._writer = path, open(path, "ab")


def row_events(metrics: dict, run: int, start: int, stop: int, wall_time: float) -> list:
    """Serialized events [bytes] of run `run`'s iterations start..stop-1 of metrics {name: [R, iterations]}."""
    out = []
    for i in range(start, stop):
        step = metrics["env_steps"][run, i]
        if not np.isfinite(step):
            continue
        values = [Summary.Value(tag=tag(m), simple_value=float(metrics[m][run, i]))
                  for m in SCALARS if m in metrics and np.isfinite(metrics[m][run, i])]
        if values:
            out.append(Event(wall_time=wall_time, step=int(step), summary=Summary(value=values)).SerializeToString())
    return out


def follow(board: "Board | None", saved: "tuple | None") -> "tuple | None":
    """The store's load result `saved` ((state, metrics, done) or None), after restarting `board` (or None)
    from it: the event files start where the checkpoint does."""
    if board is not None:
        board.restart(saved[1] if saved else {}, saved[2] if saved else 0)
    return saved


class Board:
    """The event files of a group's real runs: logdir/<label>/FILE_NAME for each label (label '' : logdir itself).
    restart(metrics, done) writes each file anew from iterations [0, done) (a fresh or resumed run);
    append(metrics, done) adds the iterations since the last call."""

    def __init__(self, logdir, labels):
        self.paths = [os.path.join(logdir, label, FILE_NAME) for label in labels]
        self.done = 0

    def restart(self, metrics: dict, done: int) -> None:
        for run, path in enumerate(self.paths):
            os.makedirs(os.path.dirname(path), exist_ok=True)
            tmp = path + ".tmp"
            w = RecordWriter(tmp)
            w.write(Event(wall_time=time.time(), file_version="brain.Event:2").SerializeToString())
            for data in row_events(metrics, run, 0, done, time.time()):
                w.write(data)
            w.close()
            os.replace(tmp, path)
        self.done = done

    def append(self, metrics: dict, done: int) -> None:
        for run, path in enumerate(self.paths):
            w = _AppendingWriter(path)
            for data in row_events(metrics, run, self.done, done, time.time()):
                w.write(data)
            w.close()
        self.done = done


def read_scalars(path: str) -> dict:
    """{tag: [(step, value)]} of an event file, in file order (to check what was written; TensorBoard's own
    reader needs the tensorboard package)."""
    with open(path, "rb") as f:
        data = f.read()
    out, pos = defaultdict(list), 0
    while pos < len(data):
        (n,) = struct.unpack("Q", data[pos:pos + 8])
        event = Event.FromString(data[pos + 12:pos + 12 + n])
        pos += 12 + n + 4
        for v in event.summary.value:
            out[v.tag].append((event.step, v.simple_value))
    return dict(out)
