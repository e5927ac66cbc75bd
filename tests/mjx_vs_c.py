"""One check shared by the task tests: a task's MJX version follows MuJoCo C (TaskC) from a shared start."""

import jax
import jax.numpy as jnp
import numpy as np

import envs


def assert_mjx_follows_mujoco_c(name, horizon, obs_tol, reward_tol, key=0, terminations=False):
    """MJX's task `name` from its reset (PRNGKey(key)) and MuJoCo C from the same state (and goal) under the same
    U(-1, 1) actions: the first observation within 1e-5, then observations within obs_tol and rewards within reward_tol
    for `horizon` env steps (and the same terminations if `terminations`)."""
    env, c = envs.make_base(name), envs.resolve(name).make_c()
    s = jax.jit(env.reset)(jax.random.PRNGKey(key))
    step = jax.jit(env.step)
    ps = s.pipeline_state
    goal = np.asarray(ps.goal, np.float64) if hasattr(ps, "goal") else None
    obs = c.set_start(np.asarray(ps.qpos, np.float64), np.asarray(ps.qvel, np.float64), goal)
    np.testing.assert_allclose(obs, np.asarray(s.obs), atol=1e-5)
    rng = np.random.default_rng(0)
    for t in range(horizon):
        a = rng.uniform(-1, 1, env.action_size).astype(np.float32)
        s = step(s, jnp.asarray(a))
        obs, reward, terminated = c.step(a)
        np.testing.assert_allclose(np.asarray(s.obs), obs, atol=obs_tol, err_msg=f"{name} step {t}")
        assert abs(float(s.reward) - reward) <= reward_tol, (name, t, float(s.reward), reward)
        assert not terminations or bool(s.done) == terminated, (name, t)
