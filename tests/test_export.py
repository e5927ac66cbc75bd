"""Export round trip: the NumPy controller acts like the JAX deterministic policy; the NumPy, ONNX and C controllers
keep actions inside the task's bounds (raw actions on request); the README's snippet scores a committed controller."""

import csv
import glob
import gzip
import json
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm.config import make_hparams
from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.policies import make_policy
from gsa_jax.deployment import numpy_policy
from gsa_jax.export import main as export_main
from gsa_jax.running.checkpoint import save_pytree
from gsa_jax.running.formats import FORMAT_VERSION, read_controller

D_S, D_A = 6, 2  # the fake runs' sizes; their task (Hopper-v5) only names their action bounds, [-1, 1]
ROOT = os.path.join(os.path.dirname(__file__), "..")


def fake_run(tmp_path, kind, K, k_max, subpolicy="linear", env="Hopper-v5"):
    """A run directory of task `env` as train.py writes it, with trained-looking (random) parameters."""
    pol = make_policy(kind, D_S, D_A, k_max, subpolicy=subpolicy)
    params = pol.init(jax.random.PRNGKey(0), make_hparams(K=K, sigma_init_scale=1.0))
    leaves, tdef = jax.tree.flatten(params)
    keys = jax.random.split(jax.random.PRNGKey(1), len(leaves))
    params = jax.tree.unflatten(tdef, [jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)])
    stats = {"count": jnp.float32(100.0), "mean": jnp.linspace(-1, 1, D_S), "var": jnp.linspace(0.5, 3, D_S)}
    run = tmp_path / f"{kind}-run"
    run.mkdir()
    one = jax.tree.map(lambda x: np.asarray(x)[None], {"params": {"policy": params}, "obs_stats": stats})  # a group of one
    save_pytree(str(run / "params.npz"), one)
    (run / "runs.csv").write_text(f"env,policy,K,seed\n{env},{kind},{K},0\n")
    config = {"env": env, "policy": kind, "normalize_obs": True, "subpolicy": subpolicy}
    (run / "config.json").write_text(json.dumps({"config": config, "hparams": {"K": K}, "seed": 0}))
    return pol, params, stats, run


