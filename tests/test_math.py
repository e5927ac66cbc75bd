"""GAE, Adam, clipping, running statistics and checkpoints against hand/NumPy references."""

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm.normalize import init_stats, normalize, update_stats
from gsa_jax.algorithm.optim import adam_step, clip_by_global_norm, init_adam
from gsa_jax.algorithm.ppo import compute_gae
from gsa_jax.running.checkpoint import load_pytree, save_pytree


def test_gae_hand_computed_truncation_vs_termination():
    """One env, 4 steps. Step 1 ends by the time limit (bootstrap from V(final obs)=10),
    step 3 by termination (bootstrap 0). gamma=0.5, lambda=0.5 so the numbers are exact."""
    g, lam = 0.5, 0.5
    r = jnp.array([[1.0], [2.0], [3.0], [4.0]])
    v = jnp.array([[1.0], [1.0], [2.0], [2.0]])
    nv = jnp.array([[1.0], [10.0], [2.0], [7.0]])  # V(next obs); at t=1 the true final obs before reset
    term = jnp.array([[0.0], [0.0], [0.0], [1.0]])
    done = jnp.array([[0.0], [1.0], [0.0], [1.0]])
    adv, target = compute_gae(r, v, nv, term, done, g, lam)
    # deltas: t0: 1+.5*1-1 = .5 ; t1: 2+.5*10-1 = 6 ; t2: 3+.5*2-2 = 2 ; t3: 4+0-2 = 2
    # A3 = 2 ; A2 = 2 + .25*A3 = 2.5 ; A1 = 6 (episode end) ; A0 = .5 + .25*6 = 2
    np.testing.assert_allclose(np.asarray(adv[:, 0]), [2.0, 6.0, 2.5, 2.0])
    np.testing.assert_allclose(np.asarray(target[:, 0]), [3.0, 7.0, 4.5, 4.0])
    # the same step 1 as a termination instead: no bootstrap
    adv_t, _ = compute_gae(r, v, nv, term.at[1, 0].set(1.0), done, g, lam)
    np.testing.assert_allclose(float(adv_t[1, 0]), 1.0)
    np.testing.assert_allclose(float(adv_t[0, 0]), 0.5 + 0.25 * 1.0)


def test_gae_lambda_one_is_discounted_return_minus_value():
    rng = np.random.default_rng(0)
    T, g = 7, 0.9
    r = rng.normal(size=(T, 3)).astype(np.float32)
    v = rng.normal(size=(T, 3)).astype(np.float32)
    nv = np.concatenate([v[1:], rng.normal(size=(1, 3)).astype(np.float32)])
    zeros = np.zeros_like(r)
    adv, _ = compute_gae(jnp.asarray(r), jnp.asarray(v), jnp.asarray(nv), zeros, zeros, g, 1.0)
    ret = nv[-1].astype(np.float64)
    expect = np.zeros((T, 3))
    for t in reversed(range(T)):
        ret = r[t] + g * ret
        expect[t] = ret - v[t]
    np.testing.assert_allclose(np.asarray(adv), expect, rtol=1e-5, atol=1e-5)


def test_adam_matches_numpy_reference():
    rng = np.random.default_rng(0)
    p_np = {"a": rng.normal(size=(3, 2)), "b": rng.normal(size=(4,))}
    params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), p_np)
    state = init_adam(params)
    m = jax.tree.map(np.zeros_like, p_np)
    v = jax.tree.map(np.zeros_like, p_np)
    lr, b1, b2, eps = 0.01, 0.9, 0.999, 1e-8
    step = jax.jit(adam_step)
    for t in range(1, 6):
        g_np = jax.tree.map(lambda x: rng.normal(size=x.shape), p_np)
        params, state = step(params, jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), g_np), state, lr)
        for k in p_np:
            m[k] = b1 * m[k] + (1 - b1) * g_np[k]
            v[k] = b2 * v[k] + (1 - b2) * g_np[k] ** 2
            p_np[k] = p_np[k] - lr * (m[k] / (1 - b1**t)) / (np.sqrt(v[k] / (1 - b2**t)) + eps)
        for k in p_np:
            np.testing.assert_allclose(np.asarray(params[k]), p_np[k], rtol=1e-5, atol=1e-6)
    assert int(state["count"]) == 5


