"""gsa_jax.running.driver on a toy program (NumPy, nothing to compile): resume equals an uninterrupted run, the
evaluation schedule, a group stops once every run failed, interrupts and full disks keep what is saved."""

import errno

import numpy as np
import pytest

from gsa_jax.running.driver import HOST_METRICS, Plan, Program, drive, eval_due, rows_before_failure
from gsa_jax.running.metrics import ITERATION_METRICS


def toy_program(runs=3, fail=None, interrupt_at=None):
    """A run's state is its iteration count; its 'return' is 10 * run + iteration. fail: {run: iteration}
    at which that run's failed_at is set (and stays)."""
    fail = fail or {}

    def run(state, hps):
        it = state["iteration"]
        if interrupt_at is not None and it[0] >= interrupt_at:
            raise KeyboardInterrupt
        chunk = hps["chunk"]
        iters = it[:, None] + np.arange(1, chunk + 1)[None]  # [R, chunk]
        m = {k: np.zeros((runs, chunk)) for k in ITERATION_METRICS}
        m["iteration"] = iters
        m["episode_return"] = 10.0 * np.arange(runs)[:, None] + iters
        fa = np.array([[fail[r] if r in fail and i >= fail[r] else -1 for i in row] for r, row in enumerate(iters)])
        m["failed_at"] = fa
        return {"iteration": it + chunk}, m

    def evaluate(state, hps, it):
        return 100.0 + np.arange(runs) + it, np.arange(runs) * (it == 8)  # run r loses r episodes at 8

    state = {"iteration": np.zeros(runs, np.int64)}
    return Program(runs, state, {"chunk": 2}, run, evaluate, lambda t: {k: np.array(v) for k, v in t.items()})


class MemoryStore:
    def __init__(self, fail_save_at=None):
        self.saved, self.finished, self.fail_save_at = None, None, fail_save_at

    def load(self, template):
        return None if self.saved is None else self.saved

    def save(self, state, metrics, done):
        if self.fail_save_at == done:
            raise OSError(errno.ENOSPC, "no space")
        self.saved = ({k: np.array(v) for k, v in state.items()}, {k: v.copy() for k, v in metrics.items()}, done)

    def finish(self, state, metrics, done, timing):
        self.finished = done


PLAN = Plan(iterations=8, chunk=2, batch=5, real_runs=3, eval_every=4)


def test_uninterrupted_run_records_every_metric():
    store = MemoryStore()
    res = drive(toy_program(), store, PLAN, log=lambda m: None)
    assert res.status == "finished" and res.finished and res.done == 8 and store.finished == 8
    assert set(res.metrics) == set(HOST_METRICS)
    np.testing.assert_array_equal(res.metrics["episode_return"][1], 10 + np.arange(1, 9))
    evaluated = np.where(np.isfinite(res.metrics["eval_return"][0]))[0] + 1
    assert evaluated.tolist() == [4, 8] and [eval_due(PLAN, i) for i in (2, 4, 6, 8)] == [False, True, False, True]
    assert res.metrics["eval_return"][2, 3] == 100 + 2 + 4
    # failed evaluation episodes are recorded where evaluated (0 is a count), NaN elsewhere
    np.testing.assert_array_equal(res.metrics["eval_failures"][:, [3, 7]], [[0, 0], [0, 1], [0, 2]])
    assert np.isnan(res.metrics["eval_failures"][:, [0, 1, 2, 4, 5, 6]]).all()
    assert res.timing["env_steps_run"] == 3 * 8 * 5


def test_a_plan_with_eval_at_evaluates_after_those_chunks_only():
    plan = PLAN._replace(eval_every=0, eval_at=(2, 6))
    res = drive(toy_program(), MemoryStore(), plan, log=lambda m: None)
    assert (np.where(np.isfinite(res.metrics["eval_return"][0]))[0] + 1).tolist() == [2, 6]
    assert [eval_due(plan, i) for i in (2, 4, 6, 8)] == [True, False, True, False]


def test_stop_and_resume_equals_uninterrupted():
    full = drive(toy_program(), MemoryStore(), PLAN, log=lambda m: None)
    store, lines = MemoryStore(), []
    first = drive(toy_program(), store, PLAN._replace(stop_after_chunks=1), log=lines.append)
    assert first.status == "stopped" and not first.finished and first.done == 2 and store.finished is None
    second = drive(toy_program(), store, PLAN, log=lines.append)
    assert second.done == 8 and "resumed at iteration 2/8" in lines[1]
    for k in HOST_METRICS:
        if k != "wall_s":
            np.testing.assert_array_equal(second.metrics[k], full.metrics[k], err_msg=k)


