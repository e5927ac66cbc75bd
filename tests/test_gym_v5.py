"""gymnasium's v5 tasks (envs/v5_tasks.py): MuJoCo C and the trainer's backend 'c' against gymnasium.make(id),
step for step over whole episodes from gymnasium's reset states with the same random actions (out-of-range
ones included); the reset noise law; MJX (envs/task_mjx.py) against MuJoCo C within a tolerance.

Whole episodes: until gymnasium's episode terminates or its 1000-step time limit truncates it.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy import stats as sps

import envs
from envs.c_backend import SimState
from envs.c_hosts import STATE_SPEC
from envs.v5_tasks import V5_TASKS
from envs.physics import Physics
from mjx_vs_c import assert_mjx_follows_mujoco_c

gym = pytest.importorskip("gymnasium")
SEEDS = 6


def gym_episode(env_id, seed, ours=None):
    """gymnasium's episode from reset(seed) under U(-1.5, 1.5) actions (float32 values): (qpos0, qvel0,
    obs0, actions [T, nu], obs [T, d], rewards [T], terminated [T], truncated [T]); with `ours` (TaskC) also
    its largest |difference| from gymnasium over the episode."""
    g = gym.make(env_id)
    obs0, _ = g.reset(seed=seed)
    u = g.unwrapped
    qpos0, qvel0 = u.data.qpos.copy(), u.data.qvel.copy()
    worst = np.abs(ours.set_start(qpos0, qvel0) - obs0).max() if ours else None
    rng = np.random.default_rng(100 + seed)
    rows = []
    while True:
        a = rng.uniform(-1.5, 1.5, g.action_space.shape).astype(np.float32).astype(np.float64)
        obs, reward, terminated, truncated, _ = g.step(a)
        rows.append((a, obs, reward, terminated, truncated))
        if ours:
            o, r, t = ours.step(a)
            worst = max(worst, np.abs(o - obs).max(), abs(r - reward))
            assert t == terminated
        if terminated or truncated:
            break
    a, o, r, te, tr = map(np.array, zip(*rows))
    return (qpos0, qvel0, obs0, a, o, r, te, tr), worst


@pytest.mark.parametrize("env_id", list(V5_TASKS))
def test_mujoco_c_task_equals_gymnasium_exactly(env_id):
    """TaskC, stepping one MjData with the task's own observation, reward and termination functions, gives
    gymnasium's values bit for bit (largest difference 0.0)."""
    for seed in range(SEEDS):
        _, worst = gym_episode(env_id, seed, envs.resolve(env_id).make_c())
        assert worst == 0.0, (env_id, seed, worst)


def start_state(task, qpos, qvel):
    """The in-program SimState of gymnasium's reset state (its float64 row, bit for bit) and its obs."""
    m = task.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)
    row = np.zeros(mujoco.mj_stateSize(m, STATE_SPEC))
    mujoco.mj_getState(m, d, row, STATE_SPEC)
    derived = {f: getattr(d, f)[None] for f in task.port.derived}
    if task.host.n_carry:  # a row carries what the next step starts from (the task's `before` values)
        row = np.concatenate([row, task.port.before(d.qpos[None], derived)[0]])
    obs = task.port.observe(d.qpos[None], d.qvel[None], derived)[0]
    extra = np.concatenate([obs, [0.0, 0.0]]).astype(np.float32)
    return SimState(row.view(np.uint32), qpos.astype(np.float32), qvel.astype(np.float32), extra), obs