@pytest.mark.parametrize("kind, K, k_max, subpolicy", [
    ("mixture", 3, 8, "linear"), ("mixture", 1, 1, "linear"), ("mlp", 1, 1, "linear"),
    ("mixture", 3, 4, "constant"), ("mixture", 2, 4, "quadratic"),
])
def test_numpy_controller_matches_jax(tmp_path, kind, K, k_max, subpolicy, capsys):
    pol, params, stats, run = fake_run(tmp_path, kind, K, k_max, subpolicy)
    out = tmp_path / "controller.npz"
    assert export_main([str(run), "--out", str(out)]) == 0
    ctrl = numpy_policy.load(str(out))
    obs = np.random.default_rng(0).normal(scale=3.0, size=(500, D_S)).astype(np.float32)
    sched = {"K": jnp.int32(K), "epsilon": jnp.float32(0.1), "sigma_min": jnp.float32(0.0)}
    a_jax, c_jax = jax.vmap(pol.mode, in_axes=(None, 0, None))(params, normalize(stats, jnp.asarray(obs)), sched)
    np.testing.assert_allclose(ctrl.act(obs, clip=False), np.asarray(a_jax), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ctrl.act(obs), np.clip(np.asarray(a_jax), -1.0, 1.0), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(ctrl.cluster(obs), np.asarray(c_jax))
    assert ctrl.act(obs[0]).shape == (D_A,)  # single observation
    if kind == "mixture":
        assert ctrl.num_clusters == K and set(np.unique(ctrl.cluster(obs))) <= set(range(K))
        assert ctrl.subpolicy == subpolicy


def test_export_bad_run_dir(tmp_path, capsys):
    assert export_main([str(tmp_path / "missing")]) == 2
    assert "is not a gsa_jax run: neither a run directory" in capsys.readouterr().err
    assert export_main([str(tmp_path)]) == 2
    assert "is not a gsa_jax run: neither a run directory" in capsys.readouterr().err


def test_numpy_policy_imports_without_jax():
    import subprocess
    import sys

    code = "import sys; import gsa_jax.deployment.numpy_policy; assert 'jax' not in sys.modules, 'jax was imported'"
    subprocess.run([sys.executable, "-c", code], check=True)
    # a committed file without bounds: they come from its task's name, with no JAX and no MuJoCo
    legacy = ("import sys; from gsa_jax.deployment import numpy_policy; "
              f"assert numpy_policy.load({os.path.join(ROOT, COMMITTED['Ant-v5'])!r}).action_low is not None; "
              "assert not {'jax', 'mujoco'} & set(sys.modules), 'jax or mujoco was imported'")
    subprocess.run([sys.executable, "-c", legacy], check=True)


@pytest.mark.parametrize("subpolicy, d_phi", [("constant", 0), ("linear", 3), ("quadratic", 9)])
def test_controller_table_every_class(subpolicy, d_phi):
    """inspect's controllers.md: one row per actuator, the linear terms as columns, strongest inputs
    ranked over every feature (e.g. the quadratic term x*z)."""
    from gsa_jax.deployment.inspection import controller_table, feature_names

    names = feature_names(subpolicy, ["x", "y", "z"])
    assert len(names) == d_phi and (subpolicy != "quadratic" or names[3:] == ["x*x", "x*y", "x*z", "y*y", "y*z", "z*z"])
    L = np.zeros((2, 2, d_phi))
    if d_phi:
        L[0, 1, d_phi - 1 if subpolicy != "quadratic" else 5] = -3.0  # z for linear, x*z for quadratic
    table = controller_table({"policy": {"L": L, "b": np.full((2, 2), 0.5)}}, 2, ["x", "y", "z"], ["a0", "a1"], subpolicy)
    rows = [line for line in table.splitlines() if line.startswith(("| a0 ", "| a1 "))]
    assert len(rows) == 4 and all(r.count("|") == rows[0].count("|") for r in rows)
    if d_phi:
        assert ("x*z (-3.00)" if subpolicy == "quadratic" else "z (-3.00)") in rows[1]


# --- ONNX and C exports against numpy_policy -------------------------------------------------------

CASES = [("mixture", 3, 8, "linear"), ("mixture", 1, 1, "linear"), ("mlp", 1, 1, "linear"),
         ("mixture", 3, 4, "constant"), ("mixture", 2, 4, "quadratic")]


def exported(tmp_path, kind, K, k_max, subpolicy):
    """(NumPy controller, its arrays, run dir) of a random fake run."""
    _, _, _, run = fake_run(tmp_path, kind, K, k_max, subpolicy)
    npz = tmp_path / "controller.npz"
    assert export_main([str(run), "--out", str(npz)]) == 0
    with np.load(npz) as f:
        arrays = {k: f[k] for k in f.files}
    return numpy_policy.load(str(npz)), arrays, run


def test_observations(ctrl, n=4000):
    """n observations spread over the normalizer's range and beyond (so the clip acts too)."""
    rng = np.random.default_rng(1)
    return (ctrl.obs_mean + ctrl.obs_std * rng.normal(scale=4.0, size=(n, ctrl.obs_mean.shape[0]))).astype(np.float32)


test_observations.__test__ = False  # a helper, not a test


def assert_same_controller(ctrl, obs, action, cluster, clip=True):
    """Clusters equal except at float32 near-ties of the two best logits; where clusters agree, actions (ctrl.act's,
    clip as given) to 1e-5 of the magnitude of the terms they sum (1e-5 absolute for small terms)."""
    ref_c, ref_a = ctrl.cluster(obs), ctrl.act(obs, clip=clip)
    if ctrl.kind == "mixture" and ctrl.num_clusters > 1:
        logits = np.sort(ctrl._mlp(ctrl.normalize(obs))[:, : ctrl.num_clusters].astype(np.float64), axis=1)
        tie = logits[:, -1] - logits[:, -2] < 1e-4
        assert tie.mean() < 0.01, "too many near-ties to compare"
    else:
        tie = np.zeros(len(obs), bool)
    np.testing.assert_array_equal(cluster[~tie], ref_c[~tie])
    same = cluster == ref_c
    err = np.abs(action[same] - ref_a[same]) / term_scale(ctrl, obs[same], ref_c[same])
    assert err.max() < 1e-5, f"max error {err.max():.3g} of the terms' magnitude"


def term_scale(ctrl, obs, cluster):
    """max(1, sum of |terms|) of each action entry [n, d_a]: float32 sums of such terms round to ~1e-7 of it."""
    if ctrl.kind == "mlp":
        x = ctrl.normalize(obs)
        for w, b in ctrl.layers[:-1]:
            x = np.tanh(x @ w + b)
        w, b = ctrl.layers[-1]
        return np.maximum(np.abs(x) @ np.abs(w) + np.abs(b), 1.0)
    if ctrl.L.shape[-1] == 0:
        return np.ones_like(ctrl.act(obs))
    phi = ctrl.features(ctrl.normalize(obs))
    terms = np.einsum("nij,nj->ni", np.abs(ctrl.L[cluster]), np.abs(phi)) + np.abs(ctrl.b[cluster])
    return np.maximum(terms, 1.0)


@pytest.mark.parametrize("kind, K, k_max, subpolicy", CASES)
def test_onnx_export_matches_numpy(tmp_path, kind, K, k_max, subpolicy):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    ctrl, _, run = exported(tmp_path, kind, K, k_max, subpolicy)
    path = tmp_path / "controller.onnx"
    assert export_main([str(run), "--out", str(path)]) == 0  # the format from the suffix
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    assert [o.name for o in model.graph.output] == ["action", "cluster", "raw_action"]
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    obs = test_observations(ctrl)
    action, cluster, raw = sess.run(None, {"obs": obs})
    assert action.dtype == np.float32 and cluster.dtype == np.int64 and cluster.shape == (len(obs),)
    assert_same_controller(ctrl, obs, action, cluster)
    assert_same_controller(ctrl, obs, raw, cluster, clip=False)


HARNESS = r"""
#define GSA_CONTROLLER_IMPLEMENTATION
#include "controller.h"
#include <stdio.h>
int other_unit(const float *obs);
int main(void) {
    float obs[GSA_OBS_DIM], action[GSA_ACT_DIM], raw[GSA_ACT_DIM];
    int cluster, raw_cluster;
    while (fread(obs, sizeof(float), GSA_OBS_DIM, stdin) == GSA_OBS_DIM) {
        gsa_act(obs, action, &cluster);
        gsa_act_raw(obs, raw, &raw_cluster);
        if (cluster != other_unit(obs) || cluster != raw_cluster) return 3;
        fwrite(action, sizeof(float), GSA_ACT_DIM, stdout);
        fwrite(raw, sizeof(float), GSA_ACT_DIM, stdout);
        fwrite(&cluster, sizeof(int), 1, stdout);
    }
    return 0;
}
"""
OTHER_UNIT = r"""
#include "controller.h"
int other_unit(const float *obs) { float a[GSA_ACT_DIM]; int c; gsa_act(obs, a, &c); return c; }
"""


def c_compiler():
    import shutil

    return next((shutil.which(c) for c in ("cc", "gcc", "clang") if shutil.which(c)), None)


def run_c_header(tmp_path, obs, d_a):
    """Compile tmp_path/controller.h with HARNESS (C99, -Wall -Wextra -pedantic -Werror, two files) and run it on obs
    [n, d_s] -> (gsa_act's actions [n, d_a], gsa_act_raw's [n, d_a], clusters [n])."""
    import subprocess

    cc = c_compiler()
    if cc is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH")
    (tmp_path / "main.c").write_text(HARNESS)
    (tmp_path / "other.c").write_text(OTHER_UNIT)
    subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Werror", "-o", str(tmp_path / "ctrl"),
                    str(tmp_path / "main.c"), str(tmp_path / "other.c"), "-lm"], check=True, cwd=tmp_path)
    r = subprocess.run([str(tmp_path / "ctrl")], input=obs.tobytes(), capture_output=True, check=True)
    record = np.dtype([("a", np.float32, (d_a,)), ("raw", np.float32, (d_a,)), ("c", np.int32)])
    rec = np.frombuffer(r.stdout, dtype=record)
    assert len(rec) == len(obs)
    return rec["a"], rec["raw"], rec["c"].astype(np.int64)


