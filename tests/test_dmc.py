"""The DeepMind Control Suite's tasks (envs/dmc/) against dm_control itself, from fixtures recorded in dm_control's
own environment (experiments/dmc_reference/record.py: mujoco 3.17 + dm_control 1.0.50, since `suite.load` fails
under mujoco 4.0): dm_control's reset states, random actions (out-of-range ones included), flattened observations
and rewards of whole episodes, and the state before every step of one episode.

Measured (tests below assert it): on cartpole, pendulum, acrobot and point_mass our MuJoCo C task gives dm_control's
observations and rewards over whole episodes to float64 rounding (largest difference 0.0 for observations, 6e-28
for rewards); on walker and hopper, whose contacts amplify the last-bit differences between mujoco 3.17 and 4.0
(~1e-16 at the first steps, 1e-10 by step 50, then apart), every single step from dm_control's recorded state gives
its next observation and reward to 1e-9, and whole episodes agree to 1e-8 over their first 50 steps.
"""

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy import stats as sps

import envs
from envs.c_hosts import STATE_SPEC, float64_rows
from envs.physics import Physics
from mjx_vs_c import assert_mjx_follows_mujoco_c

pytest.importorskip("dm_control")  # the MJCFs' source (the extra make test installs)
GOLDEN = os.path.join(os.path.dirname(__file__), "golden", "dmc")
CONTACT_FREE = ("cartpole-balance", "cartpole-swingup", "pendulum-swingup", "acrobot-swingup", "point_mass-easy")
CONTACT_HORIZON, CONTACT_TOL, STEP_TOL = 50, 1e-8, 1e-9


def fixture(name):
    return np.load(os.path.join(GOLDEN, f"{name}.npz"))


def episodes(f):
    """How many whole episodes a fixture holds (3, quadruped-walk's 2: record.py)."""
    return int(f["episodes"]) if "episodes" in f.files else 3


def goal(c, f, i):
    """The goal of episode i (the target dm_control wrote into the model), or None for a task without one."""
    return f[f"ep{i}_target"][: c.task.goal_size] if c.task.goal_size else None


def replay(c, f, i):
    """Episode i of a fixture replayed by TaskC c from dm_control's reset state: (obs [T+1, d], rewards [T])."""
    obs, rewards = [c.set_start(f[f"ep{i}_qpos0"], f[f"ep{i}_qvel0"], goal(c, f, i))], []
    for a in f[f"ep{i}_actions"]:
        o, r, terminated = c.step_controls(a.astype(np.float64))  # dm_control's actions are the controls
        assert not terminated
        obs.append(o)
        rewards.append(r)
    return np.array(obs), np.array(rewards)


@pytest.mark.parametrize("name", list(envs.dmc.TASKS))
def test_whole_episodes_equal_dm_controls(name):
    """Every step of whole episodes (dm_control's 1000, no termination: every discount 1): observations in
    dm_control's key order and sizes, and rewards, to float64 rounding (contact tasks: over CONTACT_HORIZON steps)."""
    f, c = fixture(name), envs.resolve(f"dmc:{name}").make_c()
    layout = c.task.observation_layout()
    assert [(k, int(s)) for k, s in zip(f["obs_keys"], f["obs_sizes"])] == list(c.task.observation_keys)
    assert len(layout) == int(f["obs_sizes"].sum()) and c.task.frame_skip == int(f["n_sub_steps"])
    for i in range(episodes(f)):
        assert len(f[f"ep{i}_actions"]) == c.task.episode_length == 1000 and np.all(f[f"ep{i}_discounts"] == 1.0)
        obs, rewards = replay(c, f, i)
        horizon = None if name in CONTACT_FREE else CONTACT_HORIZON
        tol = 1e-12 if horizon is None else CONTACT_TOL
        np.testing.assert_allclose(obs[:horizon], f[f"ep{i}_obs"][:horizon], rtol=0, atol=tol, err_msg=f"{name} ep{i}")
        np.testing.assert_allclose(rewards[:horizon], f[f"ep{i}_rewards"][:horizon], rtol=0, atol=tol)


@pytest.mark.parametrize("name", list(envs.dmc.TASKS))
def test_every_single_step_from_dm_controls_state(name):
    """From dm_control's state before each step of an episode (qpos, qvel, qacc_warmstart): one step with its action
    gives its next observation and reward to STEP_TOL (mujoco 4.0 stepping what mujoco 3.17 recorded)."""
    f, c = fixture(name), envs.resolve(f"dmc:{name}").make_c()
    m = c.model
    worst = 0.0
    for t, (state, a) in enumerate(zip(f["ep0_states"], f["ep0_actions"])):
        c.set_start(state[: m.nq], state[m.nq: m.nq + m.nv], goal(c, f, 0))
        c.data.act[:] = state[m.nq + m.nv: m.nq + m.nv + m.na]
        c.data.qacc_warmstart[:] = state[m.nq + m.nv + m.na:]
        o, r, _ = c.step_controls(a.astype(np.float64))
        worst = max(worst, np.abs(o - f["ep0_obs"][t + 1]).max(), abs(r - f["ep0_rewards"][t]))
    assert worst <= STEP_TOL, (name, worst)