@pytest.mark.parametrize("env_id", list(V5_TASKS))
def test_backend_c_task_gives_gymnasium_steps_rounded_to_float32(env_id):
    """The trainer's task (backend 'c', time limit, no auto-reset), from gymnasium's reset states: every
    observation and reward is gymnasium's float64 value rounded to float32 (exactly), terminations
    equal, and a 1000-step episode is cut as a truncation, not a termination."""
    env = envs.make(env_id, auto_reset=False, physics=Physics(backend="c"))
    task = env.env
    episodes = [gym_episode(env_id, seed)[0] for seed in range(SEEDS)]
    T = max(len(e[3]) for e in episodes)
    actions = np.zeros((T, SEEDS, task.action_size), np.float32)
    for i, e in enumerate(episodes):
        actions[: len(e[3]), i] = e[3]
    starts = [start_state(task, e[0], e[1]) for e in episodes]
    for (_, obs0), e in zip(starts, episodes):
        np.testing.assert_array_equal(obs0, e[2])  # the float64 reset observation, exactly
    s0 = env.reset(jax.random.PRNGKey(0))
    s0 = jax.tree.map(lambda x: jnp.stack([x] * SEEDS), s0)
    sims = jax.tree.map(lambda *xs: jnp.stack(xs), *[s for s, _ in starts])
    s0 = s0.replace(pipeline_state=sims, obs=sims.extra[:, : task.observation_size])

    def step(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, (s.obs, s.reward, s.done, s.info["truncation"])

    _, (obs, rew, done, trunc) = jax.device_get(jax.jit(lambda s, a: jax.lax.scan(step, s, a))(s0, jnp.asarray(actions)))
    for i, (_, _, _, _, o, r, te, tr) in enumerate(episodes):
        n = len(r)
        np.testing.assert_array_equal(obs[:n, i], o.astype(np.float32), err_msg=f"{env_id} seed {i}")
        np.testing.assert_array_equal(rew[:n, i], r.astype(np.float32), err_msg=f"{env_id} seed {i}")
        np.testing.assert_array_equal(done[:n, i] > 0, te | tr)
        np.testing.assert_array_equal(trunc[:n, i] > 0, tr & ~te)
    if env_id == "HalfCheetah-v5":  # never terminates: every episode is cut at 1000 steps
        assert T == 1000 and all(e[7][-1] and len(e[7]) == 1000 for e in episodes)


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5", "InvertedDoublePendulum-v5"])
def test_resets_draw_from_gymnasiums_noise_law(env_id):
    """Start states of the trainer's resets (JAX draws) and of gymnasium's resets (NumPy draws): the same
    law per coordinate (two-sample Kolmogorov-Smirnov, 2,000 starts each), inside gymnasium's bounds."""
    env = envs.make(env_id, physics=Physics(backend="c"))
    n = 2000
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), n))
    ours = np.concatenate([np.asarray(s.pipeline_state.qpos), np.asarray(s.pipeline_state.qvel)], 1)
    g = gym.make(env_id)
    theirs = []
    for seed in range(n):
        g.reset(seed=10_000 + seed)
        theirs.append(np.concatenate([g.unwrapped.data.qpos, g.unwrapped.data.qvel]))
    theirs = np.array(theirs)
    task = env.env.env.port
    q0 = np.concatenate([task.model.qpos0, np.zeros(task.model.nv)])
    bounded = task.model.nq + (task.model.nv if task.qvel_noise == "uniform" else 0)  # U(-noise, noise) coordinates
    for j in range(ours.shape[1]):
        p = sps.ks_2samp(ours[:, j], theirs[:, j]).pvalue
        assert p > 1e-3, (env_id, j, p)
        if j < bounded:
            assert np.abs(ours[:, j] - q0[j]).max() <= task.noise + 1e-6, (env_id, j)


def test_v5_task_sizes_without_building_an_environment_and_a_bad_backend_refused_in_one_line():
    assert envs.action_size("Walker2d-v5") == 6 and envs.default_episode_length("HalfCheetah-v5") == 1000
    with pytest.raises(ValueError, match="physics backend 'c' does not step 'inverted_double_pendulum' .*; it runs on backend 'mjx'"):
        envs.make("inverted_double_pendulum", physics=Physics(backend="c"))


MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL = 10, 1e-3, 1e-2


@pytest.mark.parametrize("env_id", ["Hopper-v5", "InvertedDoublePendulum-v5",
                                    pytest.param("Walker2d-v5", marks=pytest.mark.benchmark),
                                    pytest.param("HalfCheetah-v5", marks=pytest.mark.benchmark)])
def test_mjx_task_agrees_with_mujoco_c(env_id):
    """The MJX version (float32, MJX's own implementation of the same MJCF) against MuJoCo C from the same
    start under the same random actions: observations within MJX_OBS_TOL and rewards within MJX_REWARD_TOL
    over the first MJX_HORIZON env steps, the same terminations (measured here: Hopper-v5 and
    InvertedDoublePendulum-v5 within 1e-5, Walker2d-v5 5e-5, HalfCheetah-v5 1e-4 at 10 steps; halfcheetah's
    contacts drift to 4e-2 by 25 steps)."""
    assert_mjx_follows_mujoco_c(env_id, MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL, terminations=True)


