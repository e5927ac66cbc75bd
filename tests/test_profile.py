"""gsa profile (gsa_jax.commands.profile_parts): the parts of the update it times compute what the update computes (on the toy task of
test_ppo_parts), its split of an iteration adds up, and bad input is refused in one line."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.commands import profile_parts as profile
from gsa_jax.algorithm.config import Config
from gsa_jax.algorithm.optim import init_adam
from gsa_jax.algorithm.ppo import schedule
from gsa_jax.algorithm.ppo_update import apply_gradients, epoch_minibatches, minibatch_gradients
from gsa_jax.algorithm.run_parts import TrainState
from gsa_jax.benchmark import parts as parts_module
from gsa_jax.benchmark.parts import PARTS, PPO_PARTS, op_seconds, split_seconds, update_parts
from tests.test_ppo_parts import HP, minibatch, toy_params, toy_parts


def toy_state(params):
    return TrainState(params, init_adam(params), None, None, None, None, None, jax.random.PRNGKey(5), jnp.int32(0),
                      jnp.int32(-1))


def test_update_parts_compute_the_updates_steps(monkeypatch):
    """shuffle_gather gives every epoch's epoch_minibatches; the gradients part's first step is
    minibatch_gradients at the run's parameters and the next one at the parameters moved by NUDGE x those gradients
    (a nudge of 0.1 here, so a loop at fixed parameters would fail); the optimizer part's first step is
    apply_gradients, and its loop moves the parameters every step."""
    monkeypatch.setattr(parts_module, "NUDGE", 0.1)
    p = toy_parts(Config(num_envs=4, unroll_length=4, num_epochs=2, num_minibatches=2))
    params, batch = toy_params(), minibatch()
    s, sched = toy_state(params), schedule(HP, jnp.int32(0))
    parts = update_parts(p)
    mbs = jax.jit(parts["shuffle_gather"])(s, batch)
    for e, k in enumerate(jax.random.split(s.key, 2)):
        for a, b in zip(jax.tree.leaves(jax.tree.map(lambda x: x[e], mbs)), jax.tree.leaves(epoch_minibatches(p, batch, k))):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    _, aux = jax.jit(parts["gradients"])(s, HP, mbs)
    grad = jax.jit(lambda prm, mb: minibatch_gradients(p, prm, mb, HP, sched))
    grads, want = grad(params, jax.tree.map(lambda x: x[0, 0], mbs))
    moved = jax.tree.map(lambda x, g: x - 0.1 * g, params, grads)
    _, want2 = grad(moved, jax.tree.map(lambda x: x[0, 1], mbs))
    np.testing.assert_allclose(np.asarray(aux["policy_loss"][:2]), [want["policy_loss"], want2["policy_loss"]], rtol=1e-6)
    assert aux["policy_loss"].shape == (4,) and not np.isclose(aux["policy_loss"][1], grad(params, jax.tree.map(lambda x: x[0, 1], mbs))[1]["policy_loss"])
    one, _, _ = jax.jit(parts["opt_one"])(s, HP, grads)
    want_params, _, _ = apply_gradients(params, s.opt, grads, HP, jax.tree.map(lambda _: HP.lr, params))
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(want_params)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    final, opt = jax.jit(parts["optimizer"])(s, HP, grads)
    assert int(opt["count"]) == 4 and not np.allclose(np.asarray(final["policy"]["w"]), np.asarray(one["policy"]["w"]))


def test_the_split_adds_up_to_the_iteration():
    """Every part from the timed pieces (wall, host, MuJoCo C): MuJoCo C and the host calls are the iteration's
    own, the program's side of a piece is its wall less its host time, and all parts add up to the iteration."""
    t = {"iteration": (10.0, 4.5, 3.5), "rollout": (6.0, 4.5, 3.5), "physics": (5.0, 4.0, 3.0), "rollout_policy": (0.5, 0, 0),
         "targets": (0.25, 0, 0), "update": (3.0, 0, 0), "shuffle_gather": (0.5, 0, 0), "gradients": (1.5, 0, 0),
         "optimizer": (0.75, 0, 0)}
    s = split_seconds(t)
    assert set(s) == set(PARTS)
    assert s["mujoco_c"] == 3.5 and s["host_other"] == 1.0 and s["env_step_program"] == 1.0
    assert s["rollout_rest"] == 0.0 and s["update_loop"] == 0.25 and s["rest"] == 0.75
    assert sum(s.values()) == pytest.approx(10.0)
    assert sum(s[k] for k in PPO_PARTS) == pytest.approx(10.0 - 4.5 - 1.0)


@pytest.mark.parametrize("argv, words", [(["--runs", "0"], "--runs"), (["--cores", "-1"], "--cores"),
                                         (["--envs", "no-such-task"], "no-such-task"), (["--envs", ","], "--envs"),
                                         (["--cores", str(len(os.sched_getaffinity(0)) + 1)], "only")])
def test_bad_input_is_refused_in_one_line_and_changes_nothing(argv, words, capsys, tmp_path):
    affinity, flags = os.sched_getaffinity(0), os.environ.get("XLA_FLAGS")
    assert profile.main(argv + ["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err
    assert os.sched_getaffinity(0) == affinity and os.environ.get("XLA_FLAGS") == flags
    assert not (tmp_path / "out").exists()


def test_op_seconds_splits_matrix_products_from_other_ops():
    """A matmul followed by a tanh shows time in both kinds of op; a tanh alone has no matrix products."""
    both = op_seconds(jax.jit(lambda a: jnp.tanh(a @ a)), (jnp.ones((64, 64)),))
    alone = op_seconds(jax.jit(lambda a: jnp.tanh(a) * 2.0), (jnp.ones((64, 64)),))
    assert both["matrix_products"] > 0 and both["other_ops"] > 0
    assert alone["matrix_products"] == 0 and alone["other_ops"] > 0
