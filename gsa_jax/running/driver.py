"""The run driver: trains a group of R runs in compiled chunks -- a single run is a group of one.

    result = drive(program, store, plan, log=print)

One loop for `gsa train` and for every group of a sweep. It owns resume, the chunk
loop, atomic checkpoints after every chunk (through the store), the heartbeat, the NaN guard's
outcome (a run whose loss or parameters turned NaN/inf is frozen inside the compiled program; the
group stops once every run has failed), the deterministic-evaluation schedule, progress lines with
steps/s and ETA, and the timings. What differs between a single run and a sweep group is
outside it: the compiled program (gsa_jax.running.programs); both are stored by gsa_jax.running.store.GroupStore.

A store has three methods: `load(state)` -> (state, metrics, done) of the last intact checkpoint or
None; `save(state, metrics, done)` after every chunk; `finish(state, metrics, done, timing)` once
all iterations are done. Metrics live on the host as {name: float64 [R, iterations]}: the
compiled program's ITERATION_METRICS and failed_at, plus eval_return, eval_failures and wall_s.
"""

import contextlib
import gc
import math
import signal
import threading
import time
from typing import Any, Callable, Iterator, NamedTuple

import numpy as np

from gsa_jax.running.metrics import EVAL_METRICS, ITERATION_METRICS

HOST_METRICS = ITERATION_METRICS + ("failed_at",) + EVAL_METRICS + ("wall_s",)


class Program(NamedTuple):
    """A compiled training program of `runs` runs, its state with a leading run axis [R, ...]. run(state, hps)
    -> (state, metrics {name: [R, chunk]}); evaluate(state, hps, iteration) -> ([R], [R]) (or scalars): the
    deterministic controllers' mean returns and failed episodes (gsa_jax.algorithm.episodes), or None;
    place(host tree) -> the tree on the program's devices; how: how it was obtained."""

    runs: int
    state: object
    hps: object
    run: Callable
    evaluate: Callable | None
    place: Callable
    how: str = "compiled"


class Plan(NamedTuple):
    """What to train: iterations (a multiple of chunk), chunk, batch (env steps per run and iteration),
    real_runs (the program's first real_runs runs are real, the rest padding copies), eval_every (0:
    never), stop_after_chunks (None: to the end; else stop resumably after that many chunks), tag
    (progress prefix), mixture (progress shows the epsilon / sigma_min schedules), eval_at (where not empty, in
    eval_every's place: the iterations, chunk ends, after which to evaluate)."""

    iterations: int
    chunk: int
    batch: int
    real_runs: int = 1
    eval_every: int = 0
    stop_after_chunks: int | None = None
    tag: str = ""
    mixture: bool = False
    eval_at: tuple = ()


class Result(NamedTuple):
    """done: iterations trained (intact: of those, saved); metrics {name: [R, iterations]} (NaN after `done`); status:
    'finished', 'stopped' (as asked, resumable), 'failed' (every run hit NaN/inf: final, the store
    finished it), 'interrupted';
    timing: compile_s, train_s, eval_s, env_steps_run, env_steps_per_s, start_iteration."""

    done: int
    iterations: int
    metrics: dict
    status: str
    timing: dict
    intact: int = 0

    @property
    def finished(self) -> bool:
        """Nothing left to train: every iteration done, or every run failed."""
        return self.done >= self.iterations or self.status == "failed"


def empty_metrics(runs: int, iterations: int) -> dict:
    return {k: np.full((runs, iterations), np.nan, np.float64) for k in HOST_METRICS}


def failed_mask(metrics: dict, done: int) -> np.ndarray:
    """[R] bool: runs frozen at a NaN/inf by iteration `done`."""
    return metrics["failed_at"][:, done - 1] >= 0 if done else np.zeros(metrics["failed_at"].shape[0], bool)


def eval_due(plan: Plan, it: int) -> bool:
    """Whether the deterministic controller is evaluated after the chunk that ends at iteration `it`."""
    if plan.eval_at:
        return it in plan.eval_at
    return bool(plan.eval_every) and (it % plan.eval_every < plan.chunk or it == plan.iterations)


