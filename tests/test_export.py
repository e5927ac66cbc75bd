"""Export round trip: the NumPy controller acts like the JAX deterministic policy."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.policies import make_policy
from gsa_jax.algorithm.ppo import make_hparams
from gsa_jax.deployment import numpy_policy
from gsa_jax.export import main as export_main
from gsa_jax.running.checkpoint import save_pytree

D_S, D_A = 6, 2


def fake_run(tmp_path, kind, K, k_max, subpolicy="linear"):
    """A run directory as train.py writes it, with trained-looking (random) parameters."""
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
    (run / "runs.csv").write_text(f"env,policy,K,seed\ntoy,{kind},{K},0\n")
    config = {"policy": kind, "normalize_obs": True, "subpolicy": subpolicy}
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
    np.testing.assert_allclose(ctrl.act(obs), np.asarray(a_jax), rtol=1e-5, atol=1e-5)
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


def assert_same_controller(ctrl, obs, action, cluster):
    """Clusters equal except at float32 near-ties of the two best logits; where clusters agree, actions to 1e-5
    of the magnitude of the terms they sum (1e-5 absolute for small terms)."""
    ref_c, ref_a = ctrl.cluster(obs), ctrl.act(obs)
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
    assert [o.name for o in model.graph.output] == ["action", "cluster"]
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    obs = test_observations(ctrl)
    action, cluster = sess.run(None, {"obs": obs})
    assert action.dtype == np.float32 and cluster.dtype == np.int64 and cluster.shape == (len(obs),)
    assert_same_controller(ctrl, obs, action, cluster)


HARNESS = r"""
#define GSA_CONTROLLER_IMPLEMENTATION
#include "controller.h"
#include <stdio.h>
int other_unit(const float *obs);
int main(void) {
    float obs[GSA_OBS_DIM], action[GSA_ACT_DIM];
    int cluster;
    while (fread(obs, sizeof(float), GSA_OBS_DIM, stdin) == GSA_OBS_DIM) {
        gsa_act(obs, action, &cluster);
        if (cluster != other_unit(obs)) return 3;
        fwrite(action, sizeof(float), GSA_ACT_DIM, stdout);
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


@pytest.mark.parametrize("kind, K, k_max, subpolicy", CASES)
def test_c_export_compiles_and_matches_numpy(tmp_path, kind, K, k_max, subpolicy, capsys):
    """The header compiles warning-free as C99 (-Wall -Wextra -pedantic -Werror), links from two files, and
    gsa_act agrees with numpy_policy on thousands of observations."""
    import subprocess

    cc = c_compiler()
    if cc is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH")
    ctrl, _, run = exported(tmp_path, kind, K, k_max, subpolicy)
    capsys.readouterr()
    assert export_main([str(run), "--format", "c", "--out", str(tmp_path / "controller.h")]) == 0
    assert "multiply-adds" in capsys.readouterr().out
    (tmp_path / "main.c").write_text(HARNESS)
    (tmp_path / "other.c").write_text(OTHER_UNIT)
    subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Werror", "-o", str(tmp_path / "ctrl"),
                    str(tmp_path / "main.c"), str(tmp_path / "other.c"), "-lm"], check=True, cwd=tmp_path)
    obs = test_observations(ctrl)
    r = subprocess.run([str(tmp_path / "ctrl")], input=obs.tobytes(), capture_output=True, check=True)
    d_a = ctrl.act(obs[:1]).shape[-1]
    rec = np.frombuffer(r.stdout, dtype=np.dtype([("a", np.float32, (d_a,)), ("c", np.int32)]))
    assert len(rec) == len(obs)
    assert_same_controller(ctrl, obs, rec["a"], rec["c"].astype(np.int64))


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
    with pytest.raises(SystemExit):
        export_main([str(run), "--format", "tflite"])
