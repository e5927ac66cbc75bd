"""Whole PPO runs on inverted_double_pendulum: learning, determinism, masked-K equivalence.

Programs are compiled once per module (chunks of CHUNK iterations) and reused across tests.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.running.tasks import trainer_for

CHUNK = 10
LEARN_ITERS = 30  # 30 x 2048 = 61,440 env steps
EVAL_HORIZON = 40  # steps of an evaluation compared across compilations (2 s of the double pendulum)
ALIVE_REWARD = 9.0  # at least this per step while both poles are up (at most ~9.36)


def compiled(cfg):
    tr = trainer_for(cfg)
    return tr, jax.jit(tr.init), jax.jit(tr.run_chunk, static_argnums=2)


def train_iters(tr, init, run, hp, seed, iters):
    state = init(jax.random.PRNGKey(seed), hp)
    chunks = []
    for _ in range(iters // CHUNK):
        state, m = run(state, hp, CHUNK)
        chunks.append(jax.device_get(m))
    return state, {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}


@pytest.fixture(scope="module")
def mixture4():
    return compiled(Config(policy="mixture", k_max=4))


@pytest.fixture(scope="module")
def mixture_runs(mixture4):
    tr, init, run = mixture4
    hp = make_hparams(K=4, total_iterations=LEARN_ITERS)
    return hp, train_iters(tr, init, run, hp, 0, LEARN_ITERS)


def improved(returns):
    """Learning criterion. A random policy keeps the double pendulum up for ~12 steps (return ~110-130);
    the task's maximum is ~9,350 per 1000 steps. We ask, within 61k steps, for the last 3 iterations'
    mean training return to be >= 3x the first iteration's and >= 350 (i.e. the poles stay up ~4x longer)."""
    first, last = returns[0], np.nanmean(returns[-3:])
    return last >= 3 * first and last >= 350, f"first {first:.1f} -> last {last:.1f}"


def test_mixture_learns_inverted_double_pendulum(mixture_runs):
    _, (_, m) = mixture_runs
    ok, msg = improved(m["episode_return"])
    assert ok, msg
    assert m["env_steps"][-1] == LEARN_ITERS * 2048
    # schedules: epsilon and sigma_min decay by their factor every iteration
    np.testing.assert_allclose(m["epsilon"], 0.2 * 0.995 ** np.arange(LEARN_ITERS), rtol=1e-5)
    np.testing.assert_allclose(m["sigma_min"], 0.1 * 0.995 ** np.arange(LEARN_ITERS), rtol=1e-5)
    assert np.all(np.isfinite(m["policy_loss"])) and np.all(m["clusters_used"] >= 1)


def test_mlp_learns_inverted_double_pendulum():
    tr, init, run = compiled(Config(policy="mlp"))
    hp = make_hparams(K=1, total_iterations=LEARN_ITERS)
    _, m = train_iters(tr, init, run, hp, 0, LEARN_ITERS)
    ok, msg = improved(m["episode_return"])
    assert ok, msg


def test_same_seed_same_metrics(mixture4, mixture_runs):
    tr, init, run = mixture4
    hp, (_, m_first) = mixture_runs
    _, m_again = train_iters(tr, init, run, hp, 0, CHUNK)
    for k in m_again:
        np.testing.assert_array_equal(m_again[k], m_first[k][:CHUNK], err_msg=k)
    _, m_other = train_iters(tr, init, run, hp, 1, CHUNK)
    assert not np.array_equal(m_other["episode_return"], m_again["episode_return"])


def test_masked_k_run_equals_unpadded(mixture4, mixture_runs):
    """K=4 inside K_max=16 trains like K=4 with K_max=4 (same seed): first iterations equal to float tolerance."""
    hp, (_, m4) = mixture_runs
    tr, init, run = compiled(Config(policy="mixture", k_max=16))
    _, m16 = train_iters(tr, init, run, hp, 0, CHUNK)
    for k in ("episode_return", "episodes", "policy_loss", "value_loss", "approx_kl", "partition_entropy", "clusters_used"):
        np.testing.assert_allclose(m16[k][:3], m4[k][:3], rtol=2e-3, atol=1e-5, err_msg=k)