def test_group_stops_when_every_run_failed():
    store = MemoryStore()
    res = drive(toy_program(fail={0: 3, 1: 5, 2: 2}), store, PLAN, log=lambda m: None)
    assert res.status == "failed" and res.finished and res.done == 6 and store.finished == 6
    assert [rows_before_failure(res.metrics, i, res.done) for i in range(3)] == [2, 4, 1]
    assert res.timing["env_steps_run"] == (2 + 4 + 1) * 5  # iterations before each failure


def test_one_failed_run_does_not_stop_the_others():
    res = drive(toy_program(fail={1: 3}), MemoryStore(), PLAN, log=lambda m: None)
    assert res.status == "finished" and res.done == 8
    assert np.isnan(res.metrics["eval_return"][1, 3]) and res.metrics["eval_return"][0, 3] == 104


def test_interrupt_and_full_disk_keep_the_last_checkpoint():
    store = MemoryStore()
    res = drive(toy_program(interrupt_at=4), store, PLAN, log=lambda m: None)
    assert res.status == "interrupted" and res.intact == 4 and store.finished is None and store.saved[2] == 4
    with pytest.raises(OSError) as e:
        drive(toy_program(), MemoryStore(fail_save_at=6), PLAN._replace(tag="idp/mixture"), log=lambda m: None)
    assert e.value.last_intact == "iteration 4 of group idp/mixture"


def test_a_ctrl_c_that_lands_in_a_gc_callback_stops_the_run_after_the_chunk_it_came_in(capfd):
    """A SIGINT whose handler runs inside a garbage collector's callback (as JAX's _xla_gc_callback, where Python
    drops an exception) still stops the run: after the chunk it came in is saved, status 'interrupted'. Before,
    the run went on to the end. SIGINT's handler is Python's default during the test and after it."""
    import gc
    import os
    import signal

    armed = [True]

    def sigint_inside(phase, info):
        if phase == "start" and armed:
            armed.clear()
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10000):  # the handler runs here, in this callback's frame
                pass

    program = toy_program()

    def run(state, hps):
        if state["iteration"][0] == 2:
            gc.callbacks.append(sigint_inside)
            try:
                gc.collect()
            finally:
                gc.callbacks.remove(sigint_inside)
        return program.run(state, hps)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        store = MemoryStore()
        res = drive(program._replace(run=run), store, PLAN, log=lambda m: None)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    assert not armed  # the callback sent it
    assert res.status == "interrupted" and res.intact == 4 and store.saved[2] == 4 and store.finished is None
    assert "Exception ignored" not in capfd.readouterr().err  # not raised inside the callback, where Python drops it


def test_a_ctrl_c_noted_after_the_last_chunk_is_raised_once_the_result_is_stored():
    """A SIGINT that lands in a gc callback after the last chunk's check (here in its progress line): the run
    finishes and is stored, then drive raises KeyboardInterrupt (a sweep does not go on to its next group)."""
    import gc
    import os
    import signal

    def sigint_inside(phase, info):
        if phase == "start":
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10000):
                pass

    def log(line):
        if line.startswith(f"it {PLAN.iterations}/"):
            gc.callbacks.append(sigint_inside)
            try:
                gc.collect()
            finally:
                gc.callbacks.remove(sigint_inside)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    store = MemoryStore()
    try:
        with pytest.raises(KeyboardInterrupt):
            drive(toy_program(), store, PLAN._replace(real_runs=1), log=log)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert store.finished == PLAN.iterations and store.saved[2] == PLAN.iterations


def test_a_group_chunk_in_which_no_episode_ended_says_so_not_nan():
    """Long episodes (dm_control's 1,000 steps) end in some chunks only: the progress line says no episode ended."""
    from gsa_jax.running.driver import progress_line

    metrics = {"episode_return": np.full((3, 8), np.nan), "eval_return": np.full((3, 8), np.nan),
               "failed_at": np.full((3, 8), -1)}
    line = progress_line(PLAN, metrics, 2, 1000.0, 0.5)
    assert "no episode ended in this chunk" in line and "nan" not in line
    metrics["episode_return"][:, 1] = [1.0, 2.0, 3.0]
    assert "return best 3.0 median 2.0" in progress_line(PLAN, metrics, 2, 1000.0, 0.5)
