"""Mixture / MLP policy math against an independent NumPy computation, masking, init."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm.config import make_hparams
from gsa_jax.algorithm.policies import bias_spread, component, draw_noise, feature_size, make_policy, partition_entropy

D_S, D_A = 5, 3


def np_mlp(layers, x):
    for i, layer in enumerate(layers):
        x = x @ np.asarray(layer["w"], np.float64) + np.asarray(layer["b"], np.float64)
        if i < len(layers) - 1:
            x = np.tanh(x)
    return x


def np_features(subpolicy, obs):
    """Sub-policy features, written out with explicit loops."""
    if subpolicy == "constant":
        return np.zeros(0)
    if subpolicy == "linear":
        return np.asarray(obs, np.float64)
    quad = [obs[i] * obs[j] for i in range(len(obs)) for j in range(i, len(obs))]
    return np.concatenate([obs, quad])


def np_mixture_log_prob(params, obs, action, c, K, eps, sigma_min, subpolicy="linear"):
    logits = np_mlp(params["partition"], obs)[:K]
    soft = np.exp(logits - logits.max())
    soft /= soft.sum()
    p = (1 - eps) * soft + eps / K
    L = np.asarray(params["L"], np.float64)[c]
    b = np.asarray(params["b"], np.float64)[c]
    sigma = np.maximum(np.exp(np.asarray(params["log_sigma"], np.float64)[c]), sigma_min)
    mean = L @ np_features(subpolicy, obs) + b
    log_n = np.sum(-0.5 * ((action - mean) / sigma) ** 2 - np.log(sigma) - 0.5 * np.log(2 * np.pi))
    return np.log(p[c]) + log_n, p


def random_mixture_params(policy, key, K):
    """Init, then randomise every leaf so the check is not on a special point (L=0, zero head)."""
    params = policy.init(key, make_hparams(K=K, sigma_init_scale=1.0))
    leaves, treedef = jax.tree.flatten(params)
    keys = jax.random.split(jax.random.PRNGKey(7), len(leaves))
    leaves = [0.5 * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)]
    return jax.tree.unflatten(treedef, leaves)


def sched(K, eps=0.1, sigma_min=0.05):
    return {"K": jnp.int32(K), "epsilon": jnp.float32(eps), "sigma_min": jnp.float32(sigma_min)}


@pytest.fixture(scope="module")
def mix16():
    return make_policy("mixture", D_S, D_A, k_max=16)


@pytest.fixture(scope="module")
def mix4():
    return make_policy("mixture", D_S, D_A, k_max=4)


@pytest.fixture(scope="module", params=["mlp", "linear"])
def masked_pair(request):
    """(K_max = 16, K_max = 4) mixtures of one partition class."""
    return tuple(make_policy("mixture", D_S, D_A, k_max=k, partition=request.param) for k in (16, 4))


def test_mixture_log_prob_matches_numpy(mix16):
    K = 5
    params = random_mixture_params(mix16, jax.random.PRNGKey(0), K)
    rng = np.random.default_rng(0)
    lp = jax.jit(mix16.log_prob)
    for eps, smin in [(0.1, 0.05), (0.0, 0.0), (0.5, 2.0)]:
        for _ in range(5):
            obs = rng.normal(size=D_S)
            act = rng.normal(size=D_A)
            c = int(rng.integers(K))
            ref, p_ref = np_mixture_log_prob(params, obs, act, c, K, eps, smin)
            got = lp(params, jnp.asarray(obs, jnp.float32), jnp.asarray(act, jnp.float32), jnp.int32(c), sched(K, eps, smin))
            np.testing.assert_allclose(float(got), ref, rtol=1e-4, atol=1e-4)
            probs = mix16.partition_probs(params, jnp.asarray(obs, jnp.float32), sched(K, eps, smin))
            np.testing.assert_allclose(np.asarray(probs[:K]), p_ref, rtol=1e-5, atol=1e-6)
            assert np.all(np.asarray(probs[K:]) == 0.0)


@pytest.mark.parametrize("subpolicy", ["constant", "quadratic"])
def test_subpolicy_classes_match_numpy(subpolicy):
    """constant: a = b_c; quadratic: a = L_c [s, s_i s_j (i <= j)] + b_c -- log-probs and modes vs NumPy."""
    K = 3
    pol = make_policy("mixture", D_S, D_A, k_max=4, subpolicy=subpolicy)
    params = random_mixture_params(pol, jax.random.PRNGKey(2), K)
    assert params["L"].shape == (4, D_A, feature_size(subpolicy, D_S))
    assert feature_size(subpolicy, D_S) == {"constant": 0, "quadratic": D_S + D_S * (D_S + 1) // 2}[subpolicy]
    rng = np.random.default_rng(3)
    lp, mode = jax.jit(pol.log_prob), jax.jit(pol.mode)
    for _ in range(5):
        obs, act, c = rng.normal(size=D_S), rng.normal(size=D_A), int(rng.integers(K))
        ref, _ = np_mixture_log_prob(params, obs, act, c, K, 0.1, 0.05, subpolicy)
        o32 = jnp.asarray(obs, jnp.float32)
        got = lp(params, o32, jnp.asarray(act, jnp.float32), jnp.int32(c), sched(K))
        np.testing.assert_allclose(float(got), ref, rtol=1e-4, atol=1e-4)
        a, cm = mode(params, o32, sched(K))
        L, b = np.asarray(params["L"], np.float64)[int(cm)], np.asarray(params["b"], np.float64)[int(cm)]
        np.testing.assert_allclose(np.asarray(a), L @ np_features(subpolicy, obs) + b, rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="unknown subpolicy"):
        make_policy("mixture", D_S, D_A, subpolicy="cubic")


def test_component_is_the_cluster_s_gaussian_and_its_gradient_touches_only_that_cluster():
    """mean = L[c] phi + b[c] exactly, std = max(exp(log_sigma[c]), sigma_min) (XLA's exp to 1e-6); d mean_i / d L is phi in
    row (c, i) and zero for every other cluster."""
    rng = np.random.default_rng(0)
    params = {"L": jnp.asarray(rng.normal(size=(4, D_A, D_S)), jnp.float32),
              "b": jnp.asarray(rng.normal(size=(4, D_A)), jnp.float32),
              "log_sigma": jnp.asarray(rng.normal(size=(4, D_A)), jnp.float32)}
    phi = jnp.asarray(rng.normal(size=D_S), jnp.float32)
    mean, sigma = component(params, phi, 2, 0.5)
    np.testing.assert_array_equal(np.asarray(mean), np.asarray(params["L"][2] @ phi + params["b"][2]))
    np.testing.assert_allclose(np.asarray(sigma), np.maximum(np.exp(np.asarray(params["log_sigma"][2])), 0.5), rtol=1e-6)
    grad_l = np.asarray(jax.grad(lambda p: component(p, phi, 2, 0.5)[0][1])(params)["L"])
    expected = np.zeros((4, D_A, D_S), np.float32)
    expected[2, 1] = np.asarray(phi)
    np.testing.assert_array_equal(grad_l, expected)


def test_partition_entropy_matches_numpy(mix16):
    K = 6
    params = random_mixture_params(mix16, jax.random.PRNGKey(1), K)
    obs = jnp.asarray(np.random.default_rng(1).normal(size=D_S), jnp.float32)
    probs = np.asarray(mix16.partition_probs(params, obs, sched(K, 0.2)), np.float64)
    active = probs[:K]
    np.testing.assert_allclose(float(partition_entropy(jnp.asarray(probs))), -np.sum(active * np.log(active)), rtol=1e-5)
    assert float(partition_entropy(jnp.ones((1,)))) == 0.0
    np.testing.assert_allclose(float(partition_entropy(jnp.full((4,), 0.25))), np.log(4), rtol=1e-6)


def test_epsilon_uniform_and_sampling_frequencies(mix16):
    """A partition net that strongly prefers one cluster still gives every active cluster >= eps/K,
    masked ones exactly 0; sampled clusters follow the mixed probabilities."""
    K, eps = 4, 0.2
    params = random_mixture_params(mix16, jax.random.PRNGKey(2), K)
    params["partition"][-1]["b"] = params["partition"][-1]["b"].at[2].set(50.0)
    obs = jnp.zeros((D_S,))
    probs = np.asarray(mix16.partition_probs(params, obs, sched(K, eps)))
    assert np.all(probs[:K] >= eps / K - 1e-7) and np.all(probs[K:] == 0)
    np.testing.assert_allclose(probs[:K].sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(probs[2], 1 - eps + eps / K, rtol=1e-5)
    n = 20000
    _, c, _ = jax.jit(jax.vmap(mix16.sample, in_axes=(None, None, 0, None)))(
        params, obs, draw_noise(jax.random.PRNGKey(3), (n,), D_A), sched(K, eps)
    )
    freq = np.bincount(np.asarray(c), minlength=16) / n
    assert np.all(freq[K:] == 0)
    np.testing.assert_allclose(freq[:K], probs[:K], atol=4 * np.sqrt(0.25 / n))


def test_sigma_min_floor(mix16):
    """sigma_c far below sigma_min: samples, log-probs and the objective all use sigma_min."""
    K, smin = 3, 0.3
    params = random_mixture_params(mix16, jax.random.PRNGKey(4), K)
    params["log_sigma"] = jnp.full_like(params["log_sigma"], -8.0)
    obs = jnp.asarray(np.random.default_rng(4).normal(size=D_S), jnp.float32)
    n = 20000
    a, c, logp = jax.jit(jax.vmap(mix16.sample, in_axes=(None, None, 0, None)))(
        params, obs, draw_noise(jax.random.PRNGKey(5), (n,), D_A), sched(K, 0.1, smin)
    )
    a, c = np.asarray(a), np.asarray(c)
    mean = np.einsum("nij,j->ni", np.asarray(params["L"])[c], np.asarray(obs)) + np.asarray(params["b"])[c]
    np.testing.assert_allclose(np.std(a - mean, axis=0), smin, rtol=0.03)
    ref, _ = np_mixture_log_prob(params, np.asarray(obs, np.float64), a[0].astype(np.float64), c[0], K, 0.1, smin)
    np.testing.assert_allclose(float(logp[0]), ref, rtol=1e-4, atol=1e-4)


def test_masked_k_equals_unpadded(masked_pair):
    """K=4 inside K_max=16 == K=4 with K_max=4, for every partition class: init, samples, log-probs, deterministic
    actions, gradients."""
    mix16, mix4 = masked_pair
    K = 4
    hp = make_hparams(K=K, sigma_init_scale=1.0)
    p16 = mix16.init(jax.random.PRNGKey(0), hp)
    p4 = mix4.init(jax.random.PRNGKey(0), hp)
    np.testing.assert_array_equal(np.asarray(p16["b"][:K]), np.asarray(p4["b"]))
    np.testing.assert_array_equal(np.asarray(p16["log_sigma"][:K]), np.asarray(p4["log_sigma"]))
    for l16, l4 in zip(p16["partition"][:-1], p4["partition"][:-1]):
        np.testing.assert_array_equal(np.asarray(l16["w"]), np.asarray(l4["w"]))
    for layer in (p16["partition"][-1], p4["partition"][-1]):  # zero last layer: uniform at init
        assert not np.any(np.asarray(layer["w"])) and not np.any(np.asarray(layer["b"]))
    # train-like params: random, with the K active clusters of p16 equal to p4
    p4 = random_mixture_params(mix4, jax.random.PRNGKey(8), K)
    p16 = random_mixture_params(mix16, jax.random.PRNGKey(9), K)
    p16["L"] = p16["L"].at[:K].set(p4["L"])
    p16["b"] = p16["b"].at[:K].set(p4["b"])
    p16["log_sigma"] = p16["log_sigma"].at[:K].set(p4["log_sigma"])
    p16["partition"] = [dict(l) for l in p4["partition"]]
    p16["partition"][-1] = {
        "w": jnp.concatenate([p4["partition"][-1]["w"], jnp.ones((p4["partition"][-1]["w"].shape[0], 12))], axis=1),
        "b": jnp.concatenate([p4["partition"][-1]["b"], jnp.full((12,), 9.0)]),
    }
    s = sched(K, 0.15, 0.05)
    obs = jax.random.normal(jax.random.PRNGKey(10), (256, D_S))
    noise = draw_noise(jax.random.PRNGKey(11), (256,), D_A)
    samp = lambda pol, p: jax.jit(jax.vmap(pol.sample, in_axes=(None, 0, 0, None)))(p, obs, noise, s)
    a16, c16, l16 = samp(mix16, p16)
    a4, c4, l4 = samp(mix4, p4)
    np.testing.assert_array_equal(np.asarray(c16), np.asarray(c4))
    np.testing.assert_allclose(np.asarray(a16), np.asarray(a4), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(l16), np.asarray(l4), rtol=1e-5, atol=1e-5)
    m16 = jax.vmap(mix16.mode, in_axes=(None, 0, None))(p16, obs, s)
    m4 = jax.vmap(mix4.mode, in_axes=(None, 0, None))(p4, obs, s)
    np.testing.assert_array_equal(np.asarray(m16[1]), np.asarray(m4[1]))
    np.testing.assert_allclose(np.asarray(m16[0]), np.asarray(m4[0]), rtol=1e-6, atol=1e-6)

    def loss(pol, p):
        return jnp.mean(jax.vmap(pol.log_prob, in_axes=(None, 0, 0, 0, None))(p, obs, a4, c4, s))

    g16 = jax.grad(lambda p: loss(mix16, p))(p16)
    g4 = jax.grad(lambda p: loss(mix4, p))(p4)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(g16))
    np.testing.assert_allclose(np.asarray(g16["L"][:K]), np.asarray(g4["L"]), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(np.asarray(g16["partition"][-1]["w"][:, :K]), np.asarray(g4["partition"][-1]["w"]), rtol=1e-4, atol=1e-6)
    for name in ("L", "b", "log_sigma"):
        assert np.all(np.asarray(g16[name][K:]) == 0.0), name
    assert np.all(np.asarray(g16["partition"][-1]["w"][:, K:]) == 0.0)


def test_init_properties(mix16):
    for K in (1, 2, 6, 16):
        p = mix16.init(jax.random.PRNGKey(K), make_hparams(K=K, sigma_init_scale=0.8))
        assert np.all(np.asarray(p["L"]) == 0.0)
        np.testing.assert_allclose(np.exp(np.asarray(p["log_sigma"])), 0.8 / K, rtol=1e-6)
        b = np.asarray(p["b"][:K])
        assert np.all(np.abs(b) <= 1.0)
        if K > 1:
            d = np.linalg.norm(b[:, None] - b[None], axis=-1) + np.eye(K) * 9
            assert d.min() > 0.2, f"biases of K={K} not spread: min distance {d.min()}"
        # the partition starts uniform over the active clusters
        probs = mix16.partition_probs(p, jnp.ones((D_S,)), sched(K, 0.3))
        np.testing.assert_allclose(np.asarray(probs[:K]), 1.0 / K, rtol=1e-5)
    np.testing.assert_array_equal(bias_spread(1, 3), np.zeros((1, 3)))
    assert np.abs(bias_spread(64, 1)).max() <= 1.0
    # spread fills the box: every orthant of [-1,1]^3 gets a bias among the first 24
    signs = {tuple(x) for x in np.sign(bias_spread(24, 3)[1:])}
    assert len([s for s in signs if 0 not in s]) == 8


def test_mlp_policy_log_prob_matches_numpy():
    pol = make_policy("mlp", D_S, D_A)
    params = pol.init(jax.random.PRNGKey(0), make_hparams(init_log_std=0.0))
    params["log_std"] = jnp.asarray([-0.5, 0.0, 0.3])
    rng = np.random.default_rng(3)
    obs, act = rng.normal(size=D_S), rng.normal(size=D_A)
    mean = np_mlp(params["mlp"], obs)
    sig = np.exp(np.asarray(params["log_std"], np.float64))
    ref = np.sum(-0.5 * ((act - mean) / sig) ** 2 - np.log(sig) - 0.5 * np.log(2 * np.pi))
    got = pol.log_prob(params, jnp.asarray(obs, jnp.float32), jnp.asarray(act, jnp.float32), 0, sched(1))
    np.testing.assert_allclose(float(got), ref, rtol=1e-5)


def test_unknown_policy_kind():
    with pytest.raises(ValueError, match="choose one of mixture, mlp"):
        make_policy("rbf", 3, 1)