def test_evaluate_deterministic_controller(mixture4, mixture_runs):
    tr, _, _ = mixture4
    hp, (state, _) = mixture_runs
    ev = jax.jit(tr.evaluate)
    r1, f1 = ev(state.params, state.obs_stats, hp, jax.random.PRNGKey(3))
    r2, f2 = ev(state.params, state.obs_stats, hp, jax.random.PRNGKey(3))
    assert float(r1) == float(r2) and float(r1) > 0 and int(f1) == int(f2) == 0


def test_run_once_options_hold_level_1_at_least_and_only_on_the_cpu(monkeypatch):
    """XLA:CPU's older fusion code generation for programs run once (xla_cache.once_options), at XLA_FLAGS' level
    where it is 1 or more and at level 1 where it is 0 (where that code generation computes NaN weights)."""
    from gsa_jax.running import xla_cache

    older = {"xla_cpu_use_fusion_emitters": False}
    for flags, want in (("", older), ("--xla_backend_optimization_level=2", older),
                        ("--xla_backend_optimization_level=0", {**older, "xla_backend_optimization_level": 1})):
        monkeypatch.setenv("XLA_FLAGS", flags)
        assert xla_cache.once_options("cpu") == want, flags
    assert xla_cache.once_options("gpu") is None


def test_init_and_evaluation_compiled_as_run_once_programs_compute_what_the_default_does(mixture4, mixture_runs):
    """init and the evaluation compile with XLA:CPU's older fusion code generation (xla_cache.once_options, at level
    1 where the suite compiles the rest at 0): the same initial state and, from a trained controller's 61k steps,
    the same deterministic evaluation as XLA's default code generation at that level, to float rounding. The two
    code generations round differently, and the double pendulum amplifies a rounding difference until an episode
    ends a step or more apart (on an AVX2 CPU 1,496 against 1,571 over whole episodes): the evaluation is compared
    over EVAL_HORIZON steps, within which every episode is still up (no end to move) and rounding stays at float
    precision (measured: equal bits here, 3e-7 apart at 100 steps with XLA_FLAGS=--xla_cpu_max_isa=AVX2)."""
    import dataclasses

    from gsa_jax.running import xla_cache

    tr, _, _ = mixture4
    hp, (state, _) = mixture_runs
    once = xla_cache.once_options("cpu")
    assert once["xla_cpu_use_fusion_emitters"] is False
    default = {"xla_backend_optimization_level": once.get("xla_backend_optimization_level", 3)}
    key = jax.random.PRNGKey(7)
    by_default, by_once = (jax.jit(tr.init, compiler_options=o)(key, hp) for o in (default, once))
    for a, b in zip(jax.tree.leaves(by_default), jax.tree.leaves(by_once)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=1e-6)
    args = (state.params, state.obs_stats, hp, jax.random.PRNGKey(3))
    short = trainer_for(dataclasses.replace(tr.cfg, episode_length=EVAL_HORIZON))
    by_default, by_once = (jax.jit(short.evaluate, compiler_options=o)(*args) for o in (default, once))
    assert float(by_default[0]) > 0.9 * ALIVE_REWARD * EVAL_HORIZON  # every episode up through the horizon
    np.testing.assert_allclose(float(by_once[0]), float(by_default[0]), rtol=1e-5)
    assert int(by_once[1]) == int(by_default[1]) == 0


