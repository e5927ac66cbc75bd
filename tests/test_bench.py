"""The benchmark end to end at a tiny size (every field of bench.json, the plot), its time-profile
arithmetic, and hang detection + retry of its workers."""

import json
import os
import sys

import pytest

from gsa_jax.commands import bench
from gsa_jax.bench import main
from gsa_jax.benchmark import measure, workers
from gsa_jax.benchmark.measure import BenchError, measure_mujoco_c, run_workers


def test_mujoco_c_reference():
    r = measure_mujoco_c("inverted_double_pendulum", batch=16, steps=20, repeats=1)
    assert r["env_steps_per_s"] > 0 and r["physics_steps_per_s"] == r["env_steps_per_s"] * r["substeps_per_env_step"]


def test_worker_env_single_threads_eigen_with_a_worker_per_core(monkeypatch):
    from gsa_jax.running.supervise import SINGLE_THREAD_EIGEN, worker_env

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    assert worker_env(2)["XLA_FLAGS"] == "--xla_dump_to=/tmp/x " + SINGLE_THREAD_EIGEN
    assert worker_env(1)["XLA_FLAGS"] == "--xla_dump_to=/tmp/x"
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")  # the user's choice stands
    assert worker_env(2)["XLA_FLAGS"] == "--xla_cpu_multi_thread_eigen=true"
    monkeypatch.setattr(os, "cpu_count", lambda: 16)  # 2 workers on 16 cores: Eigen keeps its threads
    monkeypatch.setenv("XLA_FLAGS", "")
    assert worker_env(2)["XLA_FLAGS"] == ""


def test_bench_writes_report(tmp_path):
    out = tmp_path / "bench"
    assert main(["--env", "inverted_double_pendulum", "--sizes", "2", "--policies", "mixture", "--raw-batches", "8",
                 "--processes", "2", "--repeats", "1", "--profile-runs", "0", "--solver-variant", "none", "--out", str(out)]) == 0
    report = json.loads((out / "bench.json").read_text())
    assert [(s["runs"], s["processes"]) for s in report["sweeps"]] == [(2, 2)]
    assert [(r["batch"], r["processes"]) for r in report["raw"]] == [(8, 2)]
    for s in report["sweeps"] + report["raw"]:
        assert s["env_steps_per_s"] > 0 and s["compile_s"] > 0
        assert abs(s["ratio_vs_mujoco_c"] - s["env_steps_per_s"] / report["mujoco_c"]["env_steps_per_s"]) < 1e-9
        # worker 0 compiled, worker 1 loaded its program (the tiny IDP programs take > 1 s to compile)
        assert s["compile_per_process"][0] == "compiled" and s["compile_per_process"][1].startswith("loaded after waiting")
    assert report["sweeps"][0]["peak_rss_mib"] > 100
    assert report["versions"]["jax"] and (out / "bench.png").stat().st_size > 10_000


