"""Sweeps: grid construction and spec errors; a run in a sweep equals the run alone; worker processes;
kill -9 + resume; the watchdog restarting a stalled worker; jax.distributed with 2 processes."""

import csv
import glob
import os
import signal
import socket
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.ppo import Config, make_hparams, make_train
from gsa_jax.sweep import SpecError, build_grid, check_spec, group_config, group_name, id_columns, load_spec, run_sweep

SMALL_CONFIG = {"num_envs": 16, "unroll_length": 32, "num_minibatches": 8, "num_epochs": 2, "episode_length": 200}
TINY = f"""
name = "tiny"
envs = ["inverted_double_pendulum"]
policies = ["mixture"]
clusters = [1, 3]
seeds = [0, 1]
steps = 3072
chunk = 1
[config]
{chr(10).join(f"{k} = {v}" for k, v in SMALL_CONFIG.items())}
"""
ITERS = 6  # 3072 / 512


def test_grid_every_combination_once():
    spec = check_spec({"envs": ["hopper", "inverted_double_pendulum"], "policies": ["mlp", "mixture"],
                       "cluster_multipliers": [0.5, 1, 2, 4], "seeds": 3, "steps": 1000,
                       "hparams": {"lr": [1e-4, 3e-4], "clip_eps": 0.2}})
    groups = build_grid(spec)
    assert [(e, p) for e, p, _ in groups] == [("hopper", "mlp"), ("hopper", "mixture"),
                                              ("inverted_double_pendulum", "mlp"), ("inverted_double_pendulum", "mixture")]
    ks = {(e, p): sorted({r["K"] for r in runs}) for e, p, runs in groups}
    assert ks[("hopper", "mixture")] == [2, 3, 6, 12]  # ceil(m * 3)
    assert ks[("inverted_double_pendulum", "mixture")] == [1, 2, 4]  # 0.5 and 1 both give K=1: once
    for e, p, runs in groups:
        keys = [(r["K"], r["lr"], r["seed"]) for r in runs]
        assert len(keys) == len(set(keys)) == len(ks[(e, p)]) * 2 * 3
        assert [r["run"] for r in runs] == list(range(len(runs)))
        assert all(r["clip_eps"] == 0.2 for r in runs)


def test_grid_with_subpolicy_classes():
    """One compiled group per sub-policy class; flat PPO once; a 'subpolicy' id column."""
    spec = check_spec({"envs": ["hopper"], "policies": ["mlp", "mixture"], "subpolicies": ["constant", "quadratic"],
                       "clusters": [1, 4], "seeds": 2, "steps": 1000})
    groups = build_grid(spec)
    assert [group_name(e, p, runs) for e, p, runs in groups] == ["hopper-mlp", "hopper-mixture-constant", "hopper-mixture-quadratic"]
    assert [group_config(spec, e, p, runs).subpolicy for e, p, runs in groups] == ["linear", "constant", "quadratic"]
    assert [len(runs) for _, _, runs in groups] == [2, 4, 4]
    assert id_columns(spec) == ["env", "policy", "subpolicy", "K", "seed", "run"]
    # without the field nothing changes: same groups, columns and spec as before the field existed
    plain = check_spec({"envs": ["hopper"], "policies": ["mixture"], "clusters": [2], "steps": 10})
    assert "subpolicies" not in plain and id_columns(plain) == ["env", "policy", "K", "seed", "run"]
    assert [group_name(e, p, runs) for e, p, runs in build_grid(plain)] == ["hopper-mixture"]


def test_return_vs_k_has_one_curve_per_subpolicy(tmp_path):
    """plot_sweep on a tidy table with a subpolicy column: final returns per (class, K), flat PPO separate."""
    from gsa_jax.plot import plot_sweep

    lines = ["env,policy,subpolicy,K,seed,run,iteration,env_steps,episode_return"]
    final = {("mlp", "", 1): 50.0, ("mixture", "constant", 2): 10.0, ("mixture", "constant", 4): 20.0,
             ("mixture", "linear", 2): 30.0, ("mixture", "linear", 4): 40.0}
    for (pol, sub, k), value in final.items():
        for seed in range(3):
            for it in range(20):
                lines.append(f"hopper,{pol},{sub},{k},{seed},0,{it},{(it + 1) * 100},{value + seed - 1}")
    (tmp_path / "metrics.csv").write_text("\n".join(lines) + "\n")
    _, table, rows = plot_sweep(str(tmp_path), action_dims={"hopper": 3})
    got = {(r["policy"], r["subpolicy"], r["K"] or 1): r["final_return_mean"] for r in rows}
    assert got == final
    assert all(r["seeds"] == 3 for r in rows)
    assert os.path.getsize(tmp_path / "return_vs_k.png") > 10_000