def drive(program: Program, store: Any, plan: Plan, log: Callable = print, heartbeat: "Callable | None" = None,
          clock_start: "float | None" = None) -> Result:
    """Train (or resume) the program's runs as the plan says; checkpoint through the store. Returns a
    Result. A KeyboardInterrupt ends it with status 'interrupted' (everything saved stays saved); one noted only
    after the last chunk (interrupts_noted) is raised after the result is stored. A DiskFullError propagates with
    `.last_intact` naming the last intact iteration."""
    t0 = clock_start if clock_start is not None else time.perf_counter()
    compile_s = time.perf_counter() - t0
    state, metrics, done = resume(program, store, plan, log)
    loop = {"state": state, "done": done, "intact": done, "chunks": 0, "steps": 0, "eval_s": 0.0,
            "t_train": time.perf_counter(), "t0": t0, "start": done}
    status, noted = "stopped", {"sigint": False}
    try:
        with interrupts_noted() as noted:
            status = chunk_loop(program, store, plan, metrics, loop, log, heartbeat, noted)
    except KeyboardInterrupt:
        status = "interrupted"
    except OSError as e:
        e.last_intact = f"iteration {loop['intact']}" + (f" of group {plan.tag}" if plan.tag else "")
        raise
    train_s = time.perf_counter() - loop["t_train"] - loop["eval_s"]
    timing = {"compile_s": round(compile_s, 2), "train_s": round(train_s, 2), "eval_s": round(loop["eval_s"], 2),
              "wall_s": round(time.perf_counter() - t0, 2), "env_steps_run": loop["steps"], "start_iteration": loop["start"],
              "env_steps_per_s": round(loop["steps"] / max(train_s, 1e-9), 1)}
    if (loop["done"] >= plan.iterations and status != "interrupted") or status == "failed":
        store.finish(loop["state"], metrics, loop["done"], timing)
    if noted["sigint"] and status != "interrupted":  # noted after the last chunk's check: raised once all is saved
        raise KeyboardInterrupt
    return Result(loop["done"], plan.iterations, metrics, status, timing, loop["intact"])


def resume(program: Program, store: Any, plan: Plan, log: Callable) -> tuple:
    """(state, metrics [R, iterations], done): the store's last intact checkpoint, or the fresh program."""
    metrics = empty_metrics(program.runs, plan.iterations)
    saved = store.load(program.state)
    if saved is None:
        return program.state, metrics, 0
    state, old, done = saved
    for k, v in old.items():
        metrics[k][:, :done] = v[:, :done]
    log(f"{prefix(plan)}resumed at iteration {done}/{plan.iterations}")
    return program.place(state), metrics, done


def prefix(plan: Plan) -> str:
    return f"[{plan.tag}] " if plan.tag else ""


@contextlib.contextmanager
def interrupts_noted() -> Iterator[dict]:
    """Yields {'sigint': bool}. In the main thread, where SIGINT has Python's default handler: a SIGINT while the block
    runs sets the flag, for chunk_loop to stop at its next check, and raises KeyboardInterrupt as that handler does,
    except inside a garbage collector's callback (gc.callbacks; JAX keeps one), where Python would drop the exception
    with a traceback on stderr: a Ctrl-C that landed there stopped nothing before. The previous handler is restored
    on exit."""
    noted = {"sigint": False}
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield noted
        return

    def note(signum, frame):
        noted["sigint"] = True
        if frame is None or frame.f_code not in {getattr(fn, "__code__", None) for fn in gc.callbacks}:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, previous)


def chunk_loop(program: Program, store: Any, plan: Plan, metrics: dict, loop: dict, log: Callable,
               heartbeat: "Callable | None", noted: dict) -> str:
    """Chunks until done, stopped as asked, or every run failed; returns the status. Raises KeyboardInterrupt
    after a chunk is saved where noted['sigint'] is set (interrupts_noted)."""
    while loop["done"] < plan.iterations:
        tc = time.perf_counter()
        loop["state"], m = program.run(loop["state"], program.hps)
        done = record_chunk(program, plan, metrics, loop, m)
        store.save(loop["state"], metrics, done)
        loop["intact"] = done
        if noted["sigint"]:
            raise KeyboardInterrupt
        if heartbeat:
            heartbeat(time.perf_counter() - tc)
        sps = loop["steps"] / max(time.perf_counter() - loop["t_train"] - loop["eval_s"], 1e-9)
        if failed_mask(metrics, done)[: plan.real_runs].all():
            return "failed"
        log(progress_line(plan, metrics, done, sps, time.perf_counter() - tc))
        if plan.stop_after_chunks is not None and loop["chunks"] >= plan.stop_after_chunks and done < plan.iterations:
            return "stopped"
    return "finished"


