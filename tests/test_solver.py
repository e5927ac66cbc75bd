"""MJX's constraint solver as we run it: the line search as a while loop (envs/linesearch.py) gives the
same iterates as MJX's scan, bitwise; the solver-iterations option changes the MJX model only, says so,
and rejects bad values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import linesearch
from mujoco.mjx._src import solver


def test_while_loop_has_the_scan_contract_under_vmap():
    """Per batch element: body applied while cond holds, at most max_iter times -- envs that converge
    early keep their value while the others go on, as in MJX's scan of conds."""
    cond = lambda c: c["x"] < c["limit"]
    body = lambda c: {"x": c["x"] + 1.0, "limit": c["limit"]}
    init = {"x": jnp.zeros(5), "limit": jnp.array([0.0, 1.0, 3.0, 7.0, 50.0])}
    for impl in (linesearch.while_loop, linesearch._ORIGINAL):
        out = jax.jit(jax.vmap(lambda c: impl(cond, body, c, 6)))(init)
        np.testing.assert_array_equal(np.asarray(out["x"]), [0.0, 1.0, 3.0, 6.0, 6.0])


@pytest.fixture(scope="module")
def hopper():
    env = envs.make_base("hopper")  # installs the while-loop line search
    assert solver._while_loop_scan is linesearch.while_loop
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 4))
    acts = jax.random.uniform(jax.random.PRNGKey(1), (12, 4, env.action_size), minval=-1, maxval=1)
    return env, s0, acts


def roll(env, s0, acts):
    """A new function per call, so each trace sees the currently installed line search."""
    def body(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, (s.pipeline_state.qpos, s.pipeline_state.qvel, s.pipeline_state.qfrc_constraint)

    return jax.device_get(jax.jit(lambda s: jax.lax.scan(body, s, acts)[1])(s0))


def test_while_line_search_is_bitwise_mjx_scan(hopper):
    env, s0, acts = hopper
    ours = roll(env, s0, acts)
    assert np.abs(ours[2]).max() > 1.0  # the foot is on the floor: the constraint solver works
    solver._while_loop_scan = linesearch._ORIGINAL
    try:
        theirs = roll(env, s0, acts)
    finally:
        linesearch.install()
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)


def test_solver_option_changes_mjx_only(hopper):
    env, s0, acts = hopper
    fast = envs.make_base("hopper", solver_iterations=1, ls_iterations=4)
    assert envs.solver_settings(fast) == {"iterations": 1, "ls_iterations": 4, "task_iterations": 4, "task_ls_iterations": 50}
    assert envs.solver_settings(env)["iterations"] == 4 and envs.mj_model(fast).opt.ls_iterations == 50
    assert envs.make("hopper", solver_iterations=2).unwrapped.sys.opt.iterations == 2
    q_task, q_fast = roll(env, s0, acts[:3])[0], roll(fast, s0, acts[:3])[0]
    diff = np.abs(q_task - q_fast).max()
    assert 0.0 < diff < 0.05, diff  # a different, nearby simulator over 3 steps


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "4"])
def test_solver_option_rejects_bad_values(bad):
    with pytest.raises(ValueError, match="solver_iterations must be an integer >= 1"):
        envs.check_solver(solver_iterations=bad)
    with pytest.raises(ValueError, match="ls_iterations must be an integer >= 1"):
        envs.check_solver(ls_iterations=bad)
    from gsa_jax.ppo import Config

    with pytest.raises(ValueError, match="ls_iterations"):
        Config(env="hopper", ls_iterations=bad).validate()