@pytest.mark.parametrize("raw, field", [
    ({"envs": ["pong"], "policies": ["mlp"], "steps": 10}, "envs"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 0}, "steps"),
    ({"envs": ["hopper"], "policies": ["mixture"], "steps": 10}, "clusters"),
    ({"envs": ["hopper"], "policies": ["mixture"], "clusters": [0], "steps": 10}, "clusters"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "seeds": [1, 1]}, "seeds"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "hparams": {"lrr": 1}}, "hparams.lrr"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "hparams": {"lr": "fast"}}, "hparams.lr"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "config": {"num_envs": 10, "num_minibatches": 3}}, "config"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "colour": "red"}, "colour"),
    ({"envs": ["hopper"], "policies": ["mixture"], "clusters": 2, "steps": 10, "subpolicies": ["cubic"]}, "subpolicies"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "subpolicies": ["constant"]}, "subpolicies"),
])
def test_malformed_spec_names_the_field(raw, field):
    with pytest.raises(SpecError, match=f"field '{field}'"):
        check_spec(raw, source="x.toml")


def test_bad_toml_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("envs = [hopper")
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(str(p))
    with pytest.raises(SpecError, match="no such experiment file"):
        load_spec(str(tmp_path / "missing.toml"))


def read_rows(pattern):
    rows = []
    for path in sorted(glob.glob(pattern, recursive=True)):
        with open(path) as f:
            rows.extend(csv.DictReader(f))
    return sorted(rows, key=lambda r: (int(r["K"]), int(r["seed"]), int(r["iteration"])))


def as_array(rows, col):
    return np.array([float(r[col]) if r[col] != "" else np.nan for r in rows])


@pytest.fixture(scope="module")
def tiny_spec_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("spec") / "tiny.toml"
    p.write_text(TINY)
    return str(p)


@pytest.fixture(scope="module")
def inprocess(tiny_spec_file, tmp_path_factory):
    """The tiny sweep in this process (no supervisor), uninterrupted: the reference."""
    out = tmp_path_factory.mktemp("sweep") / "ref"
    assert run_sweep(load_spec(tiny_spec_file), str(out), devices=jax.local_devices()[:1], quiet=True)
    return out


def test_tidy_table(inprocess):
    rows = read_rows(str(inprocess / "metrics.csv"))
    assert len(rows) == 4 * ITERS
    assert {(r["K"], r["seed"]) for r in rows} == {("1", "0"), ("1", "1"), ("3", "0"), ("3", "1")}
    assert list(rows[0])[:5] == ["env", "policy", "K", "seed", "run"]
    assert os.path.exists(inprocess / "sweep.json")
    assert os.path.exists(inprocess / "groups" / "inverted_double_pendulum-mixture" / "params.npz")


def test_run_in_sweep_equals_run_alone(inprocess):
    """K=3, seed 1 of the vmapped K grid == the same config trained alone (as train.py does)."""
    rows = [r for r in read_rows(str(inprocess / "metrics.csv")) if r["K"] == "3" and r["seed"] == "1"]
    cfg = Config(env="inverted_double_pendulum", policy="mixture", k_max=3, **SMALL_CONFIG)
    tr = make_train(cfg)
    hp = make_hparams(K=3, total_iterations=ITERS)
    _, m = jax.jit(tr.run_chunk, static_argnums=2)(jax.jit(tr.init)(jax.random.PRNGKey(1), hp), hp, 3)
    for col in ("episode_return", "episodes", "policy_loss", "value_loss", "approx_kl", "partition_entropy"):
        np.testing.assert_allclose(as_array(rows, col)[:3], np.asarray(m[col], np.float64), rtol=2e-3, atol=1e-5, err_msg=col)


def sweep_cmd(spec_file, out, *extra):
    return [sys.executable, "-m", "gsa_jax.sweep", spec_file, "--out", str(out), "--quiet", *extra]