def test_solver_variant_lines(tmp_path, monkeypatch):
    """The default grid adds the largest mixture sweep and raw batch on all cores with the cheaper solver,
    and MuJoCo C with it; each ratio is against MuJoCo C with the same solver (workers faked here: the
    solver option itself is tested in test_solver.py)."""
    calls = []

    def sweep(cell, repeats, log=print):
        assert cell.value_target == "gae" and cell.backend == "mjx"  # the default critic and physics
        calls.append(("sweep", cell.policy, cell.runs, cell.processes, cell.solver))
        return {"env": cell.env, "policy": cell.policy, "runs": cell.runs, "processes": cell.processes,
                "env_steps_per_s": 1000.0 * (2 if cell.solver else 1), "compile_s": 1.0, "peak_rss_mib": 500.0,
                **measure.solver_field(cell.solver)}

    def raw(env, batch, processes, repeats, solver=None, log=print, backend=None, physics_threads=0):
        assert backend == "mjx"
        calls.append(("raw", batch, processes, solver))
        return {"env": env, "batch": batch, "processes": processes, "env_steps_per_s": 3000.0, "compile_s": 1.0,
                **measure.solver_field(solver)}

    def c(env, solver=None, **kw):
        return {"env": env, "threads": 2, "batch": 256, "substeps_per_env_step": 4, "env_steps_per_s": 10000.0 * (4 if solver else 1),
                **measure.solver_field(solver)}

    monkeypatch.setattr(bench, "measure_sweep", sweep)
    monkeypatch.setattr(bench, "measure_raw", raw)
    monkeypatch.setattr(bench, "measure_mujoco_c", c)
    out = tmp_path / "b"
    assert main(["--sizes", "1,4", "--raw-batches", "8,64", "--processes", "1,2", "--out", str(out)]) == 0
    v = measure.SOLVER_VARIANT
    assert calls == [("raw", 8, 1, None), ("raw", 8, 2, None), ("raw", 64, 1, None), ("raw", 64, 2, None), ("raw", 64, 2, v),
                     ("sweep", "mixture", 1, 1, None), ("sweep", "mixture", 4, 1, None), ("sweep", "mixture", 4, 2, None),
                     ("sweep", "mlp", 4, 2, None), ("sweep", "mixture", 4, 2, v)]
    report = json.loads((out / "bench.json").read_text())
    fast = report["sweeps"][-1]
    assert fast["solver"] == {"iterations": v[0], "ls_iterations": v[1]}
    assert fast["ratio_vs_mujoco_c"] == pytest.approx(2000 / 40000) and fast["ratio_vs_mujoco_c_task_solver"] == pytest.approx(0.2)
    assert report["sweeps"][0]["ratio_vs_mujoco_c"] == pytest.approx(0.1)
    assert report["mujoco_c_solver_variant"]["env_steps_per_s"] == 40000 and (out / "bench.png").exists()


def test_randomized_twins_and_their_ratio(tmp_path, monkeypatch):
    """--randomize measures each sweep nominal and then randomized (the randomization reaching the workers' cell),
    and records the randomized one's ratio_vs_nominal; a randomization the task cannot take is refused first."""
    cells = []

    def sweep(cell, repeats, log=print):
        cells.append(cell)
        return {"env": cell.env, "policy": cell.policy, "runs": cell.runs, "processes": cell.processes,
                "randomize": cell.randomize, "env_steps_per_s": 900.0 if cell.randomize else 1000.0, "compile_s": 1.0,
                "peak_rss_mib": 500.0}

    monkeypatch.setattr(bench, "measure_sweep", sweep)
    monkeypatch.setattr(bench, "measure_raw", lambda env, batch, processes, repeats, **kw: {
        "env": env, "batch": batch, "processes": processes, "env_steps_per_s": 3000.0, "compile_s": 1.0})
    monkeypatch.setattr(bench, "measure_mujoco_c", lambda env, solver=None, **kw: {
        "env": env, "threads": 2, "batch": 256, "substeps_per_env_step": 4, "env_steps_per_s": 10000.0})
    out = tmp_path / "b"
    argv = ["--env", "Hopper-v5", "--physics", "c", "--sizes", "2,4", "--raw-batches", "8", "--processes", "2",
            "--policies", "mixture", "--solver-variant", "none", "--randomize", "mass=0.9:1.1, delay=1", "--out", str(out)]
    assert main(argv) == 0
    assert [(c.runs, c.randomize) for c in cells] == [(2, ""), (2, "mass=0.9:1.1, delay=1"), (4, ""),
                                                       (4, "mass=0.9:1.1, delay=1")]
    assert "--randomize" in measure.worker_command(cells[1], 2, 0, 3)
    sweeps = json.loads((out / "bench.json").read_text())["sweeps"]
    assert [s.get("ratio_vs_nominal") for s in sweeps] == [None, pytest.approx(0.9), None, pytest.approx(0.9)]
    with pytest.raises(ValueError, match="Ant-v5 takes no per-simulation model on backend 'c'"):
        bench.make_plan(bench.build_parser().parse_args(["--env", "Ant-v5", "--physics", "c", "--randomize", "mass=2"]))