@pytest.mark.parametrize("kind, K, k_max, subpolicy", CASES)
def test_c_export_compiles_and_matches_numpy(tmp_path, kind, K, k_max, subpolicy, capsys):
    """The header compiles warning-free as C99 (-Wall -Wextra -pedantic -Werror), links from two files, and
    gsa_act (and gsa_act_raw) agree with numpy_policy's act(obs) (and act(obs, clip=False)) on thousands of
    observations."""
    ctrl, _, run = exported(tmp_path, kind, K, k_max, subpolicy)
    capsys.readouterr()
    assert export_main([str(run), "--format", "c", "--out", str(tmp_path / "controller.h")]) == 0
    assert "multiply-adds" in capsys.readouterr().out
    obs = test_observations(ctrl)
    action, raw, cluster = run_c_header(tmp_path, obs, ctrl.action_size)
    assert_same_controller(ctrl, obs, action, cluster)
    assert_same_controller(ctrl, obs, raw, cluster, clip=False)


def test_export_formats_and_errors(tmp_path, capsys):
    """An exported .npz re-exports; a junk .npz, an unknown format and a missing --out directory are one-line errors."""
    _, arrays, run = exported(tmp_path, "mixture", 3, 4, "linear")
    assert export_main([str(tmp_path / "controller.npz"), "--out", str(tmp_path / "again.h")]) == 0
    assert "#define GSA_NUM_CLUSTERS 3" in (tmp_path / "again.h").read_text()
    np.save(tmp_path / "junk.npy", np.zeros(3))
    junk = tmp_path / "junk.npz"
    np.savez(junk, x=np.zeros(3))
    capsys.readouterr()
    assert export_main([str(junk), "--format", "c"]) == 2
    assert "is not an exported controller" in capsys.readouterr().err
    assert export_main([str(run), "--out", str(tmp_path / "no" / "dir" / "c.onnx")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert export_main([str(run), "--format", "tflite"]) == 2
    assert capsys.readouterr().err.strip() == ("gsa export: error: argument --format: invalid choice: 'tflite' "
                                              "(choose from 'c', 'npz', 'onnx') (see gsa export --help)")
    assert export_main([str(run), "--out", str(tmp_path / "ctrl.pt")]) == 2  # an unknown suffix, no --format
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown suffix" in err and "--format" in err and ".onnx" in err, err
    assert not (tmp_path / "ctrl.pt").exists()


# --- action bounds: every format keeps actions inside the task's bounds; the README's use scores as committed -------

COMMITTED = {  # one committed controller per task family, exported before the bounds were stored in the file
    "Ant-v5": "experiments/fig1_v5/results/fig1_v5_Ant-v5_seeds_0_4/controllers/Ant-v5-mixture-K4-s0.npz",
    "hopper": "experiments/robustness/results/brax_hopper_c/training_seeds_0_4/controllers/hopper-mlp-s0.npz",
}


def test_action_range_is_every_tasks_actuator_range():
    """envs.ACTION_RANGE, what training clips to and act() clips to, is each locomotion task's actuator ctrlrange and
    gymnasium's action space, or (ctrl_range 'model': dmc:quadruped-walk) maps onto the ctrlrange end to end;
    allegro_cylinder clips its own actions (PD-target steps) to it."""
    import gymnasium

    import envs
    from envs.mujoco_c import make_c

    for name in envs.NAMES:
        if name == "allegro_cylinder":
            continue
        ranges = envs.control_range(name)
        controls = np.transpose(envs.action_bounds(name)) if ranges is None else np.transpose(ranges)
        np.testing.assert_array_equal(envs.task_model(name).actuator_ctrlrange, controls, err_msg=name)
    assert [n for n in envs.NAMES if envs.control_range(n) is not None] == ["dmc:quadruped-walk"]
    for env_id in envs.GYM_V5_TASKS:
        space = gymnasium.make(env_id).action_space
        np.testing.assert_array_equal([space.low, space.high], envs.action_bounds(env_id), err_msg=env_id)
    hand = make_c("allegro_cylinder")
    steps = [(hand.reset(0), hand.step(np.full(8, a))[0])[1] for a in (envs.ACTION_RANGE[1], 5.0)]
    np.testing.assert_array_equal(steps[0], steps[1])


def far_observations(ctrl, n=500):
    """n observations about 1e3 times the training distribution's [n, d_s]."""
    z = np.random.default_rng(2).normal(size=(n, ctrl.obs_mean.shape[0]))
    return (1e3 * (ctrl.obs_mean + ctrl.obs_std * z)).astype(np.float32)


def assert_bounded(action, raw, low, high):
    """action inside [low, high] and equal to raw clipped to them, where raw leaves them (else nothing is tested)."""
    assert np.any((raw < low) | (raw > high)), "the raw actions never leave the bounds"
    assert np.all((action >= low) & (action <= high))
    np.testing.assert_array_equal(action, np.clip(raw, low, high))


@pytest.mark.parametrize("task", sorted(COMMITTED))
def test_committed_controllers_act_inside_their_tasks_bounds(tmp_path, task, capsys):
    """A committed controller (no bounds in its file: they come from the task it names) and its npz, ONNX and C
    exports: actions inside the task's bounds for observations far outside training's, raw actions on request."""
    import envs

    path = os.path.join(ROOT, COMMITTED[task])
    with np.load(path) as f:
        assert "action_low" not in f.files and numpy_policy.task_name(f) == task
    low, high = envs.action_bounds(task)  # sized by the task's MJCF
    ctrl = numpy_policy.load(path)
    np.testing.assert_array_equal([ctrl.action_low, ctrl.action_high], [low, high])
    obs = far_observations(ctrl)
    raw = ctrl.act(obs, clip=False)
    assert_bounded(ctrl.act(obs), raw, low, high)
    out = {fmt: str(tmp_path / f"controller.{fmt}") for fmt in ("npz", "onnx", "h")}
    for fmt in out:
        assert export_main([path, "--out", out[fmt]]) == 0
    with np.load(out["npz"]) as f:
        np.testing.assert_array_equal([f["action_low"], f["action_high"]], [low, high])
    np.testing.assert_array_equal(numpy_policy.load(out["npz"]).act(obs), ctrl.act(obs))
    assert_bounded(*run_c_header(tmp_path, obs, ctrl.action_size)[:2], low, high)
    ort = pytest.importorskip("onnxruntime")
    sess = ort.InferenceSession(out["onnx"], providers=["CPUExecutionProvider"])
    action, cluster, raw_onnx = sess.run(None, {"obs": obs})
    assert_bounded(action, raw_onnx, low, high)
    assert_same_controller(ctrl, obs, raw_onnx, cluster, clip=False)


def test_controller_without_bounds_or_known_task(tmp_path, capsys):
    """A file without bounds takes its task's; naming no known task, act() returns the raw action after one warning
    line, and export refuses in one line."""
    _, arrays, _ = exported(tmp_path, "mixture", 3, 4, "linear")
    old = {k: v for k, v in arrays.items() if k not in ("action_low", "action_high")}
    np.testing.assert_array_equal(numpy_policy.Controller(old).action_high, np.ones(D_A, np.float32))
    obs = far_observations(numpy_policy.Controller(arrays))
    toy = {**old, "config_json": np.array(json.dumps({"config": {"env": "toy"}}))}
    with pytest.warns(UserWarning, match="stores no action bounds and its task 'toy' is not a known task") as caught:
        ctrl = numpy_policy.Controller(toy)
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    np.testing.assert_array_equal(ctrl.act(obs), ctrl.act(obs, clip=False))
    with pytest.raises(ValueError, match="stores no action bounds"):
        ctrl.bounds()
    np.savez(tmp_path / "toy.npz", **toy)
    capsys.readouterr()
    assert export_main([str(tmp_path / "toy.npz"), "--out", str(tmp_path / "toy.h")]) == 2
    err = capsys.readouterr().err
    assert "names no known task ('toy'), so no action bounds to export" in err and err.count("\n") == 1


def readme_snippet():
    """The README's Python block that runs a controller in gymnasium."""
    with open(os.path.join(ROOT, "README.md")) as f:
        blocks = re.findall(r"```python\n(.*?)```", f.read(), re.S)
    return next(b for b in blocks if "numpy_policy.load" in b and "env.step" in b)


def committed_scores(path):
    """(score over the robustness experiment's 20 nominal start states, MuJoCo C, gymnasium's start seeds; its
    fig1_v5 score: the mean over 16 evaluation episodes at the end of training) of a committed Ant-v5 controller."""
    name = os.path.basename(path)[:-4]
    policy, k, seed = re.fullmatch(r"Ant-v5-(mixture|mlp)-K?(\d*)-?s(\d+)", name).groups()
    res = os.path.join(ROOT, "experiments", "robustness", "results", "Ant-v5")
    with open(os.path.join(res, "robustness.csv")) as f:
        nominal = next(float(r["score"]) for r in csv.DictReader(f) if r["shift"] == "nominal"
                       and (r["policy"], r["K"], r["seed"]) == (policy, k, seed))
    rows = []
    for metrics in glob.glob(os.path.join(os.path.dirname(os.path.dirname(path)), "metrics-process-*.csv.gz")):
        with gzip.open(metrics, "rt") as f:
            rows += [r for r in csv.DictReader(f) if (r["policy"], r["K"], r["seed"]) == (policy, k or "1", seed)
                     and r["eval_return"]]
    with open(os.path.join(res, "robustness.json")) as f:
        seeds = range(*json.load(f)["start_seeds"])  # [first, last + 1]
    return nominal, float(max(rows, key=lambda r: int(r["iteration"]))["eval_return"]), seeds


def test_readme_snippet_scores_the_committed_ant_controller(monkeypatch):
    """The README's snippet, as written (its controller: Ant-v5 K = 4 seed 0), run in gymnasium.make("Ant-v5") from
    the robustness experiment's 20 start states, scores its committed nominal score there (to its CSV's rounding;
    gymnasium and MuJoCo C step alike) and its committed fig1_v5 score (16 other episodes) within two standard errors;
    with the raw action, which gymnasium charges control cost on, it scores less."""
    code = readme_snippet()
    path = re.search(r'numpy_policy\.load\("([^"]+)"\)', code).group(1)
    nominal, final_eval, seeds = committed_scores(os.path.join(ROOT, path))
    assert len(seeds) == 20 and code.count("seed=0)") == 1 and code.count("ctrl.act(obs)") == 1
    monkeypatch.chdir(ROOT)

    def scores(snippet):
        out = []
        for s in seeds:
            ns = {}
            exec(snippet.replace("seed=0)", f"seed={s})"), ns)
            out.append(ns["score"])
        return np.array(out)

    clipped = scores(code)
    assert abs(clipped.mean() - nominal) < 1e-2, (clipped.mean(), nominal)
    noise = 2 * clipped.std(ddof=1) * np.sqrt(1 / len(seeds) + 1 / 16)
    assert abs(clipped.mean() - final_eval) < noise, (clipped.mean(), final_eval, noise)
    raw = scores(code.replace("ctrl.act(obs)", "ctrl.act(obs, clip=False)"))
    assert raw.mean() < nominal - 10.0 and np.all(raw <= clipped + 1e-6), (raw.mean(), nominal)


# --- what a controller was trained on: task, observation size, definition sha256; exactly K clusters ---------------


def test_export_records_its_task_and_exactly_k_clusters(tmp_path, capsys):
    """A run's export (K = 3 of K_max = 8) carries its task, observation size and the task definition's sha256 (the
    run's config.json) in npz, ONNX metadata and the C header; its partition outputs are the K clusters only, and a
    committed padded file re-exports to its K as well."""
    _, _, _, run = fake_run(tmp_path, "mixture", 3, 8)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "task": {"task": "Hopper-v5", "sha256": "ab" * 32}}))
    out = {fmt: str(tmp_path / f"c.{fmt}") for fmt in ("npz", "onnx", "h")}
    for path in out.values():
        assert export_main([str(run), "--out", path]) == 0
    with np.load(out["npz"]) as f:
        assert (str(f["task"]), int(f["obs_size"]), str(f["task_sha256"])) == ("Hopper-v5", D_S, "ab" * 32)
        last = int(f["n_layers"]) - 1
        assert f[f"w{last}"].shape[-1] == 3 and f[f"b{last}"].shape == (3,) and f["L"].shape[0] == 3
    header = open(out["h"]).read()
    assert f"Task Hopper-v5, observation size {D_S}, task definition sha256 {'ab' * 32}." in header
    onnx = pytest.importorskip("onnx")
    props = {p.key: p.value for p in onnx.load(out["onnx"]).metadata_props}
    assert (props["task"], props["obs_size"], props["task_sha256"]) == ("Hopper-v5", str(D_S), "ab" * 32)
    padded = os.path.join(ROOT, COMMITTED["Ant-v5"])
    assert export_main([padded, "--out", out["npz"]]) == 0
    f, old = read_controller(out["npz"]), read_controller(padded)  # the committed file: format_version 0
    last = int(f["n_layers"]) - 1
    assert old[f"w{last}"].shape[-1] > 4 and f[f"w{last}"].shape[-1] == 4 and str(f["task_sha256"]) == ""
    assert int(f["format_version"]) == FORMAT_VERSION and str(f["partition"]) == "mlp"
    obs = far_observations(numpy_policy.Controller(f))
    np.testing.assert_array_equal(numpy_policy.Controller(f).act(obs), numpy_policy.Controller(old).act(obs))