def test_evaluation_in_a_vmapped_group_equals_alone(mixture4):
    """Two runs' deterministic evaluations from the same starts, vmapped as a sweep group evaluates them,
    equal each run evaluated alone."""
    import jax.numpy as jnp

    from gsa_jax.running.programs import make_group_evaluate

    tr, init, _ = mixture4
    hps = [make_hparams(K=k) for k in (2, 4)]
    states = [init(jax.random.PRNGKey(s), h) for s, h in zip((0, 1), hps)]
    params = dict(states[1].params, policy=dict(states[1].params["policy"], b=states[1].params["policy"]["b"] + 0.3))
    states[1] = states[1]._replace(params=params)  # another controller (at init every seed has the same one)
    key = jax.random.fold_in(jax.random.PRNGKey(0), 5)
    alone = [float(jax.jit(tr.evaluate)(s.params, s.obs_stats, h, key)[0]) for s, h in zip(states, hps)]
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    group = make_group_evaluate(tr.cfg, run_batch=0)(
        jax.tree.map(stack, *[s.params for s in states]), jax.tree.map(stack, *[s.obs_stats for s in states]),
        jax.tree.map(stack, *hps), jnp.stack([key, key]))
    np.testing.assert_allclose(np.asarray(group[0]), alone, rtol=1e-5)
    assert np.asarray(group[1]).tolist() == [0, 0]
    assert alone[0] != alone[1]


def test_a_sweep_groups_init_and_evaluation_compile_as_programs_run_once(mixture4):
    """A sweep group's init and evaluation carry xla_cache.once_options (its training program does not), and a
    group of one run's init so compiled is finite (at level 0 that code generation gave NaN weights there)."""
    from gsa_jax.running import xla_cache
    from gsa_jax.running.programs import make_group_evaluate, make_group_program

    tr, _, _ = mixture4
    _, init, run, _ = make_group_program(tr.cfg, 2, jax.devices()[:1])
    keys, hps = jnp.stack([jax.random.PRNGKey(0)]), jax.tree.map(lambda x: x[None], make_hparams(K=4))
    states = init(keys, hps)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(states) if jnp.issubdtype(x.dtype, jnp.floating))
    evaluate = make_group_evaluate(tr.cfg, platform=jax.devices()[0].platform)
    options = {name: dict(program.lower(*args)._lowering._compiler_options_kvs)  # jax 0.10.1's
               for name, program, args in (("init", init, (keys, hps)), ("run", run, (states, hps)),
                                           ("evaluate", evaluate, (states.params, states.obs_stats, hps, keys)))}
    assert options["init"] == options["evaluate"] == xla_cache.once_options("cpu") and options["run"] == {}


def test_a_single_runs_one_reset_program_gives_init_and_evaluation_what_each_computes_alone(mixture4, mixture_runs):
    """A single run resets its training envs (32) and its evaluation's (16) with one compiled program over 32 keys
    (programs.single_run_parts): the same initial state and the same evaluation of a trained controller, bit for
    bit, as init and evaluate each resetting its own envs, compiled with the same options."""
    from gsa_jax.algorithm.ppo import shares_starts
    from gsa_jax.running import xla_cache
    from gsa_jax.running.programs import single_run_parts

    tr, _, _ = mixture4
    hp, (state, _) = mixture_runs
    p = tr.parts
    assert shares_starts(tr.cfg) and p.eval_env is p.env.env and p.cfg.eval_envs < p.cfg.num_envs
    once = xla_cache.once_options("cpu")
    init, evaluation, ahead = single_run_parts(p, once)
    key = jax.random.PRNGKey(7)
    alone = jax.jit(tr.init, compiler_options=once)(key, hp)
    shared = init(key, hp)
    assert jax.tree.structure(shared) == jax.tree.structure(alone)
    for a, b in zip(jax.tree.leaves(alone), jax.tree.leaves(shared)):
        np.testing.assert_array_equal(np.asarray(b), np.asarray(a))
    args = (state.params, state.obs_stats, hp, jax.random.PRNGKey(3))
    alone = jax.jit(tr.evaluate, compiler_options=once)(*args)
    assert float(alone[0]) > 350  # long episodes: a different start or step would show
    compiled = ahead(state.params, state.obs_stats, hp)
    for shared in (evaluation(*args), compiled(*args)):
        assert (float(shared[0]), int(shared[1])) == (float(alone[0]), int(alone[1]))


