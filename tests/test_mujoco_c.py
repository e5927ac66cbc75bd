"""MuJoCo C ports of the tasks (envs/mujoco_c.py) step for step against their MJX environments, and
`python -m gsa_jax.deploy` running an exported controller without JAX."""

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.mujoco_c import make_c


@pytest.fixture(scope="module")
def hopper_mjx():
    env = envs.make_base("hopper")
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_hopper_port_matches_mjx_step_for_step(hopper_mjx):
    """Same start state, same actions: observation, reward and termination agree (float32 MJX vs float64 C)
    over 30 steps (0.24 s) from 3 starts."""
    env, reset, step = hopper_mjx
    task = make_c("hopper")
    rng = np.random.default_rng(0)
    for seed in range(3):
        s = reset(jax.random.PRNGKey(seed))
        obs = task.set_start(np.asarray(s.pipeline_state.qpos), np.asarray(s.pipeline_state.qvel))
        np.testing.assert_allclose(obs, np.asarray(s.obs), atol=1e-5)
        for t in range(30):
            a = rng.uniform(-1, 1, 3).astype(np.float32)
            s = step(s, jnp.asarray(a))
            obs, r, done = task.step(a)
            np.testing.assert_allclose(obs, np.asarray(s.obs), atol=2e-3, rtol=2e-3, err_msg=f"seed {seed} step {t}")
            assert abs(r - float(s.reward)) < 2e-2, (t, r, float(s.reward))
            assert done == bool(s.done > 0.5)


@pytest.mark.parametrize("name", ["walker2d", "halfcheetah", "ant"])
def test_brax_port_matches_mjx_each_step(name):
    """Each env step from MJX's own state (qpos, qvel, the solver's warm start and the torso position MJX
    carries, which the forward reward differences), along 2 x 25-step MJX rollouts: reward (1e-3) and
    termination agree at every step, positions to 2e-3, velocities to 1e-3 at 90% of the steps. The
    rest are contact onsets, where float32 MJX and float64 MuJoCo C resolve contacts differently (ant's
    1-iteration solver most: up to ~0.2 in one velocity); whole trajectories drift apart from there."""
    env = envs.make_base(name)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    task = make_c(name)
    n_pos = task.observe().shape[0] - task.model.nv
    rng = np.random.default_rng(0)
    vel_err = []
    for seed in range(2):
        s = reset(jax.random.PRNGKey(seed))
        for t in range(25):
            ps = s.pipeline_state
            task.set_start(np.asarray(ps.qpos), np.asarray(ps.qvel))
            task.data.xpos[1] = np.asarray(ps.xpos[1])  # kinematics of the last substep's start, as MJX holds them
            task.data.qacc_warmstart[:] = np.asarray(ps.qacc_warmstart)
            a = rng.uniform(-1, 1, task.action_size).astype(np.float32)
            s = step(s, jnp.asarray(a))
            obs, r, done = task.step(a)
            err = np.abs(obs - np.asarray(s.obs))
            assert err[:n_pos].max() < 2e-3, (seed, t, err[:n_pos].max())
            assert abs(r - float(s.reward)) < 1e-3, (seed, t, r, float(s.reward))
            assert done == bool(s.done > 0.5), (seed, t)
            vel_err.append(err[n_pos:].max())
    assert np.quantile(vel_err, 0.9) < 1e-3 and max(vel_err) < 0.5, sorted(vel_err)[-5:]


@pytest.mark.parametrize("name", ["walker2d", "halfcheetah", "ant"])
def test_brax_port_reset_distribution(name):
    """Seeded resets around qpos0 with the task's noise (uniform on qpos; uniform or normal on qvel)."""
    task = make_c(name)
    q = []
    for seed in range(200):
        task.reset(seed)
        q.append(np.concatenate([task.data.qpos - task.model.qpos0, task.data.qvel]))
    q, law = np.array(q), task.task
    nq = task.model.nq
    assert np.all(np.abs(q[:, :nq]) <= law.noise + 1e-9) and q[:, :nq].std() > law.noise / 3
    vel_std = q[:, nq:].std()
    assert (vel_std > law.noise * 0.8) if law.qvel_noise == "normal" else (np.all(np.abs(q[:, nq:]) <= law.noise + 1e-9))
    np.testing.assert_array_equal(task.reset(3), task.reset(3))