def deploy_lines(controller, *flags, out=None):
    """(exit status, stderr) of `python -m gsa_jax.deploy controller` for one short episode, in a new process (each
    reads the task's file afresh); out: a list that receives its stdout."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "gsa_jax.deploy", str(controller), "--episodes", "1",
                           "--episode-length", "5", *flags], capture_output=True, text=True, timeout=300, cwd=ROOT)
    if out is not None:
        out.append(done.stdout)
    return done.returncode, done.stderr.strip()


def test_a_controller_whose_task_changed_is_refused_in_one_line(tmp_path):
    """deploy and numpy_policy.load(task=...) refuse a controller whose task definition's sha256 changed (--force
    runs it), that names another task, or whose observation size is no longer the task's (even with --force): one
    line, no traceback. A committed controller without the fields still deploys, labelled as the user's task."""
    import hashlib

    source = open(os.path.join(ROOT, "examples", "reacher.py")).read()
    mine = tmp_path / "mine.py"
    mine.write_text(source)
    name = f"{mine}:Reacher"
    committed = sorted(glob.glob(os.path.join(ROOT, "experiments", "your_task_reacher", "results", "controllers", "*.npz")))[0]
    assert deploy_lines(committed, out=(printed := []))[0] == 0
    assert "examples.reacher:Reacher: MuJoCo C (your task)," in printed[0], printed  # not "our port"
    with np.load(committed) as f:
        arrays = {k: f[k] for k in f.files}
    arrays.update(config_json=np.array(json.dumps({"config": {"env": name}})), task=np.array(name), obs_size=np.array(10),
                  task_sha256=np.array(hashlib.sha256(source.encode()).hexdigest()))
    np.savez(tmp_path / "ctrl.npz", **arrays)
    assert deploy_lines(tmp_path / "ctrl.npz") == (0, "")
    assert numpy_policy.load(str(tmp_path / "ctrl.npz"), task=name).obs_mean.shape == (10,)
    with pytest.raises(numpy_policy.TaskMismatch, match="is for task .*mine.py:Reacher', not 'examples.reacher:Reacher'"):
        numpy_policy.load(str(tmp_path / "ctrl.npz"), task="examples.reacher:Reacher")
    with pytest.raises(numpy_policy.TaskMismatch, match="takes 10 observation values and task 'hopper' now observes 11"):
        numpy_policy.load(str(tmp_path / "ctrl.npz"), task="hopper", force=True)
    mine.write_text(source + "\n# an edit\n")
    status, err = deploy_lines(tmp_path / "ctrl.npz")
    assert status == 2 and err.count("\n") == 0 and "changed since" in err and "--force" in err, err
    assert deploy_lines(tmp_path / "ctrl.npz", "--force")[0] == 0
    mine.write_text(source.replace("self._to_target(qpos, derived)], axis=1)", "self._to_target(qpos, derived)[:, :1]], axis=1)"))
    for flags in ((), ("--force",)):
        status, err = deploy_lines(tmp_path / "ctrl.npz", *flags)
        assert status == 2 and err.count("\n") == 0 and "takes 10 observation values" in err and "now observes 9" in err, err
    relabelled = {**arrays, "config_json": np.array(json.dumps({"config": {"env": "hopper"}}))}
    np.savez(tmp_path / "relabelled.npz", **relabelled)
    status, err = deploy_lines(tmp_path / "relabelled.npz")
    assert status == 2 and err.count("\n") == 0 and "takes 10 observation values and task 'hopper' now observes 11" in err, err