@pytest.mark.parametrize("name", ["cartpole-balance", "cartpole-swingup", "walker-walk", "hopper-hop", "cheetah-run",
                                  "reacher-hard", "finger-spin", "ball_in_cup-catch", "fish-swim", "quadruped-walk"])
def test_resets_draw_from_dm_controls_law(name):
    """The trainer's resets (backend 'c': JAX draws, or the task's initialize() on the host) against dm_control's 300
    recorded ones (qpos, qvel and a target drawn at reset): the same law per coordinate (two-sample
    Kolmogorov-Smirnov), and the same constants where dm_control does not randomize."""
    env = envs.make(f"dmc:{name}", physics=Physics(backend="c"))
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 1000))
    host = env.env.env.host
    rows = float64_rows(s.pipeline_state.rows)
    goals = rows[:, host.n_mj + host.n_before:] if host.task.goal_size else np.zeros((len(rows), 0))
    ours = np.concatenate([np.asarray(s.pipeline_state.qpos, np.float64), np.asarray(s.pipeline_state.qvel), goals], 1)
    theirs = fixture(name)["resets"]
    theirs = theirs[:, : ours.shape[1]]  # a target's x, y of the three coordinates dm_control writes
    for j in range(ours.shape[1]):
        if np.ptp(theirs[:, j]) == 0:
            np.testing.assert_allclose(ours[:, j], theirs[0, j], atol=1e-6, err_msg=f"{name} coordinate {j}")
        else:
            assert sps.ks_2samp(ours[:, j], theirs[:, j]).pvalue > 1e-3, (name, j)


