"""The pieces make_train binds, each alone, against NumPy references: ppo_loss, sgd_update and rollout
(on a toy task with a time limit, nothing from MJX), and the metric names the iteration returns."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.algorithm.nn import init_mlp
from gsa_jax.algorithm.optim import adam_step, clip_by_global_norm, init_adam
from gsa_jax.algorithm.ppo import rollout, schedule
from gsa_jax.algorithm.ppo_update import ppo_loss, sgd_update, shuffle, shuffle_by_sorts
from gsa_jax.algorithm.run_parts import Parts, TrainState
from gsa_jax.running.metrics import ITERATION_METRICS

HP = make_hparams(K=1, clip_eps=0.2, vf_coef=0.5, gamma=0.9, max_grad_norm=0.5)


def log_prob(params, obs, action, cluster, sched):
    """A toy Gaussian policy's log-probability: mean w * obs[:, 0], unit variance, clusters ignored."""
    return -0.5 * jnp.square(action[:, 0] - params["w"] * obs[:, 0])


def toy_parts(cfg=Config(num_envs=2, unroll_length=4, num_epochs=1, num_minibatches=1)):
    return Parts(cfg, ToyEnv(), None, None, 1, None, log_prob, None, None)


def minibatch(n=16, seed=0):
    rng = np.random.default_rng(seed)
    return {k: jnp.asarray(v, jnp.float32) for k, v in {
        "obs": rng.normal(size=(n, 1)), "action": rng.normal(size=(n, 1)), "cluster": np.zeros(n),
        "logp": rng.normal(size=n) * 0.3 - 0.5, "adv": rng.normal(size=n), "target": rng.normal(size=n)}.items()}


def toy_params(seed=1):
    return {"policy": {"w": jnp.float32(0.7)}, "value": init_mlp(jax.random.PRNGKey(seed), (1, 1))}


def reference_loss(params, mb, hp):
    """PPO's clipped surrogate + vf_coef x 0.5 MSE, in float64 NumPy."""
    mb = {k: np.asarray(v, np.float64) for k, v in mb.items()}
    w, lin = float(params["policy"]["w"]), params["value"][0]
    logp = -0.5 * (mb["action"][:, 0] - w * mb["obs"][:, 0]) ** 2
    ratio = np.exp(logp - mb["logp"])
    adv = (mb["adv"] - mb["adv"].mean()) / (mb["adv"].std() + 1e-8)
    eps = float(hp.clip_eps)
    pg = -np.mean(np.minimum(ratio * adv, np.clip(ratio, 1 - eps, 1 + eps) * adv))
    v = mb["obs"] @ np.asarray(lin["w"], np.float64) + np.asarray(lin["b"], np.float64)
    v_loss = 0.5 * np.mean((v[:, 0] - mb["target"]) ** 2)
    return pg + float(hp.vf_coef) * v_loss, pg, v_loss


def test_ppo_loss_matches_numpy():
    params, mb = toy_params(), minibatch()
    loss, aux = jax.jit(lambda prm, m: ppo_loss(toy_parts(), prm, m, HP, schedule(HP, jnp.int32(0))))(params, mb)
    ref, pg, v_loss = reference_loss(params, mb, HP)
    np.testing.assert_allclose([float(loss), float(aux["policy_loss"]), float(aux["value_loss"])], [ref, pg, v_loss], rtol=1e-5)
    assert 0.0 < float(aux["clip_fraction"]) < 1.0  # some ratios leave the clip range: the clipping is exercised