def dm_control_action_spec():
    """dm_control's action_spec of its quadruped, by its own function on its own model (suite.load itself fails
    under mujoco 4, tests/test_dmc.py)."""
    from types import SimpleNamespace

    import mujoco

    pytest.importorskip("dm_control")
    from dm_control.mujoco.engine import action_spec
    from dm_control.suite import common, quadruped

    xml = quadruped.make_model()
    model = mujoco.MjModel.from_xml_string(xml.decode() if isinstance(xml, bytes) else xml, common.ASSETS)
    return action_spec(SimpleNamespace(model=model))


def test_quadruped_controllers_act_in_dm_controls_action_spec(tmp_path, capsys):
    """dm_control's quadruped maps actions in [-1, 1] onto its actuators' ctrlrange: its exports (npz, ONNX, C) act in
    that range itself, dm_control's action_spec, on the task's own states and far outside them (the committed file,
    exported before, acts in [-1, 1], outside the spec); the actions are the committed controller's controls, and
    deploy's controller (back in [-1, 1], what our MuJoCo C task takes) acts as the committed one (float rounding)."""
    from envs.mujoco_c import make_c
    from gsa_jax.deployment.evaluation import load_controller, run_mujoco_c

    spec = dm_control_action_spec()
    committed = sorted(glob.glob(os.path.join(ROOT, "experiments", "atlas_dmc", "results", "quadruped-walk", "mixture",
                                              "controllers", "*.npz")))[0]
    old = numpy_policy.load(committed)
    out = {fmt: str(tmp_path / f"controller.{fmt}") for fmt in ("npz", "onnx", "h")}
    for path in out.values():
        assert export_main([committed, "--out", path]) == 0
    new = numpy_policy.load(out["npz"])
    task, rng, states = make_c("dmc:quadruped-walk"), np.random.default_rng(0), []
    states.append(task.reset(0))
    for _ in range(300):
        states.append(task.step(rng.uniform(-1, 1, 12))[0])
    obs = np.concatenate([np.array(states, np.float32), far_observations(new)])

    def inside(action):
        return np.all((action.astype(np.float64) >= spec.minimum) & (action.astype(np.float64) <= spec.maximum))

    assert not inside(old.act(obs)) and not np.array_equal(spec.maximum, np.ones(12))
    assert new.action_space == "controls" and inside(new.act(obs))
    np.testing.assert_allclose(new.act(obs), old.controls(old.act(obs)), rtol=1e-5, atol=1e-5)
    assert inside(run_c_header(tmp_path, obs, 12)[0])
    ort = pytest.importorskip("onnxruntime")
    assert inside(ort.InferenceSession(out["onnx"], providers=["CPUExecutionProvider"]).run(None, {"obs": obs})[0])
    unit, record, _ = load_controller(out["npz"])  # what deploy and robustness step our MuJoCo C task with: [-1, 1]
    np.testing.assert_allclose(unit.act(obs), old.act(obs), rtol=1e-5, atol=1e-5)
    assert record.name == "dmc:quadruped-walk"
    assert np.all(np.isfinite(run_mujoco_c(unit, record, {}, 1, 50)["returns"]))