def test_clip_by_global_norm():
    g = {"a": jnp.array([3.0, 0.0]), "b": jnp.array([[4.0]])}
    clipped, norm = clip_by_global_norm(g, 1.0)
    np.testing.assert_allclose(float(norm), 5.0)
    np.testing.assert_allclose(np.asarray(clipped["a"]), [0.6, 0.0], rtol=1e-6)
    unchanged, _ = clip_by_global_norm(g, 10.0)
    np.testing.assert_allclose(np.asarray(unchanged["b"]), [[4.0]])


def test_running_stats_match_numpy():
    rng = np.random.default_rng(0)
    batches = [rng.normal(loc=3.0, scale=2.0, size=(n, 4)) for n in (5, 50, 17)]
    stats = init_stats(4)
    for b in batches:
        stats = update_stats(stats, jnp.asarray(b, jnp.float32))
    allx = np.concatenate(batches)
    np.testing.assert_allclose(np.asarray(stats["mean"]), allx.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(stats["var"]), allx.var(0), rtol=1e-3)
    z = normalize(stats, jnp.asarray(allx, jnp.float32))
    np.testing.assert_allclose(np.asarray(z).mean(0), 0.0, atol=1e-3)
    scalar = update_stats(init_stats(None), jnp.asarray(allx[:, 0], jnp.float32).reshape(9, 8))
    np.testing.assert_allclose(float(scalar["mean"]), allx[:, 0].mean(), rtol=1e-4)