def test_sgd_update_with_one_minibatch_is_one_clipped_adam_step():
    """1 epoch x 1 minibatch = one Adam step on the whole batch's clipped gradient (the shuffle does not
    change a mean); 2 minibatches take two steps and end elsewhere."""
    p, params, batch = toy_parts(Config(num_envs=4, unroll_length=4, num_epochs=1, num_minibatches=1)), toy_params(), minibatch()
    sched, lr = schedule(HP, jnp.int32(0)), jnp.float32(1e-2)
    new, opt, stats = jax.jit(lambda prm, o, b: sgd_update(p, prm, o, b, HP, sched, lr, jax.random.PRNGKey(3)))(
        params, init_adam(params), batch)
    grads = jax.grad(lambda prm: ppo_loss(p, prm, batch, HP, sched)[0])(params)
    grads, gnorm = clip_by_global_norm(grads, HP.max_grad_norm)
    want, _ = adam_step(params, grads, init_adam(params), lr)
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(want)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)
    assert int(opt["count"]) == 1 and np.isclose(float(stats["grad_norm"]), float(gnorm))
    p2 = toy_parts(Config(num_envs=4, unroll_length=4, num_epochs=1, num_minibatches=2))
    _, opt2, _ = sgd_update(p2, params, init_adam(params), batch, HP, sched, lr, jax.random.PRNGKey(3))
    assert int(opt2["count"]) == 2


class ToyState(NamedTuple):
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    info: dict
    steps: jax.Array


class ToyEnv:
    """x' = x + a, reward -|x'|, a time limit of 3 steps (truncation) with auto-reset to x = 1 + 0.5 * env."""

    action_size = 1

    def reset(self, key):
        x = jnp.ones((1,)) + 0.5 * key[0].astype(jnp.float32)
        z = jnp.zeros(())
        return ToyState(x, z, z, {"final_obs": x, "truncation": z}, jnp.zeros((), jnp.int32))

    def step(self, s, a):
        x, steps = s.obs + a, s.steps + 1
        done = (steps >= 3).astype(jnp.float32)
        reset = self.reset(jnp.zeros(2, jnp.uint32)).obs + (s.obs - s.obs)  # same start for the toy
        return ToyState(jnp.where(done > 0, reset, x), -jnp.abs(x[0]), done,
                        {"final_obs": x, "truncation": done}, jnp.where(done > 0, 0, steps))


def orders_of_four_are_uniform(perms):
    """perms [4800, 4]: every row a permutation of range(4), and the 24 orders about equally frequent (each
    expected 200; a chi-square of 23 degrees of freedom stays far below 80)."""
    perms = np.asarray(perms)
    assert (np.sort(perms, axis=1) == np.arange(4)).all()
    _, counts = np.unique(perms, axis=0, return_counts=True)
    return len(counts) == 24 and np.sum((counts - 200.0) ** 2 / 200.0) < 80


def test_shuffle_is_a_uniform_permutation():
    """Each draw is a permutation of range(n) with int32 indices, uniform over the 24 orders of 4 items; at
    2,048 items (two rounds of sorts) still a permutation, and not the identity."""
    keys = jax.random.split(jax.random.PRNGKey(0), 4800)
    assert orders_of_four_are_uniform(jax.jit(jax.vmap(lambda k: shuffle(k, 4)))(keys))
    big = np.asarray(shuffle(jax.random.PRNGKey(1), 2048))
    assert big.dtype == np.int32 and (np.sort(big) == np.arange(2048)).all() and not (big == np.arange(2048)).all()


def test_shuffle_rounds_break_ties_at_random():
    """With one random bit per key, every round ties most pairs; ties keep the previous round's order, so
    12 rounds still give a uniform order of 4 items, while one round is far from it (a tied pair of the
    first round keeps index order: the identity comes out at least 1/16 of the time). Too many items for
    the index bits is an error."""
    keys = jax.random.split(jax.random.PRNGKey(2), 4800)
    assert orders_of_four_are_uniform(jax.vmap(lambda k: shuffle_by_sorts(k, 4, 1, 12))(keys))
    one_round = np.asarray(jax.vmap(lambda k: shuffle_by_sorts(k, 4, 1, 1))(keys))
    assert np.mean((one_round == np.arange(4)).all(axis=1)) > 1 / 16
    with pytest.raises(ValueError, match="index bits"):
        shuffle_by_sorts(jax.random.PRNGKey(0), 5, 30, 1)


