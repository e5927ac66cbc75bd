"""Sweeps: grid construction and spec errors; a run in a sweep equals the run alone; worker processes;
kill -9 + resume; the watchdog restarting a stalled worker; jax.distributed with 2 processes."""

import csv
import glob
import json
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
from golden_runs import arrays_digest, check_fingerprint, summarize, table_digest

from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.running.tasks import trainer_for
from gsa_jax.running.runinfo import ResumeRefused
from gsa_jax.running.spec import (
    SpecError, build_grid, check_spec, group_config, group_eval_at, group_eval_every, group_name, load_spec,
)
from gsa_jax.running.sweeps import SweepOptions, run_sweep
from gsa_jax.running.tuning import load_tuning

FEW = {"reps": 50, "curve_reps": 20}  # bootstrap resamples of gsa_jax.plot: enough for the checks, cheap
SMALL_CONFIG = {"num_envs": 16, "unroll_length": 32, "num_minibatches": 8, "num_epochs": 2, "episode_length": 200}
TINY = f"""
name = "tiny"
envs = ["inverted_double_pendulum"]
policies = ["mixture"]
clusters = [1, 3]
seeds = [0, 1]
steps = 3072
chunk = 1
eval_every = 2
[config]
eval_envs = 4
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
    assert [group_name(g) for g in groups] == ["hopper-mlp", "hopper-mixture-constant", "hopper-mixture-quadratic"]
    assert [group_config(spec, g).subpolicy for g in groups] == ["linear", "constant", "quadratic"]
    assert [len(runs) for _, _, runs in groups] == [2, 4, 4]
    assert spec.id_columns() == ["env", "policy", "subpolicy", "K", "seed", "run"]
    # without the field nothing changes: same groups, columns and spec as before the field existed
    plain = check_spec({"envs": ["hopper"], "policies": ["mixture"], "clusters": [2], "steps": 10})
    assert plain.subpolicies is None and "subpolicies" not in plain.to_json() and plain.id_columns() == ["env", "policy", "K", "seed", "run"]
    assert [group_name(g) for g in build_grid(plain)] == ["hopper-mixture"]


def test_grid_with_partition_classes():
    """One compiled group per partition class (a mixture's own axis, crossed with sub-policy classes); flat PPO once
    and compared with every mixture cell (MIXTURE_COLUMNS aside); an unknown class is refused where the file is read."""
    from gsa_jax.algorithm.kinds import MIXTURE_COLUMNS
    from gsa_jax.analysis.sweeps.results import Cell
    from gsa_jax.analysis.sweeps.tables import flat_cell
    from gsa_jax.running.spec import GROUP_AXES

    spec = check_spec({"envs": ["hopper"], "policies": ["mlp", "mixture"], "partitions": ["mlp", "linear"],
                       "subpolicies": ["constant", "linear"], "clusters": [2], "seeds": 2, "steps": 1000})
    groups = build_grid(spec)
    assert [group_name(g) for g in groups] == [
        "hopper-mlp", "hopper-mixture-constant-mlp-partition", "hopper-mixture-constant-linear-partition",
        "hopper-mixture-linear-mlp-partition", "hopper-mixture-linear-linear-partition"]
    assert [group_config(spec, g).partition for g in groups] == ["mlp", "mlp", "linear", "mlp", "linear"]
    assert spec.id_columns() == ["env", "policy", "subpolicy", "partition", "K", "seed", "run"]
    assert MIXTURE_COLUMNS == tuple(column for _, column, policy, _ in GROUP_AXES if policy == "mixture")
    flat = Cell("hopper", "mlp", 1, (("subpolicy", ""), ("partition", "")))
    mix = Cell("hopper", "mixture", 2, (("subpolicy", "linear"), ("partition", "linear")))
    assert flat_cell(mix, [flat, mix]) == flat
    with pytest.raises(SpecError, match="partitions"):
        check_spec({"envs": ["hopper"], "policies": ["mixture"], "clusters": [2], "steps": 10, "partitions": ["tree"]})


def test_grid_with_value_targets():
    """One compiled group per critic, for flat PPO and mixtures alike, crossed with sub-policy classes."""
    spec = check_spec({"envs": ["hopper"], "policies": ["mlp", "mixture"], "subpolicies": ["constant", "linear"],
                       "value_targets": ["gae", "retrace"], "clusters": [2], "seeds": 2, "steps": 1000,
                       "config": {"retrace_iterations": 3}})
    groups = build_grid(spec)
    assert [group_name(g) for g in groups] == [
        "hopper-mlp-gae", "hopper-mlp-retrace", "hopper-mixture-constant-gae", "hopper-mixture-constant-retrace",
        "hopper-mixture-linear-gae", "hopper-mixture-linear-retrace"]
    cfgs = [group_config(spec, g) for g in groups]
    assert [c.value_target for c in cfgs] == ["gae", "retrace"] * 3
    assert {c.retrace_iterations for c in cfgs} == {3} and [c.subpolicy for c in cfgs][2:4] == ["constant"] * 2
    assert spec.id_columns() == ["env", "policy", "subpolicy", "value_target", "K", "seed", "run"]


def test_return_vs_k_has_one_curve_per_subpolicy(tmp_path):
    """plot_sweep on an evaluated tidy table with a subpolicy column: final scores per (class, K), flat PPO
    separate; return-vs-K draws one curve per class, its points in K order."""
    from gsa_jax.analysis.sweep_report import plot_sweep
    from gsa_jax.analysis.sweeps.results import load_sweeps, setting_columns
    from gsa_jax.analysis.sweeps.tables import k_curves

    lines = ["env,policy,subpolicy,K,seed,run,iteration,env_steps,episode_return,eval_return"]
    final = {("mlp", "", 1): 50.0, ("mixture", "constant", 2): 10.0, ("mixture", "constant", 4): 20.0,
             ("mixture", "linear", 2): 30.0, ("mixture", "linear", 4): 40.0}
    for (pol, sub, k), value in final.items():
        for seed in range(3):
            for it in range(20):
                ev = value + seed - 1 if it % 4 == 3 else ""
                lines.append(f"hopper,{pol},{sub},{k},{seed},0,{it},{(it + 1) * 100},{value / 2},{ev}")
    (tmp_path / "metrics.csv").write_text("\n".join(lines) + "\n")
    _, table, rows = plot_sweep(str(tmp_path), action_dims={"hopper": 3}, random_returns={"hopper": 0.0}, **FEW)
    got = {(r["policy"], r["subpolicy"], r["K"] or 1): r["final_return_mean"] for r in rows}
    assert got == final and all(r["score"] == "deterministic" for r in rows)
    assert all(r["seeds"] == 3 for r in rows)
    settings = setting_columns(load_sweeps([str(tmp_path)]))
    assert settings == ["subpolicy"]  # not the statistics columns of the rows
    curves = k_curves(rows, "hopper", settings)
    assert {k: [(r["K"], r["final_return_mean"]) for r in pts] for k, pts in curves.items()} == {
        (("subpolicy", "constant"),): [(2, 10.0), (4, 20.0)], (("subpolicy", "linear"),): [(2, 30.0), (4, 40.0)]}
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
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "value_targets": ["gae", "td"]}, "value_targets"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "value_targets": ["gae", "gae"]}, "value_targets"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "value_targets": ["retrace"],
      "config": {"value_target": "gae"}}, "value_targets"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "config": {"value_target": "td"}}, "config"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "config": {"retrace_iterations": 0}}, "config"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "eval_at": [5], "eval_every": 2}, "eval_at"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "eval_at": [5, 5]}, "eval_at"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "eval_at": [11]}, "eval_at"),
    ({"envs": ["hopper"], "policies": ["mlp"], "steps": 10, "eval_at": []}, "eval_at"),
])
def test_malformed_spec_names_the_field(raw, field):
    with pytest.raises(SpecError, match=f"field '{field}'"):
        check_spec(raw, source="x.toml")


def test_eval_at_evaluates_after_the_chunks_holding_its_steps():
    spec = check_spec({"envs": ["hopper"], "policies": ["mlp"], "steps": 1000, "eval_at": [1, 40, 41, 1000]})
    # batch 10, chunk 2: steps 1 .. 20 lie in the chunk ending at iteration 2, 21 .. 40 in the one ending at 4, ...
    assert group_eval_at(spec, batch=10, chunk=2) == (2, 4, 6, 100) and group_eval_every(spec, 100) == 0
    plain = check_spec({"envs": ["hopper"], "policies": ["mlp"], "steps": 1000})
    assert group_eval_at(plain, batch=10, chunk=2) == () and group_eval_every(plain, 100) == 4


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
    assert run_sweep(load_spec(tiny_spec_file), str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), quiet=True))
    return out


def test_a_resumed_sweep_keeps_its_runs_per_program(tmp_path):
    """--resume DIR continues with the runs per program DIR/sweep.json recorded (an older record's pad_runs, read by
    running.formats, too)."""
    from gsa_jax.commands.sweep import saved_options
    from gsa_jax.running.formats import current
    from gsa_jax.running.sweeps import check_resumable

    def saved(meta):
        return saved_options(current(meta, "sweep", "sweep.json"), "d", None)

    assert saved({"spec": {}, "runs_per_program": 10, "num_processes": 2}) == {
        "out": "d", "runs_per_program": 10, "local_processes": 2}
    runs = [{"env": "e", "policy": "mixture", "K": 1, "seed": s} for s in range(10)]
    assert saved({"spec": {}, "pad_runs": 10, "runs": runs}) == {"out": "d", "runs_per_program": 10}
    whole = {"spec": {}, "pad_runs": 10, "runs": runs + [{**runs[0], "seed": 10}]}
    assert current(whole, "sweep", "sweep.json")["trained_whole"] == 11  # it reads; resuming it is refused
    root = tmp_path / "old"
    root.mkdir()
    (root / "sweep.json").write_text(json.dumps(whole))
    with pytest.raises(ResumeRefused, match="a group of 11 runs, which it trained whole"):  # parts would retrain it
        check_resumable(str(root), None, {}, None)


def test_every_experiment_file_is_valid():
    root = os.path.join(os.path.dirname(__file__), "..", "experiments")
    files = sorted(glob.glob(os.path.join(root, "*", "*.toml")))
    assert len(files) >= 10
    for f in files:  # experiments/tuning/ holds tuning files (gsa_jax.tune), every other folder experiment files
        load = load_tuning if os.path.basename(os.path.dirname(f)) == "tuning" else load_spec
        assert load(f).name == os.path.splitext(os.path.basename(f))[0], f


def test_fixed_sweep_computes_what_it_computed(inprocess):
    """The tiny sweep's tidy metrics and its group's parameters and metrics arrays are bit for bit the ones recorded
    for this host family, and its summary is the recorded one within the tolerance that holds across hosts
    (tests/golden_runs.py)."""
    group = inprocess / "groups" / "inverted_double_pendulum-mixture"
    check_fingerprint("sweep_tiny", {"table": table_digest(inprocess / "metrics.csv"),
                                     **{f"{n}.npz": arrays_digest(group / f"{n}.npz") for n in ("params", "metrics")}},
                      summarize(group))


def test_tidy_table(inprocess):
    rows = read_rows(str(inprocess / "metrics.csv"))
    assert len(rows) == 4 * ITERS
    assert {(r["K"], r["seed"]) for r in rows} == {("1", "0"), ("1", "1"), ("3", "0"), ("3", "1")}
    assert list(rows[0])[:5] == ["env", "policy", "K", "seed", "run"]
    evaluated = [int(r["iteration"]) for r in rows if r["eval_return"] != ""]
    assert sorted(set(evaluated)) == [2, 4, 6] and len(evaluated) == 4 * 3  # eval_every = 2, every run
    meta = json.loads((inprocess / "sweep.json").read_text())
    assert meta["physics"]["inverted_double_pendulum-mixture"]["linesearch_in_force"] == "exact"
    assert meta["run_batch"] == 8  # the default runs per sub-batch, as the program used
    group = json.loads((inprocess / "groups" / "inverted_double_pendulum-mixture" / "config.json").read_text())
    assert meta["format_version"] == group["format_version"] == 1  # running.formats.FORMAT_VERSION
    assert os.path.exists(inprocess / "groups" / "inverted_double_pendulum-mixture" / "params.npz")


def test_every_finished_runs_controller_exported(inprocess, tmp_path):
    """extract --controllers: one exported controller per run, named by env, policy, K and seed, holding that
    run's own parameters (its row of the group's params.npz, K's clusters only), loadable without JAX."""
    from gsa_jax.deployment import numpy_policy
    from gsa_jax.extract import main as extract_main

    out = tmp_path / "controllers"
    assert extract_main([str(inprocess), "--controllers", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"inverted_double_pendulum-mixture-K{k}-s{s}.npz" for k in (1, 3) for s in (0, 1)]
    with np.load(inprocess / "groups" / "inverted_double_pendulum-mixture" / "params.npz") as p:
        L = p["['params']['policy']['L']"]
    with open(inprocess / "groups" / "inverted_double_pendulum-mixture" / "runs.csv") as f:
        row = next(i for i, r in enumerate(csv.DictReader(f)) if r["K"] == "3" and r["seed"] == "1")
    ctrl = numpy_policy.load(str(out / "inverted_double_pendulum-mixture-K3-s1.npz"))
    np.testing.assert_array_equal(ctrl.L, L[row][:3])
    assert ctrl.num_clusters == 3 and np.isfinite(ctrl.act(np.zeros(L.shape[-1], np.float32))).all()
    assert extract_main([str(tmp_path), "--controllers", str(out)]) == 2  # not a sweep: one line, exit 2
    # --results: what a results commit holds, and gsa_jax.plot reads it as it reads the sweep
    res = tmp_path / "results"
    assert extract_main([str(inprocess), "--results", str(res)]) == 0
    assert {p.name for p in res.iterdir()} == {"sweep.json", "metrics.csv.gz", "failed_runs.json", "controllers"}
    assert len(list((res / "controllers").iterdir())) == 4 and not list(res.glob("**/state.npz"))
    with np.load(next((res / "controllers").iterdir())) as f:
        assert int(f["format_version"]) == 1  # every exported controller is stamped
    from gsa_jax.analysis.sweeps.results import load_sweep

    ours, theirs = load_sweep(str(res)), load_sweep(str(inprocess))
    assert ours.keys() == theirs.keys()
    for cell in ours:
        for seed in ours[cell]:
            np.testing.assert_array_equal(ours[cell][seed]["eval_return"], theirs[cell][seed]["eval_return"])


def test_a_sweeps_run_is_read_as_a_run_directory_is(inprocess, tmp_path, capsys):
    """SWEEP_DIR/<run label> is a trained run's address: the same reader as a run directory's gives its settings
    (the group's config.json, this run's seed and hyperparameters) and its row of the group's params.npz;
    export takes it; extract --list prints the addresses; an unknown label is one line naming the runs."""
    import shutil

    from gsa_jax.export import main as export_main
    from gsa_jax.extract import main as extract_main
    from gsa_jax.running.trained import RunNotFound, read_run

    address = str(inprocess / "inverted_double_pendulum-mixture-K3-s1")
    run = read_run(address)
    assert run.meta["seed"] == 1 and run.meta["hparams"]["K"] == 3 and run.meta["hparams"]["total_iterations"] == ITERS
    assert run.meta["config"]["k_max"] == 3 and run.meta["result"] == {"iterations_done": ITERS, "status": "finished"}
    group = inprocess / "groups" / "inverted_double_pendulum-mixture"
    with open(group / "runs.csv") as f:
        row = next(i for i, r in enumerate(csv.DictReader(f)) if r["K"] == "3" and r["seed"] == "1")
    with np.load(group / "params.npz") as p:
        for k in p.files:
            np.testing.assert_array_equal(run.params[k], p[k][row], err_msg=k)
    assert {"iterations", "chunk", "eval_every", "eval_seed", "physics", "versions", "git_commit"} <= set(run.meta)
    assert export_main([address, "--out", str(tmp_path / "c.npz")]) == 0
    capsys.readouterr()
    assert extract_main([str(inprocess), "--list"]) == 0
    assert address in capsys.readouterr().out
    with pytest.raises(RunNotFound, match="holds no finished run 'hopper-mlp-s0'; its finished runs: inverted_double"):
        read_run(str(inprocess / "hopper-mlp-s0"))
    older = tmp_path / "older"  # a sweep written before groups recorded their config.json: one line, no shim
    shutil.copytree(inprocess, older)
    (older / "groups" / "inverted_double_pendulum-mixture" / "config.json").unlink()
    capsys.readouterr()
    assert extract_main([str(older), "--list"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "older gsa_jax" in err and "git_commit" in err


ALONE_COLUMNS = ("episode_return", "episodes", "policy_loss", "value_loss", "approx_kl", "partition_entropy")


def train_alone(iterations=3):
    """{column: [iterations]} and the final parameters ("param<i>", flattened leaves) of K=3, seed 1 of the
    tiny grid trained alone (as train.py does), as this process compiles it."""
    tr = trainer_for(Config(env="inverted_double_pendulum", policy="mixture", k_max=3, **SMALL_CONFIG))
    hp = make_hparams(K=3, total_iterations=ITERS)
    state, m = jax.jit(tr.run_chunk, static_argnums=2)(jax.jit(tr.init)(jax.random.PRNGKey(1), hp), hp, iterations)
    out = {c: np.asarray(m[c], np.float64) for c in ALONE_COLUMNS + ("grad_norm",)}
    return dict(out, **{f"param{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state.params))})


@pytest.fixture(scope="module")
def alone():
    return train_alone()


def test_run_in_sweep_equals_run_alone(inprocess, alone):
    """K=3, seed 1 of the vmapped K grid == the same config trained alone."""
    rows = [r for r in read_rows(str(inprocess / "metrics.csv")) if r["K"] == "3" and r["seed"] == "1"]
    for col in ALONE_COLUMNS:
        np.testing.assert_allclose(as_array(rows, col)[:3], alone[col], rtol=2e-3, atol=1e-5, err_msg=col)


def test_run_compiled_at_the_default_level_equals_the_suites(alone, tmp_path):
    """The suite compiles without LLVM's optimizations (tests/conftest.py); a user's programs compile at
    XLA's default level 3. The run alone compiled at level 3 in another process equals this process's to
    float rounding (level 3 may contract a multiply and an add into one FMA), metrics and parameters."""
    level = [f for f in os.environ["XLA_FLAGS"].split() if f.startswith("--xla_backend_optimization_level")]
    assert level, "tests/conftest.py sets the suite's compile level"
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}  # compiled there, not loaded
    env["XLA_FLAGS"] = " ".join([f for f in env["XLA_FLAGS"].split() if f not in level] + ["--xla_backend_optimization_level=3"])
    code = ("import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from test_sweep import train_alone; "
            "np.savez(sys.argv[2], **train_alone())")
    subprocess.run([sys.executable, "-c", code, os.path.dirname(__file__), str(tmp_path / "l3.npz")], env=env, check=True,
                   timeout=600)
    with np.load(tmp_path / "l3.npz") as default:
        assert sorted(default.files) == sorted(alone)
        for name, ours in alone.items():
            np.testing.assert_allclose(ours, default[name], rtol=1e-3, atol=1e-5, err_msg=name)


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
    assert_same_event_files(out, inprocess)


def assert_same_event_files(out, reference):
    """TensorBoard: one event file per run, each iteration once (a killed chunk is not repeated after the resume),
    every tidy metric as in metrics.csv and the same as the reference sweep's."""
    from gsa_jax.running.tensorboard import FILE_NAME, read_scalars

    rows = read_rows(str(out / "metrics.csv"))
    for k, seed in ((1, 0), (1, 1), (3, 0), (3, 1)):
        label = f"inverted_double_pendulum-mixture-K{k}-s{seed}"
        got, ref = (read_scalars(str(d / "tensorboard" / label / FILE_NAME)) for d in (out, reference))
        mine = [r for r in rows if r["K"] == str(k) and r["seed"] == str(seed)]
        steps = [int(r["env_steps"]) for r in mine]
        assert [s for s, _ in got["returns/episode_return"]] == steps  # each iteration once, in order
        np.testing.assert_allclose([v for _, v in got["ppo/value_loss"]], as_array(mine, "value_loss"), rtol=1e-5)  # CSV: 6 digits
        assert [s for s, _ in got["returns/eval_return"]] == [int(r["env_steps"]) for r in mine if r["eval_return"] != ""]
        assert set(got) == set(ref)
        for t in got:
            np.testing.assert_allclose(np.array(got[t]), np.array(ref[t]), rtol=1e-5, atol=1e-5, err_msg=t)


def test_watchdog_restarts_a_stalled_worker(tiny_spec_file, inprocess, tmp_path, monkeypatch):
    """A worker that stalls after its 2nd chunk (tests/hang_worker.py) is killed and restarted from its
    checkpoint; the results equal an uninterrupted sweep's."""
    from hang_worker import supervise_stalling_worker

    for k, v in subprocess_env().items():
        monkeypatch.setenv(k, v)
    out = tmp_path / "stalled"
    out.mkdir()
    code, lines = supervise_stalling_worker(2, tmp_path / "hung_once", tiny_spec_file, out)
    assert code == 0
    assert any("watchdog: worker 0 made no progress" in line for line in lines), lines
    assert (tmp_path / "hung_once").exists()
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=1e-6)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_with_jax_distributed_match_one_process(tiny_spec_file, inprocess, tmp_path):
    """Two processes on localhost (jax.distributed coordinator), each its share of the grid with seeds 0-3:
    4 runs each, the shape of the one-process reference, so the suite's compilation cache can serve its
    program; the runs of seeds 0 and 1 equal the reference's."""
    spec, out = tmp_path / "tiny.toml", tmp_path / "dist"
    spec.write_text(open(tiny_spec_file).read().replace("seeds = [0, 1]", "seeds = [0, 1, 2, 3]"))
    coord = f"127.0.0.1:{free_port()}"
    procs = [subprocess.Popen(sweep_cmd(spec, out, "--no-watchdog", "--coordinator", coord,
                                        "--num-processes", "2", "--process-id", str(i)),
                              env=subprocess_env(), stderr=subprocess.PIPE, text=True) for i in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-2000:]
    assert sorted(os.listdir(out)) == ["process-0", "process-1", "sweep.json", "tensorboard"]
    assert len(os.listdir(out / "tensorboard")) == 8  # both processes' runs side by side, one TensorBoard run each
    merged = read_rows(str(out / "process-*" / "metrics.csv"))
    assert len(merged) == 8 * ITERS and {r["seed"] for r in merged} == {"0", "1", "2", "3"}
    # other runs beside them in each vmapped batch: float tolerance
    assert_same_results([r for r in merged if r["seed"] in ("0", "1")], read_rows(str(inprocess / "metrics.csv")), rtol=2e-3)
    from gsa_jax.analysis.sweep_report import plot_sweep

    png, table, rows = plot_sweep(str(out), random_returns={"inverted_double_pendulum": 50.0}, **FEW)
    assert os.path.getsize(png) > 10_000 and [r["K"] for r in rows] == [1, 3] and all(r["seeds"] == 4 for r in rows)
    assert all(r["score"] == "deterministic" for r in rows)  # the sweep evaluated its controllers


def test_sub_batched_equals_vmap_with_empty_leaves():
    """sub_batched runs slices of the run axis in a scan: same outputs as one vmap, also for
    zero-size leaves (MJX data has some) and for sizes that do not divide the runs (plain vmap)."""
    from gsa_jax.running.programs import sub_batched

    f = jax.vmap(lambda x, h: ({"y": jnp.sin(x) * h, "e": jnp.zeros((0, 2))}, x.sum() + h))
    x, h = jnp.arange(24.0).reshape(6, 4), jnp.arange(6.0)
    ref = f(x, h)
    for size in (0, 2, 3, 4, 6, 8):
        out = jax.jit(sub_batched(f, size))(x, h)
        assert jax.tree.structure(out) == jax.tree.structure(ref)
        for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(ref)):
            assert a.shape == b.shape
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# --- failures: validation, NaN runs, full disks, unreadable checkpoints, changed specs, a second writer -----------

def sweep_main(spec_file, out, *extra):
    """The sweep CLI in this process (no supervisor): its exit status."""
    from gsa_jax.sweep import main

    return main([str(spec_file), "--out", str(out), "--no-watchdog", "--local-processes", "1", "--quiet", *extra])


def test_default_out_is_runs_sweeps_name(tmp_path, monkeypatch):
    """Without --out (make sweep) the output directory is runs/sweeps/<the experiment's name>."""
    from gsa_jax.commands.sweep import build_parser, check_args

    spec = tmp_path / "exp.toml"
    spec.write_text('name = "tiny_default_out"\nenvs = ["hopper"]\npolicies = ["mlp"]\nsteps = 100\n')
    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args([str(spec)])
    _, out, _ = check_args(args)
    assert out == os.path.join("runs", "sweeps", "tiny_default_out")
    assert (tmp_path / "runs" / "sweeps" / "tiny_default_out").is_dir()


def canonical_rows(path):
    with open(path) as f:
        return sorted(f.read().splitlines())


@pytest.mark.parametrize("extra, message", [
    ('[hparams]\neps_init = 1.5', "field 'hparams.eps_init': eps_init must be in [0, 1), got 1.5"),
    ('[hparams]\nlr = -0.1', "field 'hparams.lr': lr must be > 0, got -0.1"),
    ('[hparams]\ngamma = [0.99, 1.5]', "field 'hparams.gamma': gamma must be in [0, 1], got 1.5"),
])
def test_out_of_range_hparams_rejected_before_compiling(tmp_path, capsys, extra, message):
    spec = tmp_path / "bad.toml"
    spec.write_text('envs = ["hopper"]\npolicies = ["mlp"]\nsteps = 100\n' + extra + "\n")
    assert sweep_main(spec, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err, err
    assert not (tmp_path / "out" / "sweep.json").exists()


def test_experiment_name_cannot_escape_the_results_root(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "evil.toml"
    spec.write_text('name = "../../etc/evil"\nenvs = ["hopper"]\npolicies = ["mlp"]\nsteps = 100\n')
    from gsa_jax.sweep import main

    assert main([str(spec), "--no-watchdog", "--quiet"]) == 2
    assert "field 'name': must be a plain name" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["evil.toml"]


def test_nan_run_is_frozen_listed_and_the_others_train_on(tiny_spec_file, inprocess, tmp_path, capsys):
    """One lr per run: lr = 1e30 makes two runs of the vmapped group non-finite. They stop at the
    failing iteration (metrics end there, last finite parameters kept, listed in sweep.json and the
    summary, exit 1); the healthy runs are bit for bit those of the sweep without them; plot lists the
    failed runs apart."""
    spec = tmp_path / "nan.toml"
    spec.write_text(open(tiny_spec_file).read().replace("seeds = [0, 1]", "seeds = [0]").replace(
        "[config]", "[hparams]\nlr = [3e-4, 1e30]\n[config]"))
    out = tmp_path / "nan"
    assert sweep_main(spec, out) == 1
    printed = capsys.readouterr().out
    assert "2 run(s) failed" in printed and "failed at iteration" in printed
    failed = json.loads((out / "sweep.json").read_text())["failed_runs"]
    assert sorted((f["K"], f["lr"]) for f in failed) == [(1, 1e30), (3, 1e30)]
    rows = read_rows(str(out / "metrics.csv"))
    for f in failed:
        mine = [r for r in rows if int(r["K"]) == f["K"] and float(r["hparam_lr"]) == 1e30]
        assert len(mine) == f["failed_at"] - 1 < ITERS
    healthy = [{k: v for k, v in r.items() if k not in ("hparam_lr", "run")} for r in rows if float(r["hparam_lr"]) == 3e-4]
    ref = [{k: v for k, v in r.items() if k != "run"} for r in read_rows(str(inprocess / "metrics.csv")) if r["seed"] == "0"]
    assert healthy == ref  # the same strings: bit for bit
    with np.load(out / "groups" / "inverted_double_pendulum-mixture" / "params.npz") as p:
        assert all(np.all(np.isfinite(p[k])) for k in p.files)
    from gsa_jax.analysis.sweep_report import plot_sweep

    _, _, table = plot_sweep(str(out), random_returns={"inverted_double_pendulum": 50.0}, **FEW)
    by_cell = {(r["K"], float(r["hparam_lr"])): r for r in table}
    for f in failed:
        assert by_cell[(f["K"], 1e30)]["failed_runs"] == f"0@{f['failed_at']}" and by_cell[(f["K"], 1e30)]["seeds"] == 0
    assert by_cell[(1, 3e-4)]["failed_runs"] == "" and by_cell[(1, 3e-4)]["seeds"] == 1


SWEEP_DISK_FULL = [("sweep.json", 1), ("metrics.npz", 1), ("state.npz", 1), ("metrics.csv", 1), ("heartbeat.json", 1),
                   ("metrics.npz", 2), ("state.npz", 2), ("heartbeat.json", 2), ("metrics.csv", 1), ("sweep.json", 2)]


def test_disk_full_at_every_sweep_write_then_resume(tiny_spec_file, inprocess, tmp_path, monkeypatch, capsys):
    """Every sweep write path (sweep.json, a group's metrics.npz and state.npz, the tidy metrics.csv, the
    heartbeat) fails once with ENOSPC, first and mid-run: one line, exit 4, no temp file; the same
    command resumes; the end result equals the uninterrupted sweep, row for row."""
    from test_faults import DiskFull, no_temp_files

    out = tmp_path / "full"
    for name, n in SWEEP_DISK_FULL:
        with monkeypatch.context() as m:
            inj = DiskFull(m, name, n)
            status = sweep_main(tiny_spec_file, out)
        err = capsys.readouterr().err.strip()
        assert inj.fired and status == 4, (name, n, status, err)
        assert err.count("\n") == 0 and "gsa sweep: error: disk full: writing" in err
        assert "the last intact checkpoint is" in err and no_temp_files(out) == []
    assert sweep_main(tiny_spec_file, out) == 0
    assert canonical_rows(out / "metrics.csv") == canonical_rows(inprocess / "metrics.csv")
    assert json.loads((out / "sweep.json").read_text())["failed_runs"] == []


def test_unreadable_group_state_falls_back(tiny_spec_file, inprocess, tmp_path, capsys):
    """...and the printed `--resume DIR` alone continues the sweep as its sweep.json recorded it."""
    import shlex

    from gsa_jax.sweep import main

    out = tmp_path / "trunc"
    capsys.readouterr()
    assert main([tiny_spec_file, "--out", str(out), "--no-watchdog", "--local-processes", "1", "--stop-after-chunks", "3",
                 "--no-tensorboard"]) == 0
    hint = shlex.split(capsys.readouterr().out.strip().splitlines()[-1].split("or: ", 1)[1])
    assert hint[-3:] == ["sweep", "--resume", str(out)] or hint[1:] == ["-m", "gsa_jax.sweep", "--resume", str(out)], hint
    state = out / "groups" / "inverted_double_pendulum-mixture" / "state.npz"
    state.write_bytes(state.read_bytes()[:1000])
    assert main(hint[hint.index("--resume"):] + ["--no-watchdog", "--quiet"]) == 0  # worker count and TensorBoard setting as recorded
    assert not (out / "tensorboard").exists() and not (out / "process-0").exists()
    printed = capsys.readouterr()
    assert "state.npz is unreadable" in printed.out + printed.err and "state.prev.npz" in printed.out + printed.err
    assert canonical_rows(out / "metrics.csv") == canonical_rows(inprocess / "metrics.csv")


def test_changed_spec_and_second_writer_refused(tiny_spec_file, tmp_path, capsys):
    from gsa_jax.running.runlock import acquire, release

    out = tmp_path / "changed"
    assert sweep_main(tiny_spec_file, out, "--stop-after-chunks", "1") == 0
    changed = tmp_path / "tiny.toml"
    changed.write_text(open(tiny_spec_file).read().replace("steps = 3072", "steps = 4096"))
    capsys.readouterr()
    assert sweep_main(changed, out) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "steps: 3072 -> 4096" in err and "--force" in err
    assert sweep_main(changed, out, "--resume", str(out)) == 2  # an experiment given with --resume: compared too
    assert "steps: 3072 -> 4096" in capsys.readouterr().err
    from gsa_jax.sweep import main

    for argv, message in (([], "give an experiment file (TOML), or --resume DIR"),
                          (["--resume", str(tmp_path / "none")], "no sweep there (no sweep.json)"),
                          (["--resume", str(out), "--out", str(tmp_path)], "name different directories")):
        assert main(argv + ["--no-watchdog", "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err
    lock = acquire(str(out), "another sweep")
    try:
        assert sweep_main(tiny_spec_file, out) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and f"in use by pid {os.getpid()}" in err and "another sweep" in err
    finally:
        release(lock)


# Last in this file (with the parts test after it): it compiles the group with 2 runs per sub-batch, which replaces the
# 4-run program the tests above reuse in this process (gsa_jax.running.programs keeps one).
def test_sweep_in_sub_batches_matches_all_at_once(tiny_spec_file, inprocess, tmp_path):
    """--run-batch 2: the group's 4 runs trained as 2 sequential sub-batches give the same runs."""
    out = tmp_path / "sub"
    assert run_sweep(load_spec(tiny_spec_file), str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), quiet=True, run_batch=2))
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=2e-3)
    assert json.loads((out / "sweep.json").read_text())["run_batch"] == 2


def test_a_group_trained_in_parts_equals_the_group_whole(tiny_spec_file, inprocess, tmp_path, capsys):
    """--runs-per-program 2: the group's 4 runs trained as two parts of 2 (groups/<group> and <group>-part2), one
    program compiled once and reused by the second part, give the same runs; every run is found and read back."""
    from gsa_jax.running.trained import finished_runs

    out = tmp_path / "parts"
    assert run_sweep(load_spec(tiny_spec_file), str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), runs_per_program=2))
    printed = [line for line in capsys.readouterr().out.splitlines() if "; program " in line]
    assert len(printed) == 2 and "program reused" in printed[1] and "program reused" not in printed[0]
    group = "inverted_double_pendulum-mixture"
    assert sorted(os.listdir(out / "groups")) == [group, group + "-part2"]
    assert_same_results(read_rows(str(out / "metrics.csv")), read_rows(str(inprocess / "metrics.csv")), rtol=2e-3)
    assert json.loads((out / "sweep.json").read_text())["runs_per_program"] == 2
    found = finished_runs(str(out))
    assert [os.path.basename(r[1]) for r in found] == [group] * 2 + [group + "-part2"] * 2  # parts in order
    assert sorted((r[3]["K"], r[3]["seed"]) for r in found) == [("1", "0"), ("1", "1"), ("3", "0"), ("3", "1")]
    with pytest.raises(ResumeRefused, match="--runs-per-program 2, not 0"):  # other parts would train them again
        run_sweep(load_spec(tiny_spec_file), str(out), SweepOptions(devices=tuple(jax.local_devices()[:1])))
    from gsa_jax.sweep import main  # the supervisor refuses before any worker starts (workers 1.. would not check)

    capsys.readouterr()
    assert main([str(tiny_spec_file), "--out", str(out), "--local-processes", "2", "--runs-per-program", "3"]) == 2
    captured = capsys.readouterr()
    assert "--runs-per-program 2, not 3" in captured.err and "worker processes" not in captured.out


def test_group_of_an_older_file_format_refused_in_one_line(tiny_spec_file, inprocess, tmp_path, capsys):
    """A finished group whose metrics.npz lacks a tracked metric (an older gsa_jax wrote it) is refused with
    one line that says how to go on; nothing is filled in silently."""
    import shutil

    out = tmp_path / "old"
    shutil.copytree(inprocess, out)
    path = out / "groups" / "inverted_double_pendulum-mixture" / "metrics.npz"
    with np.load(path) as m:
        arrays = {k: m[k] for k in m.files if k != "failed_at"}
    np.savez(path, **arrays)
    capsys.readouterr()
    assert sweep_main(tiny_spec_file, out) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "older gsa_jax (no failed_at)" in err and "git_commit" in err


def test_a_sweep_job_travels_to_its_workers_as_json_and_splits_over_the_local_processes(tiny_spec_file, tmp_path):
    """gsa sweep's settings become one SweepJob (gsa_jax.orchestration.sweep_job); its JSON text, a worker's argument,
    reads back as the same job, and its local workers are one job each (process i of N, each a worker of one
    process); a text that is not a job is one line and exit status 2, before anything trains."""
    from gsa_jax.commands.sweep import job_of, parse_args
    from gsa_jax.orchestration.sweep_job import job_from_json, job_to_json, main, worker_dir, worker_jobs

    job = job_of(parse_args([tiny_spec_file, "--out", str(tmp_path / "s"), "--local-processes", "3",
                             "--runs-per-program", "4", "--no-tensorboard"]))
    assert (job.local, job.watchdog, job.worker, job.runs_per_program, job.tensorboard) == (3, True, False, 4, False)
    assert job_from_json(job_to_json(job)) == job
    workers = worker_jobs(job)
    assert [(w.process_id, w.num_processes, w.local, w.worker) for w in workers] == [(i, 3, 1, True) for i in range(3)]
    assert [worker_dir(w) for w in workers] == [os.path.join(job.out, f"process-{i}") for i in range(3)]
    assert worker_jobs(job._replace(local=1)) == [job._replace(local=1, worker=True)]
    assert main(["{not json"]) == 2 and main([]) == 2


def test_the_public_api_reads_a_sweep_as_the_tables_do(inprocess):
    """gsa_jax.sweep_runs, select_run and load_sweep (the API the experiment scripts use) are the sweep's finished
    runs, its one run of a cell and seed, and its curves, as extraction and the tables read them; a cell the sweep
    does not hold is a UserError (one line)."""
    import gsa_jax
    from gsa_jax.analysis.sweeps.results import load_sweep
    from gsa_jax.errors import UserError
    from gsa_jax.running.trained import finished_runs

    runs = gsa_jax.sweep_runs(str(inprocess))
    assert runs == finished_runs(str(inprocess)) and len(runs) == 4
    env = runs[0][3]["env"]
    address = gsa_jax.select_run(str(inprocess), env, "mixture", 3, 1)
    label = next(r[0] for r in runs if (r[3]["K"], r[3]["seed"]) == ("3", "1"))
    assert address == os.path.join(str(inprocess), label)
    with pytest.raises(UserError, match="0 finished runs"):
        gsa_jax.select_run(str(inprocess), env, "mixture", 2, 0)
    assert gsa_jax.load_sweep(str(inprocess)).keys() == load_sweep(str(inprocess)).keys()
    curves = gsa_jax.load_sweep(str(inprocess), ["eval_return"])
    assert all(set(seeds) == {0, 1} and list(next(iter(seeds.values()))) == ["eval_return"] for seeds in curves.values())