def test_backend_c_steps_as_mujoco_c_rounded_to_float32():
    """The trainer's backend 'c' (mujoco.batch, mj_step1's stage after each step) from dm_control's reset states:
    every observation and reward is TaskC's float64 value rounded to float32, over whole episodes of hopper-hop
    (touch sensors from the last substep, positions from the new state) and cartpole-swingup."""
    for name in ("hopper-hop", "cartpole-swingup"):
        f = fixture(name)
        env = envs.make(f"dmc:{name}", auto_reset=False, physics=Physics(backend="c"))
        from test_gym_v5 import start_state

        sims, ref_obs, ref_rew = [], [], []
        for i in range(3):
            sim, _ = start_state(env.env, f[f"ep{i}_qpos0"], f[f"ep{i}_qvel0"])
            sims.append(sim)
            obs, rew = replay(envs.resolve(f"dmc:{name}").make_c(), f, i)
            ref_obs.append(obs[1:])
            ref_rew.append(rew)
        s0 = jax.tree.map(lambda x: jnp.stack([x] * 3), env.reset(jax.random.PRNGKey(0)))
        sims = jax.tree.map(lambda *xs: jnp.stack(xs), *sims)
        s0 = s0.replace(pipeline_state=sims)
        actions = jnp.asarray(np.stack([f[f"ep{i}_actions"] for i in range(3)], 1))

        def step(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, (s.obs, s.reward)

        _, (obs, rew) = jax.device_get(jax.jit(lambda s, a: jax.lax.scan(step, s, a))(s0, actions))
        for i in range(3):
            np.testing.assert_array_equal(obs[:, i], ref_obs[i].astype(np.float32), err_msg=f"{name} ep{i}")
            np.testing.assert_array_equal(rew[:, i], ref_rew[i].astype(np.float32), err_msg=f"{name} ep{i}")


def test_actions_map_onto_a_models_ctrlrange_alike_on_backend_c_and_in_mujoco_c():
    """quadruped-walk (ctrl_range 'model': actions in [-1, 1] onto ctrlranges [-1, 1.1] and [-0.8, 0.8]): backend 'c'
    from a reset of its own gives TaskC's observations and rewards rounded to float32 for 30 steps of random actions,
    and the extreme actions reach the ends of every ctrlrange."""
    name = "dmc:quadruped-walk"
    env, c = envs.make(name, auto_reset=False, physics=Physics(backend="c")), envs.resolve(name).make_c()
    s = jax.jit(env.reset)(jax.random.PRNGKey(4))
    host = env.env.host
    mujoco.mj_setState(c.model, c.data, float64_rows(s.pipeline_state.rows)[: host.n_mj], STATE_SPEC)
    mujoco.mj_forward(c.model, c.data)
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    for t in range(30):
        a = rng.uniform(-1, 1, c.model.nu).astype(np.float32)
        s = step(s, jnp.asarray(a))
        obs, reward, _ = c.step(a.astype(np.float64))
        np.testing.assert_array_equal(np.asarray(s.obs), obs.astype(np.float32), err_msg=f"step {t}")
        assert float(s.reward) == np.float32(reward), t
    ends = c.task.controls(np.array([[-1.0] * c.model.nu, [1.0] * c.model.nu]))
    np.testing.assert_allclose(ends, c.model.actuator_ctrlrange.T, rtol=0, atol=1e-15)


MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL = 50, 1e-3, 1e-3


@pytest.mark.parametrize("name", ["cartpole-swingup", "pendulum-swingup", "reacher-easy"])
def test_mjx_agrees_with_mujoco_c(name):
    """The MJX version (float32) from the same start (and goal) under the same actions: observations within MJX_OBS_TOL
    and rewards within MJX_REWARD_TOL over MJX_HORIZON env steps (measured: 1e-6 on reacher-easy over 50 steps)."""
    assert_mjx_follows_mujoco_c(f"dmc:{name}", MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL)


def test_an_unknown_dmc_task_lists_the_available_ones_in_one_line():
    with pytest.raises(ValueError, match=r"unknown DeepMind Control Suite task 'dmc:cartpole-upside'; choose one of "
                                         r"dmc:cartpole-balance, dmc:cartpole-swingup, ") as e:
        envs.check_name("dmc:cartpole-upside")
    assert "\n" not in str(e.value) and all(name in str(e.value) for name in envs.DMC_TASKS)


@pytest.mark.parametrize("backend", ["c", "mjx"])
def test_a_goal_drawn_at_reset_is_carried_and_redrawn_only_when_an_episode_restarts(backend):
    """reacher-easy's target (initialize() on the host, the goal in the state): with reset mode 'fresh' each env keeps
    its goal through an episode and gets a new one exactly when its episode restarts (5-step episodes here); the
    observation's to_target is goal - finger xy throughout."""
    env = envs.make("dmc:reacher-easy", physics=Physics(backend=backend), reset_mode="fresh", episode_length=5)
    c = envs.resolve("dmc:reacher-easy").make_c()
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(2), 3))
    step = jax.jit(jax.vmap(env.step))

    def goals(s):
        ps = s.pipeline_state
        if backend == "mjx":
            return np.asarray(ps.goal)
        host = env.env.env.host
        return float64_rows(ps.rows)[:, host.n_mj + host.n_before:]

    g, seen = goals(s), []
    for t in range(12):
        s = step(s, jnp.zeros((3, 2)))
        new = goals(s)
        restarted = (t + 1) % 5 == 0
        assert np.all(np.any(new != g, axis=1) == restarted), (backend, t)
        seen.append(new)
        g = new
        assert np.all(np.linalg.norm(new, axis=1) <= 0.2 + 1e-6)
        for i in range(3):  # the observation is MuJoCo C's at the same state and goal (to_target = goal - finger xy)
            ref = c.set_start(np.asarray(s.pipeline_state.qpos[i], np.float64),
                              np.asarray(s.pipeline_state.qvel[i], np.float64), new[i])
            np.testing.assert_allclose(np.asarray(s.obs[i]), ref, atol=1e-5, err_msg=f"{backend} step {t} env {i}")
    assert len({tuple(np.round(x, 6)) for x in np.concatenate(seen)}) == 9  # 3 envs x 3 episodes, all different


def test_exported_controllers_carry_the_map_onto_a_models_ctrlrange():
    """An exported controller of a ctrl_range 'model' task stores its ctrlrange (ctrl_low, ctrl_high) and
    Controller.controls maps act()'s actions as the task does; a task whose actions are its controls stores none."""
    from gsa_jax.deployment.exporting import control_range_arrays
    from gsa_jax.deployment.numpy_policy import Controller

    assert control_range_arrays(envs.resolve("dmc:walker-walk")) == {} and control_range_arrays(None) == {}
    stored = control_range_arrays(envs.resolve("dmc:quadruped-walk"))
    task = envs.resolve_task("dmc:quadruped-walk")
    np.testing.assert_array_equal(np.stack([stored["ctrl_low"], stored["ctrl_high"]], 1), task.model.actuator_ctrlrange)
    nu = task.model.nu
    arrays = {"kind": np.array("mlp"), "obs_mean": np.zeros(3, np.float32), "obs_var": np.ones(3, np.float32),
              "obs_clip": np.array(10.0), "n_layers": np.array(1), "w0": np.zeros((3, nu), np.float32),
              "b0": np.zeros(nu, np.float32), "action_low": -np.ones(nu, np.float32), "action_high": np.ones(nu, np.float32),
              **stored}
    a = np.random.default_rng(0).uniform(-1, 1, nu)
    np.testing.assert_array_equal(Controller(arrays).controls(a), task.controls(a[None])[0])


def test_a_task_mjx_cannot_step_says_so_in_one_line():
    with pytest.raises(ValueError, match=r"MJX cannot step task 'dmc:fish-swim' \(.*collisions not implemented.*\); "
                                         r"train it with backend 'c'"):
        envs.make_base("dmc:fish-swim")
