"""gsa_jax.algorithm.subpolicies: a sub-policy class is one entry. A new class registered as one SubpolicyClass
acts through the JAX policy, the NumPy controller, the ONNX and C exports, inspection's names and the verifier's
Jacobian, with nothing else changed; and the three built-in classes keep their feature maps."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.config import make_hparams
from gsa_jax.algorithm.policies import feature_size, make_policy, subpolicy_features
from gsa_jax.deployment import export_c, export_onnx, numpy_policy
from gsa_jax.deployment.inspection import controller_table, feature_names
from tests.test_export import assert_same_controller, run_c_header, test_observations

D_S, D_A, K = 4, 2, 3


def square_onnx(node, const, z, d_s):
    node("Mul", [z, z], ["z_sq"])
    node("Concat", [z, "z_sq"], ["phi"], axis=1)
    return "phi"


SQUARE = subpolicies.SubpolicyClass(  # phi = [z, z_i^2]: a class the package does not have
    "square", "a = L_c [z, z_i^2] + b_c", size=lambda d_s: 2 * d_s,
    features=lambda z, xp=np: xp.concatenate([z, z * z], axis=-1),
    names=lambda obs_names: list(obs_names) + [f"{n}^2" for n in obs_names],
    jacobian=lambda z: np.concatenate([np.eye(len(z)), np.diag(2.0 * z)]),
    onnx=square_onnx,
    c=lambda d_s: ([f"float phi[{2 * d_s}];", f"for (i = 0; i < {d_s}; ++i) {{ phi[i] = z[i]; phi[{d_s} + i] = z[i] * z[i]; }}"],
                   "phi"),
    madds=lambda d_s: d_s)


@pytest.fixture
def square():
    subpolicies.register(SQUARE)
    yield SQUARE
    del subpolicies.SUBPOLICIES[SQUARE.name]


def controller_arrays(sub, seed=0):
    """An exported mixture controller of Hopper-v5's action bounds with random arrays (numpy_policy's layout)."""
    rng = np.random.default_rng(seed)
    d_phi = subpolicies.get(sub).size(D_S)
    arrays = {"kind": np.array("mixture"), "subpolicy": np.array(sub), "partition": np.array("mlp"),
              "obs_mean": rng.normal(0, 0.1, D_S).astype(np.float32),
              "obs_var": rng.uniform(0.5, 2.0, D_S).astype(np.float32), "obs_clip": np.array(10.0, np.float32),
              "config_json": np.array(json.dumps({"config": {"env": "Hopper-v5", "policy": "mixture"}, "seed": seed})),
              "action_low": -np.ones(D_A, np.float32), "action_high": np.ones(D_A, np.float32), "n_layers": np.array(2),
              "L": rng.normal(0, 0.3, (K, D_A, d_phi)).astype(np.float32), "b": rng.normal(0, 0.3, (K, D_A)).astype(np.float32)}
    for i, (n_in, n_out) in enumerate([(D_S, 16), (16, K)]):
        arrays[f"w{i}"] = rng.normal(0, 0.5, (n_in, n_out)).astype(np.float32)
        arrays[f"b{i}"] = rng.normal(0, 0.1, n_out).astype(np.float32)
    return arrays


def test_builtin_classes_features_sizes_and_names():
    z = np.arange(1.0, 4.0)
    assert list(subpolicies.SUBPOLICIES) == ["constant", "linear", "quadratic"]
    assert subpolicies.CONSTANT.features(z, np).shape == (0,)
    np.testing.assert_array_equal(subpolicies.LINEAR.features(z, np), z)
    np.testing.assert_array_equal(subpolicies.QUADRATIC.features(z, np), [1, 2, 3, 1, 2, 3, 4, 6, 9])
    for sub in subpolicies.SUBPOLICIES.values():
        assert len(sub.features(z, np)) == sub.size(3) == len(sub.names(["x", "y", "z"])) == len(sub.jacobian(z))
    with pytest.raises(ValueError, match="unknown subpolicy 'cubic'; choose one of constant, linear, quadratic"):
        subpolicies.get("cubic")
    with pytest.raises(ValueError, match="exists"):
        subpolicies.register(subpolicies.LINEAR)


def test_a_registered_class_works_in_the_jax_policy(square):
    assert feature_size("square", D_S) == 2 * D_S
    obs = jnp.linspace(-1.0, 1.0, D_S)
    np.testing.assert_allclose(subpolicy_features("square", obs), np.concatenate([obs, obs * obs]))
    pol = make_policy("mixture", D_S, D_A, k_max=K, subpolicy="square")
    params = pol.init(jax.random.PRNGKey(0), make_hparams(K=K, sigma_init_scale=1.0))
    assert params["L"].shape == (K, D_A, 2 * D_S)


def test_a_registered_class_works_in_numpy_onnx_c_inspection_and_verify(square, tmp_path):
    arrays = controller_arrays("square")
    ctrl = numpy_policy.Controller(arrays)
    obs = test_observations(ctrl, n=1000)
    z = ctrl.normalize(obs)
    c = ctrl.cluster(obs)
    expected = np.einsum("nij,nj->ni", ctrl.L[c], np.concatenate([z, z * z], axis=-1)) + ctrl.b[c]
    np.testing.assert_allclose(ctrl.act(obs, clip=False), expected, rtol=1e-5, atol=1e-5)
    (tmp_path / "controller.h").write_text(export_c.to_source(arrays))
    assert export_c.cost(arrays)["multiply_adds"] == D_S + 16 * D_S + K * 16 + D_A * 2 * D_S + D_S
    action, raw, cluster = run_c_header(tmp_path, obs, D_A)
    assert_same_controller(ctrl, obs, action, cluster)
    assert_same_controller(ctrl, obs, raw, cluster, clip=False)
    assert feature_names("square", ["x", "y"]) == ["x", "y", "x^2", "y^2"]
    table = controller_table({"policy": {"L": ctrl.L, "b": ctrl.b}}, K, list("abcd"), ["a0", "a1"], "square")
    assert "a = L_c [z, z_i^2] + b_c" in table and "# Square controllers" in table
    from gsa_jax.verify.linearize import piece_jacobian

    o = (ctrl.obs_mean + 0.2 * ctrl.obs_std * np.array([1.0, -1.0, 0.5, -0.5])).astype(np.float64)
    _, jac = piece_jacobian(ctrl, o, 0)  # piece 0 everywhere: a = L_0 phi(z(o)) + b_0, checked by central differences
    piece = lambda x: ctrl.L[0].astype(np.float64) @ SQUARE.features((x - ctrl.obs_mean) / ctrl.obs_std) + ctrl.b[0]  # noqa: E731
    fd = np.stack([(piece(o + e) - piece(o - e)) / (2e-3) for e in np.eye(D_S) * 1e-3], axis=1)
    inside = np.abs(piece(o)) < 1.0  # the clip's rows are zero
    assert inside.any() and np.all(np.abs(ctrl.normalize(o)) < ctrl.obs_clip)
    np.testing.assert_allclose(jac[inside], fd[inside], rtol=1e-6, atol=1e-8)
    ort = pytest.importorskip("onnxruntime")
    sess = ort.InferenceSession(export_onnx.to_bytes(arrays), providers=["CPUExecutionProvider"])
    action, cluster, raw = sess.run(None, {"obs": obs})
    assert_same_controller(ctrl, obs, action, cluster)
    assert_same_controller(ctrl, obs, raw, cluster, clip=False)