def record_chunk(program: Program, plan: Plan, metrics: dict, loop: dict, m: dict) -> int:
    """A chunk's metrics into the host arrays, its evaluation when due, steps and clocks. Returns done."""
    import jax  # here, its one use: the formatting helpers (fmt, duration) load without JAX (a command's --help)

    m = jax.device_get(m)
    done, chunk, runs = loop["done"], plan.chunk, program.runs
    for k in ITERATION_METRICS + ("failed_at",):
        metrics[k][:, done:done + chunk] = np.reshape(m[k], (runs, chunk))
    it = done + chunk
    failed = failed_mask(metrics, it)
    if eval_due(plan, it) and not failed[: plan.real_runs].all():
        te = time.perf_counter()
        evaluation = jax.device_get(program.evaluate(loop["state"], program.hps, it))
        for name, values in zip(EVAL_METRICS, evaluation):
            metrics[name][:, it - 1] = np.where(failed, np.nan, np.reshape(np.asarray(values, np.float64), (runs,)))
        loop["eval_s"] += time.perf_counter() - te
    metrics["wall_s"][:, done:it] = round(time.perf_counter() - loop["t0"], 3)
    good = [rows_before_failure(metrics, i, it) - done for i in range(plan.real_runs)]
    loop["steps"] += sum(max(0, g) for g in good) * plan.batch
    loop["done"], loop["chunks"] = it, loop["chunks"] + 1
    return it


def rows_before_failure(metrics: dict, i: int, upto: int) -> int:
    """Iterations of run i that count: up to `upto`, ending before the iteration where it failed."""
    failed_at = int(metrics["failed_at"][i, upto - 1]) if upto else -1
    return upto if failed_at < 0 else min(upto, failed_at - 1)


def progress_line(plan: Plan, metrics: dict, done: int, sps: float, chunk_s: float) -> str:
    """One line after a chunk: iteration, return (a single run: its mean over the chunk and its last
    evaluation; a group: best and median run), throughput, ETA."""
    runs = plan.real_runs
    eta = (plan.iterations - done) * plan.batch * runs / max(sps, 1e-9)
    recent = metrics["episode_return"][:runs, max(0, done - plan.chunk):done]
    per_run = np.array([np.nanmean(r) if np.any(np.isfinite(r)) else np.nan for r in recent])
    ev = metrics["eval_return"][:runs, done - 1]
    if runs == 1:
        line = (f"it {done}/{plan.iterations} | steps {done * plan.batch:,} | return {fmt(per_run[0], '.1f')}"
                + (f" | eval {ev[0]:.1f}" if np.isfinite(ev[0]) else "") + f" | {sps:,.0f} steps/s | ETA {duration(eta)}")
        if plan.mixture:
            line += (f" | eps {metrics['epsilon'][0, done - 1]:.3f} sigma_min {metrics['sigma_min'][0, done - 1]:.4f}"
                     f" | clusters used {int(metrics['clusters_used'][0, done - 1])}")
        return prefix(plan) + line + f" | chunk {chunk_s:.1f}s"
    failed = int(failed_mask(metrics, done)[:runs].sum())
    returns = (f"best {np.nanmax(per_run):.1f} median {np.nanmedian(per_run):.1f}" if np.isfinite(per_run).any()
               else "- (no episode ended in this chunk)")
    return (f"{prefix(plan)}it {done}/{plan.iterations} | {sps:,.0f} env-steps/s | ETA {duration(eta)} | return "
            f"{returns}" + (f" | eval median {np.nanmedian(ev):.1f}" if np.isfinite(ev).any() else "")
            + (f" | {failed} run(s) failed (NaN/inf)" if failed else "") + f" | chunk {chunk_s:.1f}s")


def fmt(x: "float | None", spec: str) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def duration(s: float) -> str:
    s = int(max(0, s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"