def test_checkpoint_round_trip(tmp_path):
    tree = {"p": [{"w": jnp.arange(6.0).reshape(2, 3), "b": jnp.zeros(3)}], "k": jnp.int32(7)}
    path = tmp_path / "x.npz"
    save_pytree(str(path), tree)
    back = load_pytree(str(path), tree)
    for a, b in zip(jax.tree.leaves(tree), jax.tree.leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert np.asarray(a).dtype == np.asarray(b).dtype
    assert [p.name for p in tmp_path.iterdir()] == ["x.npz"]  # no temp file left behind


def test_checkpoint_of_a_dict_state_loads_into_the_named_tuple(tmp_path):
    """A state.npz written when the training state was a dict of the same fields resumes as TrainState."""
    from gsa_jax.algorithm.run_parts import TrainState

    fields = {f: {"a": np.arange(3.0) + i} if f == "params" else np.float32(i) for i, f in enumerate(TrainState._fields)}
    save_pytree(str(tmp_path / "old.npz"), fields)
    back = load_pytree(str(tmp_path / "old.npz"), TrainState(**fields))
    assert isinstance(back, TrainState) and float(back.iteration) == TrainState._fields.index("iteration")
    np.testing.assert_array_equal(back.params["a"], np.arange(3.0))


def test_orthogonal_init_without_lapack():
    """Semi-orthogonal for every MLP shape, scaled; and no LAPACK call in a vmapped init (batched QR
    deadlocks XLA:CPU's thread pool on 2 cores)."""
    from gsa_jax.algorithm.nn import orthogonal

    for shape in [(11, 64), (64, 64), (64, 1), (1, 64), (64, 24)]:
        w = np.asarray(orthogonal(jax.random.PRNGKey(3), shape, scale=2.0)) / 2.0
        g = w.T @ w if shape[0] >= shape[1] else w @ w.T
        np.testing.assert_allclose(g, np.eye(g.shape[0]), atol=2e-6)
    hlo = jax.jit(jax.vmap(lambda k: orthogonal(k, (64, 64)))).lower(jax.random.split(jax.random.PRNGKey(0), 4)).as_text()
    assert "lapack" not in hlo.lower()


def test_gaussians_are_each_shapes_own_draw_in_one_draw():
    """nn.gaussians gives, bit for bit, the numbers jax.random.normal draws for each key and shape alone (JAX's
    partitionable threefry: an element's bits depend on its key and flat index only), vmapped over runs too; and an
    MLP's init draws them once: one threefry in its program where each layer drew its own (what made a run's init
    compile slower than its training chunk)."""
    from gsa_jax.algorithm.nn import gaussians, init_mlp

    shapes = [(64, 11), (64, 64), (64, 1), (3, 2)]
    keys = jax.random.split(jax.random.PRNGKey(7), len(shapes))
    alone = [np.asarray(jax.jit(lambda k, s=s: jax.random.normal(k, s, jnp.float32))(k)) for k, s in zip(keys, shapes)]
    for got, want in zip(jax.jit(lambda ks: gaussians(ks, shapes))(keys), alone):
        np.testing.assert_array_equal(np.asarray(got), want)
    other = jax.random.split(jax.random.PRNGKey(8), len(shapes))
    alone_other = [np.asarray(jax.random.normal(k, s, jnp.float32)) for k, s in zip(other, shapes)]
    for got, want, want_other in zip(jax.jit(jax.vmap(lambda ks: gaussians(ks, shapes)))(jnp.stack([keys, other])),
                                     alone, alone_other):
        np.testing.assert_array_equal(np.asarray(got)[0], want)
        np.testing.assert_array_equal(np.asarray(got)[1], want_other)
    hlo = jax.jit(lambda k: init_mlp(k, (11, 64, 64, 1))).lower(jax.random.PRNGKey(0)).as_text()
    assert hlo.count("func.func private @threefry2x32") == 2  # the key split's and the one draw


def test_mlp_init_layers_are_orthogonal_draws_of_their_keys():
    """init_mlp's layer i is orthogonal(key_i) of its own split key, scaled (equal up to float rounding: the draw is
    shared, the arithmetic the same); a zero out_scale gives a zero last layer; biases are zero."""
    from gsa_jax.algorithm.nn import init_mlp, orthogonal

    key, sizes = jax.random.PRNGKey(4), (11, 64, 64, 3)
    layers = init_mlp(key, sizes, hidden_scale=2.0, out_scale=0.5)
    for i, (k, d_in, d_out) in enumerate(zip(jax.random.split(key, 3), sizes[:-1], sizes[1:])):
        scale = 0.5 if i == 2 else 2.0
        np.testing.assert_allclose(np.asarray(layers[i]["w"]), np.asarray(orthogonal(k, (d_in, d_out), scale)), atol=2e-6)
        np.testing.assert_array_equal(np.asarray(layers[i]["b"]), np.zeros(d_out))
    zero_last = init_mlp(key, sizes, out_scale=0.0)
    np.testing.assert_array_equal(np.asarray(zero_last[-1]["w"]), np.zeros((64, 3)))
    np.testing.assert_allclose(np.asarray(zero_last[0]["w"]), np.asarray(layers[0]["w"]) / 2.0 * np.sqrt(2.0), atol=2e-6)


def test_orthogonal_init_is_newton_schulz_in_one_loop():
    """The polar factor by Newton-Schulz as a NumPy reference computes it from the same Gaussian draw; and the
    program holds the iteration once, as a loop (two matmuls), not unrolled into 2 x 60 (what XLA compiles for
    every init: the run's, a sweep group's)."""
    from gsa_jax.algorithm.nn import orthogonal

    key = jax.random.PRNGKey(5)
    x = np.asarray(jax.random.normal(key, (24, 9), jnp.float32), np.float64)
    x = x / np.linalg.norm(x)
    for _ in range(60):
        x = 1.5 * x - 0.5 * x @ (x.T @ x)
    np.testing.assert_allclose(np.asarray(orthogonal(key, (24, 9), scale=1.5)), 1.5 * x, atol=2e-6)
    np.testing.assert_allclose(np.asarray(orthogonal(key, (9, 24), scale=1.5)), 1.5 * x.T, atol=2e-6)  # wide: X^T
    hlo = jax.jit(lambda k: orthogonal(k, (64, 64))).lower(key).as_text()
    assert hlo.count("stablehlo.dot_general") == 2 and "stablehlo.while" in hlo