def test_physics_backends_plan():
    """--physics mjx,c measures every raw batch and sweep on each backend; MJX's solver variant only on MJX;
    a backend that cannot run the task is refused before anything runs."""
    args = bench.build_parser().parse_args(["--sizes", "2,4", "--raw-batches", "8", "--processes", "2", "--physics", "mjx,c"])
    info = bench.make_plan(args)
    assert info["backends"] == ["mjx", "c"]
    assert [(n, be) for _, n, _, sol, be in info["plan"] if not sol] == [(2, "mjx"), (4, "mjx"), (2, "c"), (4, "c"),
                                                                          (4, "mjx"), (4, "c")]
    assert {be for *_, sol, be in info["plan"] + info["raw_plan"] if sol} == {"mjx"}
    assert [(b, be) for b, _, sol, be in info["raw_plan"] if not sol] == [(8, "mjx"), (8, "c")]
    args = bench.build_parser().parse_args(["--env", "inverted_double_pendulum", "--physics", "c"])
    with pytest.raises(ValueError, match="--physics: physics backend 'c' does not step"):
        bench.make_plan(args)


@pytest.mark.parametrize("text, quick, expected", [(None, False, measure.SOLVER_VARIANT), (None, True, None), ("none", False, None),
                                                   ("2,8", True, (2, 8))])
def test_solver_variant_parsing(text, quick, expected):
    assert bench.parse_solver_variant(text, quick) == expected


@pytest.mark.parametrize("text", ["1", "a,b", "0,4", "1,2,3"])
def test_solver_variant_errors(text, capsys):
    assert main(["--solver-variant", text]) == 2
    assert "--solver-variant" in capsys.readouterr().err


@pytest.mark.parametrize("processes", [1, 2])
def test_time_profile_decomposition(monkeypatch, processes):
    """t(E) = collect + E * epoch: with E=10 -> 2.0 s and E=1 -> 0.65 s per iteration (all the workers'
    runs together), an epoch is 0.15 s, the rollout 0.5 s of which raw physics takes 0.3 s."""
    steps = 64 * 2048
    fake = {10: steps / 2.0, 1: steps / 0.65}

    def sweep(cell, repeats, log=print):
        assert cell.run_batch == 8 and cell.backend == "c" and cell.processes == processes
        return {"env_steps_per_iteration": steps, "env_steps_per_s": fake[cell.epochs or 10]}

    def raw(env, batch, procs, repeats, log=print, backend=None):
        # physics as the rollout steps it: in each worker one sub-batch of 8 runs x 32 envs at a time
        assert batch == 8 * 32 * processes and procs == processes and backend == "c"
        return {"env_steps_per_s": steps / 0.3}

    monkeypatch.setattr(measure, "measure_sweep", sweep)
    monkeypatch.setattr(measure, "measure_raw", raw)
    p = measure.time_profile("hopper", "mixture", 64, 3, run_batch=8, backend="c", processes=processes)
    assert p["iteration_s"] == pytest.approx(2.0) and p["processes"] == processes
    assert p["update_s"] == pytest.approx(1.5) and p["physics_s"] == pytest.approx(0.3)
    assert p["rollout_other_s"] == pytest.approx(0.2)
    assert sum(p["fractions"].values()) == pytest.approx(1.0)
    # outside physics 1.7 s per 131,072 env steps of P processes, P x that per process; MuJoCo C 2 threads x
    # 50,000 env-steps/s: per core and env step 20 us of physics + P x 12.97 us of the rest
    c = measure.ratio_ceiling(p, {"env_steps_per_s": 100_000.0, "threads": 2})
    assert c["ratio_ceiling_with_mujoco_c_physics"] == pytest.approx(20e-6 / (20e-6 + processes * 1.7 / steps))