def test_rollout_counts_episodes_and_resets_returns():
    """Constant actions 0.5 from x = 1: rewards -1.5, -2, -2.5 then a time-limit reset; episode returns,
    counts, discounted returns and 'term' (0 at a truncation) against a hand computation."""
    p = toy_parts()._replace(v_sample=lambda prm, obs, noise, sched: (jnp.full((obs.shape[0], 1), 0.5),
                                                                      jnp.zeros(obs.shape[0], jnp.int32),
                                                                      jnp.zeros(obs.shape[0])))
    p = p._replace(cfg=Config(num_envs=2, unroll_length=7, normalize_obs=False))
    env_state = jax.vmap(ToyEnv().reset)(jnp.zeros((2, 2), jnp.uint32))
    state = TrainState({"policy": None}, None, None, None, env_state, jnp.zeros(2), jnp.zeros(2), None, None, None)
    (s, ep_ret, disc, fin_sum, fin_cnt), traj = rollout(p, state, HP, schedule(HP, jnp.int32(0)), jax.random.PRNGKey(0))
    rewards = np.tile([-1.5, -2.0, -2.5], 3)[:7]
    np.testing.assert_allclose(np.asarray(traj["reward"][:, 0]), rewards)
    assert float(fin_cnt) == 2 * 2 and np.isclose(float(fin_sum), 2 * 2 * -6.0)
    np.testing.assert_allclose(np.asarray(ep_ret), [-1.5, -1.5])  # one step into the third episode
    np.testing.assert_allclose(np.asarray(traj["term"]), 0.0)  # time limits are not terminations
    np.testing.assert_allclose(np.asarray(traj["next_obs"][2, 0]), [2.5])  # the true last observation
    disc_ref = [-1.5, -1.5 * 0.9 - 2.0, (-1.5 * 0.9 - 2.0) * 0.9 - 2.5]
    np.testing.assert_allclose(np.asarray(traj["disc_return"][:3, 0]), disc_ref, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(disc), [-1.5, -1.5])


def test_rollout_draws_fresh_noise_for_every_step_and_env():
    """The policy gets its own standard normal draw at each of the T x N steps (none reused)."""
    p = toy_parts()._replace(v_sample=lambda prm, obs, noise, sched: (noise["z"], jnp.zeros(obs.shape[0], jnp.int32),
                                                                      noise["u"]))
    p = p._replace(cfg=Config(num_envs=32, unroll_length=64, normalize_obs=False))
    env_state = jax.vmap(ToyEnv().reset)(jnp.zeros((32, 2), jnp.uint32))
    state = TrainState({"policy": None}, None, None, None, env_state, jnp.zeros(32), jnp.zeros(32), None, None, None)
    _, traj = rollout(p, state, HP, schedule(HP, jnp.int32(0)), jax.random.PRNGKey(1))
    z, u = np.asarray(traj["action"][..., 0]).ravel(), np.asarray(traj["logp"]).ravel()
    # float32 draws repeat by chance only rarely; a draw shared between steps or envs would repeat 32 or 64 times
    assert z.shape == u.shape == (64 * 32,) and len(np.unique(z)) > 0.99 * len(z) and len(np.unique(u)) > 0.99 * len(u)
    assert abs(z.mean()) < 4 / np.sqrt(len(z)) and abs(z.std() - 1) < 0.06
    assert np.all((u >= 0) & (u < 1)) and abs(u.mean() - 0.5) < 4 * np.sqrt(1 / 12 / len(u))


def test_iteration_returns_exactly_the_listed_metrics():
    from gsa_jax.running.tasks import trainer_for

    tr = trainer_for(Config(num_envs=2, unroll_length=4, num_minibatches=2, num_epochs=1))
    hp = make_hparams(K=2)
    state = jax.eval_shape(tr.init, jax.random.PRNGKey(0), hp)
    _, metrics = jax.eval_shape(lambda s, h: tr.run_chunk(s, h, 1), state, hp)  # guarded: with failed_at
    assert set(metrics) == set(ITERATION_METRICS) | {"failed_at"}
