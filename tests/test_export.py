"""Export round trip: the NumPy controller acts like the JAX deterministic policy."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax import numpy_policy
from gsa_jax.checkpoint import save_pytree
from gsa_jax.export import main as export_main
from gsa_jax.normalize import normalize
from gsa_jax.policies import make_policy

D_S, D_A = 6, 2


def fake_run(tmp_path, kind, K, k_max, subpolicy="linear"):
    """A run directory as train.py writes it, with trained-looking (random) parameters."""
    pol = make_policy(kind, D_S, D_A, k_max, subpolicy=subpolicy)
    params = pol.init(jax.random.PRNGKey(0), {"K": jnp.int32(K), "sigma_init_scale": jnp.float32(1.0)})
    leaves, tdef = jax.tree.flatten(params)
    keys = jax.random.split(jax.random.PRNGKey(1), len(leaves))
    params = jax.tree.unflatten(tdef, [jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)])
    stats = {"count": jnp.float32(100.0), "mean": jnp.linspace(-1, 1, D_S), "var": jnp.linspace(0.5, 3, D_S)}
    run = tmp_path / f"{kind}-run"
    run.mkdir()
    save_pytree(str(run / "params.npz"), {"params": {"policy": params}, "obs_stats": stats})
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
    assert "is not a directory" in capsys.readouterr().err
    assert export_main([str(tmp_path)]) == 2
    assert "is not a gsa_jax run: config.json is missing" in capsys.readouterr().err


def test_numpy_policy_imports_without_jax():
    import subprocess
    import sys

    code = "import sys; import gsa_jax.numpy_policy; assert 'jax' not in sys.modules, 'jax was imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("subpolicy, d_phi", [("constant", 0), ("linear", 3), ("quadratic", 9)])
def test_controller_table_every_class(subpolicy, d_phi):
    """inspect's controllers.md: one row per actuator, the linear terms as columns, strongest inputs
    ranked over every feature (e.g. the quadratic term x*z)."""
    from gsa_jax.inspect import controller_table, feature_names

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