def subprocess_env():
    env = dict(os.environ)
    env["JAX_COMPILATION_CACHE_DIR"] = str(jax.config.jax_compilation_cache_dir)
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"
    return env


def assert_same_results(rows_a, rows_b, rtol):
    assert [(r["K"], r["seed"], r["iteration"]) for r in rows_a] == [(r["K"], r["seed"], r["iteration"]) for r in rows_b]
    for col in ("episode_return", "policy_loss", "value_loss", "partition_entropy"):
        np.testing.assert_allclose(as_array(rows_a, col), as_array(rows_b, col), rtol=rtol, atol=1e-5, err_msg=col)


def test_kill9_then_resume_equals_uninterrupted(tiny_spec_file, inprocess, tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen(sweep_cmd(tiny_spec_file, out, "--no-watchdog"), env=subprocess_env(),
                            start_new_session=True)
    metrics = out / "groups" / "inverted_double_pendulum-mixture" / "metrics.npz"
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if metrics.exists():
            with np.load(metrics) as m:
                if int(m["__done__"]) >= 2:
                    break
        time.sleep(0.05)
    assert proc.poll() is None, "sweep finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    with np.load(metrics) as m:
        assert int(m["__done__"]) < ITERS
    subprocess.run(sweep_cmd(tiny_spec_file, out, "--no-watchdog"), env=subprocess_env(), check=True, timeout=600)
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=1e-6)


def test_watchdog_restarts_a_stalled_worker(tiny_spec_file, inprocess, tmp_path):
    out = tmp_path / "stalled"
    env = subprocess_env()
    env["GSA_JAX_FAULT_HANG_AFTER_CHUNKS"] = "2"
    res = subprocess.run(sweep_cmd(tiny_spec_file, out, "--local-processes", "1", "--watchdog-min", "8"),
                         env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "watchdog: worker 0 made no progress" in res.stdout
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=1e-6)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_with_jax_distributed_match_one_process(tiny_spec_file, inprocess, tmp_path):
    """Two processes on localhost (jax.distributed coordinator), each its share of the grid; merged = one process."""
    out = tmp_path / "dist"
    coord = f"127.0.0.1:{free_port()}"
    procs = [subprocess.Popen(sweep_cmd(tiny_spec_file, out, "--no-watchdog", "--coordinator", coord,
                                        "--num-processes", "2", "--process-id", str(i)),
                              env=subprocess_env(), stderr=subprocess.PIPE, text=True) for i in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-2000:]
    assert sorted(os.listdir(out)) == ["process-0", "process-1", "sweep.json"]
    merged = read_rows(str(out / "process-*" / "metrics.csv"))
    # each process vmaps 2 runs instead of 4: same math, batched differently -> float tolerance
    assert_same_results(merged, read_rows(str(inprocess / "metrics.csv")), rtol=2e-3)
    from gsa_jax.plot import plot_sweep

    png, table, rows = plot_sweep(str(out))
    assert os.path.getsize(png) > 10_000 and [r["K"] for r in rows] == [1, 3] and all(r["seeds"] == 2 for r in rows)


def test_sub_batched_equals_vmap_with_empty_leaves():
    """sub_batched runs slices of the run axis in a scan: same outputs as one vmap, also for
    zero-size leaves (MJX data has some) and for sizes that do not divide the runs (plain vmap)."""
    from gsa_jax.sweep import sub_batched

    f = jax.vmap(lambda x, h: ({"y": jnp.sin(x) * h, "e": jnp.zeros((0, 2))}, x.sum() + h))
    x, h = jnp.arange(24.0).reshape(6, 4), jnp.arange(6.0)
    ref = f(x, h)
    for size in (0, 2, 3, 4, 6, 8):
        out = jax.jit(sub_batched(f, size))(x, h)
        assert jax.tree.structure(out) == jax.tree.structure(ref)
        for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(ref)):
            assert a.shape == b.shape
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_sweep_in_sub_batches_matches_all_at_once(tiny_spec_file, inprocess, tmp_path):
    """--run-batch 2: the group's 4 runs trained as 2 sequential sub-batches give the same runs."""
    out = tmp_path / "sub"
    assert run_sweep(load_spec(tiny_spec_file), str(out), devices=jax.local_devices()[:1], quiet=True, run_batch=2)
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=2e-3)