def test_a_run_shares_its_reset_only_where_its_evaluation_env_is_its_training_env_without_auto_reset():
    """ppo.shares_starts: not under a training randomization, nor with reset mode 'fresh' (each episode a new draw),
    nor where an evaluation would reset more than twice its envs; start_keys pads split(key, n) with its last key to
    max(num_envs, eval_envs)."""
    from gsa_jax.algorithm.ppo import Parts, shares_starts, start_keys

    assert shares_starts(Config())
    assert not shares_starts(Config(reset_mode="fresh"))
    assert not shares_starts(Config(randomize="mass=0.9:1.1"))
    assert shares_starts(Config(num_envs=32, eval_envs=16)) and not shares_starts(Config(num_envs=33, eval_envs=16))
    for num_envs, eval_envs in ((4, 2), (2, 4), (3, 3)):
        p = Parts(Config(num_envs=num_envs, eval_envs=eval_envs), *[None] * 8)
        for n in (num_envs, eval_envs):
            keys = np.asarray(start_keys(p, jax.random.PRNGKey(5), n))
            split = np.asarray(jax.random.split(jax.random.PRNGKey(5), n))
            assert keys.shape == (max(num_envs, eval_envs), 2)
            np.testing.assert_array_equal(keys[:n], split)
            np.testing.assert_array_equal(keys[n:], np.repeat(split[-1:], len(keys) - n, axis=0))


class NaNRewardAtStep5:
    """The evaluation task with the reward of step 5 made NaN in episodes that start with the cart right
    of centre (obs[0] > 0): a physics failure forced on chosen, still-alive episodes."""

    def __init__(self, env):
        self.env = env

    def reset(self, rng):
        state = self.env.reset(rng)
        state.info["right"] = state.obs[0] > 0
        return state

    def step(self, state, action):
        nxt = self.env.step(state, action)
        bad = state.info["right"] & (nxt.info["steps"] == 5)
        return nxt.replace(reward=jnp.where(bad, jnp.nan, nxt.reward))


def test_evaluation_with_a_forced_non_finite_episode_counts_it_and_scores_it_to_its_last_finite_step(mixture4, mixture_runs):
    """Against a NumPy reference from the unmodified task's per-step rewards: the failed episodes count
    their first 4 rewards, the others their whole episode; the failures are counted."""
    from gsa_jax.algorithm.ppo import evaluate, make_env, make_parts, norm_obs, schedule

    tr, _, _ = mixture4
    hp, (state, _) = mixture_runs
    task = envs.resolve(tr.cfg.env)
    eval_env = make_env(tr.cfg, task, auto_reset=False)
    parts = make_parts(tr.cfg, make_env(tr.cfg, task), NaNRewardAtStep5(eval_env))
    key = jax.random.PRNGKey(11)
    mean, failures = jax.jit(lambda p, o, h, k: evaluate(parts, p, o, h, k))(state.params, state.obs_stats, hp, key)

    def roll(params, obs_stats, h, k):  # the reference's raw per-step rewards and dones [T, E]
        sched = schedule(h, jnp.zeros((), jnp.int32))
        s0 = jax.vmap(eval_env.reset)(jax.random.split(k, tr.cfg.eval_envs))

        def step(s, _):
            a, _ = parts.v_mode(params["policy"], norm_obs(tr.cfg, obs_stats, s.obs), sched)
            s = jax.vmap(eval_env.step)(s, jnp.clip(a, -1.0, 1.0))
            return s, (s.reward, s.done)

        return s0.obs, jax.lax.scan(step, s0, None, length=tr.cfg.episode_length)[1]

    obs0, (r, d) = jax.device_get(jax.jit(roll)(state.params, state.obs_stats, hp, key))
    end = np.argmax(d > 0, axis=0) + 1  # steps in each episode
    right = obs0[:, 0] > 0
    fails = right & (end >= 5)
    expect = [r[: (4 if f else e), i].astype(np.float64).sum() for i, (e, f) in enumerate(zip(end, fails))]
    assert 0 < fails.sum() < tr.cfg.eval_envs, fails  # some episodes fail, some do not
    assert int(failures) == int(fails.sum())
    np.testing.assert_allclose(float(mean), np.mean(expect), rtol=1e-5)