def test_hopper_reset_distribution():
    task = make_c("hopper")
    obs = np.stack([task.reset(seed) for seed in range(200)])
    assert obs.shape == (200, 11)
    assert np.all(np.abs(obs[:, 1:5] - task.model.qpos0[2:6]) <= 5e-3 + 1e-7)  # angles: qpos0 + U(-5e-3, 5e-3)
    assert np.all(np.abs(obs[:, 5:]) <= 5e-3 + 1e-7) and obs[:, 5:].std() > 1e-3  # velocities: U(-5e-3, 5e-3)
    assert np.all(np.abs(obs[:, 0] - 1.25) <= 5e-3 + 1e-6)  # torso height: 1.25 m + the rootz noise
    np.testing.assert_array_equal(task.reset(3), task.reset(3))  # seeded


def test_allegro_port_matches_mjx_reset():
    """The C port starts from the keyframe like the MJX env (targets jittered, same observation layout)."""
    task = make_c("allegro_cylinder")
    env = envs.make_base("allegro_cylinder")
    s = jax.jit(env.reset)(jax.random.PRNGKey(0))
    obs = task.reset(0)
    assert obs.shape == (10,)
    np.testing.assert_allclose(obs[:8], np.asarray(s.obs[:8]), atol=1e-6)  # same keyframe joint positions
    assert np.all(obs[8:] > 0.01)  # both tips touching
    with pytest.raises(ValueError, match="no MuJoCo C version of .inverted_double_pendulum."):
        make_c("inverted_double_pendulum")


def test_deploy_on_the_allegro_hand(tmp_path, random_controller):
    """A (random) Allegro controller runs in MuJoCo C through the deploy CLI: full 2 s episodes."""
    from gsa_jax.deploy import main

    assert main([str(random_controller("allegro_cylinder")), "--episodes", "2", "--out", str(tmp_path / "d.json")]) == 0
    res = json.loads((tmp_path / "d.json").read_text())
    assert res["env"] == "allegro_cylinder" and res["mujoco_c"]["length_mean"] == 200
    assert np.all(np.isfinite(res["mujoco_c"]["returns"]))


def test_deploy_runs_without_jax_and_reports(tmp_path, random_controller):
    """An exported (random) hopper controller runs in MuJoCo C via the CLI, with no JAX module imported."""
    path = random_controller(episode_length=50)
    code = ("import sys; from gsa_jax.deploy import main; rc = main([sys.argv[1], '--episodes', '3', '--out', sys.argv[2]]);"
            "assert 'jax' not in sys.modules, 'jax was imported'; sys.exit(rc)")
    r = subprocess.run([sys.executable, "-c", code, str(path), str(tmp_path / "d.json")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "d.json").read_text())
    c = res["mujoco_c"]
    assert res["env"] == "hopper" and c["episodes"] == 3 and 1 <= c["length_mean"] <= 50
    assert len(c["returns"]) == 3 and np.isfinite(c["return_mean"])
    bad = subprocess.run([sys.executable, "-m", "gsa_jax.deploy", str(tmp_path / "none.npz")], capture_output=True, text=True)
    assert bad.returncode == 2 and "does not exist" in bad.stderr
    (tmp_path / "junk.npz").write_bytes(b"junk")  # not a zip: refused in one line, nothing unpickled
    bad = subprocess.run([sys.executable, "-m", "gsa_jax.deploy", str(tmp_path / "junk.npz")], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "is not an exported controller" in bad.stderr