def test_a_trained_v5_controller_exports_and_scores_the_same_in_mujoco_c_and_gymnasium(tmp_path, capsys):
    """train -> export -> deploy on Hopper-v5: our MuJoCo C task and gymnasium.make('Hopper-v5') give the
    same episodes from the same seeds (the same task, the same start draws); another id is refused."""
    import json

    from gsa_jax.deploy import main as deploy_main
    from gsa_jax.export import main as export_main
    from gsa_jax.train import main as train_main

    run = tmp_path / "run"
    assert train_main(["--env", "Hopper-v5", "--physics", "c", "--policy", "mixture", "--clusters", "2", "--steps", "1024",
                       "--num-envs", "8", "--unroll-length", "64", "--minibatches", "4", "--out", str(run), "--quiet"]) == 0
    assert export_main([str(run), "--out", str(tmp_path / "ctrl.npz")]) == 0
    out = tmp_path / "deploy.json"
    assert deploy_main([str(tmp_path / "ctrl.npz"), "--episodes", "3", "--gymnasium", "Hopper-v5", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    # to float32 rounding: gymnasium computes the control cost in the action's dtype (the controller's float32)
    assert res["env"] == "Hopper-v5" and res["mujoco_c"]["return_mean"] == pytest.approx(res["gymnasium"]["return_mean"], rel=1e-7)
    assert res["mujoco_c"]["length_mean"] == res["gymnasium"]["length_mean"]
    assert deploy_main([str(tmp_path / "ctrl.npz"), "--gymnasium", "Walker2d-v5"]) == 2
    assert "the controller is for 'Hopper-v5', not 'Walker2d-v5'" in capsys.readouterr().err


def test_ant_host_gives_the_same_steps_on_one_or_two_threads():
    """Ant-v5's one-MjData-per-thread host inside the compiled program (64 envs, 30 steps): the same rows
    bit for bit with 1 and 2 threads."""
    rows = []
    for threads in (1, 2):
        env = envs.make("Ant-v5", auto_reset=False, physics=Physics(backend="c", threads=threads))
        s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 64))
        acts = jax.random.uniform(jax.random.PRNGKey(1), (30, 64, env.action_size), minval=-1, maxval=1)
        s, _ = jax.jit(lambda s, a: jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), s, a))(s, acts)
        rows.append(np.asarray(s.pipeline_state.rows))
    np.testing.assert_array_equal(rows[0], rows[1])
    assert len({r.tobytes() for r in rows[0]}) == 64


@pytest.mark.benchmark  # MJX compiles Ant-v5's step for ~1-2 min here: run with -m benchmark, as the other MJX tasks
def test_ant_on_mjx_steps_like_mujoco_c_from_shared_states():
    """Ant-v5 on MJX (contact forces from MJX's rne_postconstraint) against MuJoCo C, one env step from each of
    20 states of a MuJoCo C episode under random actions (contacts on and off). A contact that MuJoCo C makes or
    breaks within float32 rounding of the 0.01 margin can go the other way in MJX, so whole trajectories part
    after such an event (~3 env steps from a reset); from a shared state, measured here: the contact-force
    block within 2.1e-3 at every state, the whole observation within 3e-4 at 18 of 20 (0.15 and 0.03 at the
    two where a contact toggled inside the step), rewards within 4.2e-5 at those 18."""
    from brax.envs.base import State

    env = envs.make_base("Ant-v5")
    init, step = jax.jit(env.pipeline_init), jax.jit(env.step)
    traj, rng, diffs = envs.resolve("Ant-v5").make_c(), np.random.default_rng(0), []
    traj.reset(0)
    for t in range(200):
        a = rng.uniform(-1, 1, 8)
        if t % 10 == 5:
            c = envs.resolve("Ant-v5").make_c()
            c.set_start(traj.data.qpos, traj.data.qvel)
            data = init(jnp.asarray(traj.data.qpos, jnp.float32), jnp.asarray(traj.data.qvel, jnp.float32))
            zero = jnp.zeros((), jnp.float32)
            s = step(State(data, jnp.zeros(env.observation_size, jnp.float32), zero, zero, {}, {}), jnp.asarray(a, jnp.float32))
            obs, reward, terminated = c.step(a)
            d = np.abs(np.asarray(s.obs) - obs)
            diffs.append((d.max(), d[27:].max(), abs(float(s.reward) - reward)))
            assert bool(s.done) == terminated
        traj.step(a)
    whole, forces, rewards = np.array(diffs).T
    assert forces.max() <= 5e-3, forces
    close = whole <= 1e-3
    assert close.sum() >= 16 and rewards[close].max() <= 1e-3, (whole, rewards)
