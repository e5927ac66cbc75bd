"""Worker supervision: run worker processes, watch their heartbeats, and restart (from the last
checkpoint) a worker that stops making progress -- XLA:CPU has been seen to hang in large vmapped MJX
programs. Used by gsa sweep; gsa bench starts its workers with the same environment.

A worker reports progress by rewriting `heartbeat.json` ({"count": chunks done, "durations": [s]})
in its heartbeat directory after every chunk.
"""

import json
import os
import signal
import statistics
import subprocess
import time
from typing import Callable

from envs.physics import LOCAL_WORKERS_ENV
from gsa_jax.running.checkpoint import write_atomic

SINGLE_THREAD_EIGEN = "--xla_cpu_multi_thread_eigen=false"


def worker_env(processes: int) -> dict:
    """Environment of `processes` local worker processes. With a worker on every core, XLA's Eigen ops
    run single-threaded in each (their thread pools would only compete with the other workers; 256
    hopper runs on 2 cores: 1.05-1.12x, experiments/bench_eigen_threads/), unless XLA_FLAGS already sets it;
    and each worker's MuJoCo C threads (physics backend 'c', threads 0) take its share of the cores."""
    env = dict(os.environ, **{LOCAL_WORKERS_ENV: str(processes)})  # physics backend 'c' threads: envs.physics
    if 1 < (os.cpu_count() or 1) <= processes and "xla_cpu_multi_thread_eigen" not in env.get("XLA_FLAGS", ""):
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + SINGLE_THREAD_EIGEN).strip()
    return env


def heartbeat_writer(directory: str) -> Callable:
    """A function a worker calls after every chunk with the chunk's duration: rewrites
    directory/heartbeat.json atomically."""
    beats = {"count": 0, "durations": []}

    def beat(duration):
        beats["count"] += 1
        beats["durations"] = (beats["durations"] + [duration])[-50:]
        write_atomic(os.path.join(directory, "heartbeat.json"), json.dumps(beats))

    return beat


def start_worker(cmd: list, heartbeat_dir: str, processes: int, restarts: int = 0) -> dict:
    """Start one worker command (its own session, so a kill takes its children too) with a fresh heartbeat."""
    hb = os.path.join(heartbeat_dir, "heartbeat.json")
    if os.path.exists(hb):
        os.unlink(hb)
    proc = subprocess.Popen(cmd, start_new_session=True, env=worker_env(processes))
    return {"proc": proc, "hb": hb, "seen": None, "last": time.time(), "durations": [], "restarts": restarts}


def stall_limit(worker: dict, watchdog_min_s: float) -> float:
    """Seconds without a new heartbeat after which a worker counts as hung: max(watchdog_min_s, 10 x its
    median chunk time); before its first chunk (compiling, minutes for big groups) max(3 x that, 600)."""
    if worker["durations"]:
        return max(watchdog_min_s, 10 * statistics.median(worker["durations"]))
    return max(3 * watchdog_min_s, 600.0)


def read_heartbeat(worker: dict) -> None:
    """Note a new heartbeat of the worker (count changed) with its time."""
    try:
        with open(worker["hb"]) as f:
            hb = json.load(f)
        if hb["count"] != worker["seen"]:
            worker["seen"], worker["last"], worker["durations"] = hb["count"], time.time(), hb["durations"][-20:]
    except (OSError, ValueError, KeyError):
        pass


def kill(worker: dict) -> None:
    os.killpg(worker["proc"].pid, signal.SIGKILL)
    worker["proc"].wait()


def wait_for_exit(workers: dict, seconds: float, step_s: float = 0.05) -> None:
    """Sleep up to `seconds`, returning as soon as a worker process has exited (a finished sweep ends when its
    last worker does, not up to a second later)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and all(w["proc"].poll() is None for w in workers.values()):
        time.sleep(step_s)


def supervise(worker_cmds: list, heartbeat_dirs: list, watchdog_min_s: float, max_restarts: int,
              log: Callable = print) -> int:
    """Run one worker process per command; kill and restart (from its last checkpoint) any worker whose
    heartbeat stalls (stall_limit). Returns the first non-zero exit status (3: a worker hung more than
    max_restarts times), or 0; 130 when interrupted."""
    n = len(worker_cmds)
    workers = {i: start_worker(worker_cmds[i], heartbeat_dirs[i], n) for i in range(n)}
    status = 0
    try:
        while workers:
            wait_for_exit(workers, 1.0)
            for i, w in list(workers.items()):
                rc = w["proc"].poll()
                if rc is not None:
                    del workers[i]
                    status = status or rc
                    continue
                read_heartbeat(w)
                limit = stall_limit(w, watchdog_min_s)
                if time.time() - w["last"] <= limit:
                    continue
                log(f"watchdog: worker {i} made no progress for {time.time() - w['last']:.0f}s (limit {limit:.0f}s); "
                    f"killing it and restarting from its last checkpoint")
                kill(w)
                if w["restarts"] >= max_restarts:
                    log(f"watchdog: worker {i} gave up after {max_restarts} restarts")
                    del workers[i]
                    status = status or 3
                    continue
                workers[i] = start_worker(worker_cmds[i], heartbeat_dirs[i], n, w["restarts"] + 1)
    except KeyboardInterrupt:
        for w in workers.values():
            kill(w)
        log("\ninterrupted; finished chunks are saved: run the same command again to resume")
        return 130
    return status