def test_profile_processes_flag():
    """--profile-processes: the profiles' worker counts, checked before anything runs."""
    args = bench.build_parser().parse_args(["--profile-runs", "64", "--profile-processes", "1,2", "--solver-variant", "none"])
    assert bench.make_plan(args)["profile_procs"] == [1, 2]
    assert bench.make_plan(bench.build_parser().parse_args(["--solver-variant", "none"]))["profile_procs"] == [1]
    for bad in ("0", "x", "128"):
        with pytest.raises(ValueError, match="--profile-processes"):
            bench.make_plan(bench.build_parser().parse_args(["--profile-runs", "64", "--profile-processes", bad]))


def test_hung_worker_is_killed_and_retried(tmp_path):
    """A worker that never beats is killed after the compile limit; a failing one is reported."""
    logs = []
    hang = [sys.executable, "-c", "import time; time.sleep(60)"]
    with pytest.raises(BenchError, match="no progress"):
        run_workers([hang], compile_limit_s=1, retries=1, log=logs.append)
    assert len(logs) == 2 and "retrying" in logs[0] and "giving up" in logs[1]
    fail = [sys.executable, "-c", "import sys; sys.exit(3)"]
    with pytest.raises(BenchError, match="exited with 3"):
        run_workers([fail], compile_limit_s=30, retries=0, log=logs.append)


def test_in_run_split_and_ceiling():
    """Two 'c' workers of 1,000 env steps per chunk: per worker the chunk medians of the seconds in MuJoCo C,
    in the rest of the host calls and in the program; the ceiling puts MuJoCo C's rollout cost (2 threads x
    10,000 env-steps/s: 100 us per env step) in place of the host calls."""
    chunk = lambda t, host, mj: ({"calls": 64, "host_s": host, "mujoco_c_s": mj}, t)  # noqa: E731
    workers = []
    for chunks in ([chunk(0.30, 0.20, 0.18), chunk(0.32, 0.21, 0.19), chunk(0.40, 0.20, 0.18)],
                   [chunk(0.20, 0.10, 0.09), chunk(0.20, 0.10, 0.09), chunk(0.20, 0.10, 0.09)]):
        workers.append({"env_steps_per_chunk": 1000, "chunk_s": [t for _, t in chunks], "host_chunks": [h for h, _ in chunks]})
    split = measure.in_run_split(workers)
    w0, w1 = split["per_process"]
    assert (w0["mujoco_c_s"], w0["host_other_s"], w0["program_s"]) == pytest.approx((0.18, 0.02, 0.11))
    assert (w1["mujoco_c_s"], w1["host_other_s"], w1["program_s"]) == pytest.approx((0.09, 0.01, 0.10))
    assert split["fractions"]["mujoco_c"] == pytest.approx(0.27 / 0.51) and sum(split["fractions"].values()) == pytest.approx(1)
    c = measure.in_run_ceiling(split, {"env_steps_per_s": 20_000.0, "threads": 2})
    assert c["ratio_ceiling_in_run"] == pytest.approx((1000 / (0.1 + 0.11) + 1000 / (0.1 + 0.10)) / 20_000)
    assert c["mujoco_c_us_per_env_step"] == pytest.approx(1e6 * 0.27 / 2000) and c["rollout_us_per_env_step"] == pytest.approx(100)
    assert c["sweep_of_ceiling_at_own_mujoco_c"] == pytest.approx((1000 / 0.31 + 1000 / 0.20) / (1000 / 0.29 + 1000 / 0.19))
    assert measure.in_run_split([{"chunk_s": [1.0], "env_steps_per_chunk": 10}]) is None  # MJX: no host calls, no split


def test_timed_chunks_record_each_chunks_clock_change(tmp_path):
    """A worker's timed chunks: each chunk's wall seconds and its change of the clock's counts."""
    import argparse

    counts = iter([{"calls": 0}, {"calls": 3}, {"calls": 3}, {"calls": 10}])
    args = argparse.Namespace(repeats=2, barrier=str(tmp_path), worker_id=0)
    times, changes = workers._time_chunks(args, lambda s: s + 1, 0, clock=lambda: next(counts))
    assert len(times) == 2 and min(times) >= 0 and changes == [{"calls": 3}, {"calls": 7}]
    assert workers._time_chunks(args, lambda s: s, 0)[1] == [{}, {}]
