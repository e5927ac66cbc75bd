"""gymnasium's own MuJoCo tasks for exported controllers (gsa_jax.deployment.gymnasium_rollout, deploy --gymnasium):
layouts checked, not assumed; mismatches refused with a reason. And a task of ours as a gymnasium env
(envs.as_gymnasium): checked by gymnasium, its episodes its MuJoCo C twin's."""

import json
import subprocess
import sys

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from envs.mujoco_c import BRAX_PORTS  # noqa: E402
from gsa_jax.deployment.gymnasium_rollout import GymnasiumError, check_layout, make_gym


@pytest.mark.parametrize("task, env_id", [("hopper", "Hopper-v5"), ("walker2d", "Walker2d-v5"),
                                          ("halfcheetah", "HalfCheetah-v5"), ("ant", "Ant-v5")])
def test_v5_layouts_match_ours(task, env_id):
    """gymnasium's v5 observation equals our observation function on its states (ant with its option)."""
    env, options = make_gym(task, env_id, check_steps=30)
    assert env.observation_space.shape == (BRAX_PORTS[task]().observation_size,)
    assert options == ({"include_cfrc_ext_in_observation": False} if task == "ant" else {})


def test_mismatched_layout_is_refused():
    """Ant-v5 with its default contact forces observes 105 values: refused, naming the sizes."""
    env = gymnasium.make("Ant-v5")
    with pytest.raises(GymnasiumError, match="observes 105 values, our ant 27"):
        check_layout("ant", env, "Ant-v5", steps=2)


def test_inverted_double_pendulum_refused_for_the_stated_reason():
    """Refused with a reason that is true of the installed gymnasium: it observes 9 (v5) / 11 (v4) values, ours 8."""
    from envs.mujoco_c import observation_layout

    assert gymnasium.make("InvertedDoublePendulum-v5").observation_space.shape == (9,)
    assert gymnasium.make("InvertedDoublePendulum-v4").observation_space.shape == (11,)
    assert len(observation_layout("inverted_double_pendulum")) == 8
    with pytest.raises(GymnasiumError, match="constraint force"):
        make_gym("inverted_double_pendulum", "InvertedDoublePendulum-v5")


@pytest.mark.parametrize("task, env_id, message", [
    ("hopper", "Walker2d-v5", "the controller is for 'hopper'"),
    ("hopper", "hopper", "not a gymnasium env id"),
    ("hopper", "Hopper-v99", "cannot make 'Hopper-v99'"),
    ("ant", "Ant-v4", "cannot make 'Ant-v4' with options"),
    ("allegro_cylinder", "Hopper-v5", "no Allegro-hand task"),
])
def test_bad_requests_are_one_line_errors(task, env_id, message):
    with pytest.raises(GymnasiumError, match=message) as e:
        make_gym(task, env_id)
    assert "\n" not in str(e.value)


def test_deploy_cli_in_gymnasium(tmp_path, random_controller):
    """A (random) hopper controller in our MuJoCo C port and gymnasium's Hopper-v5 via the CLI, no JAX imported."""
    path = random_controller()
    code = ("import sys; from gsa_jax.deploy import main; rc = main([sys.argv[1], '--episodes', '3', '--gymnasium', "
            "'Hopper-v5', '--out', sys.argv[2]]); assert 'jax' not in sys.modules, 'jax was imported'; sys.exit(rc)")
    r = subprocess.run([sys.executable, "-c", code, str(path), str(tmp_path / "d.json")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "gymnasium Hopper-v5" in r.stdout and "MuJoCo C (our port)" in r.stdout
    res = json.loads((tmp_path / "d.json").read_text())
    g = res["gymnasium"]
    assert g["env_id"] == "Hopper-v5" and g["episodes"] == 3 and len(g["returns"]) == 3
    assert np.isfinite(g["return_ci95"]) and g["episode_length_limit"] == 1000
    assert res["versions"]["gymnasium"] == gymnasium.__version__
    bad = subprocess.run([sys.executable, "-m", "gsa_jax.deploy", str(path), "--gymnasium", "Ant-v5"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "not 'Ant-v5'" in bad.stderr
    assert bad.stdout == ""  # refused before any episode in MuJoCo C


@pytest.mark.parametrize("task", ["examples.reacher:Reacher", "Hopper-v5"])
def test_a_task_as_a_gymnasium_env_passes_check_env_and_steps_as_its_mujoco_c_twin(task):
    """envs.as_gymnasium(task) passes gymnasium's env checker, and under the same seeds and random actions (some
    outside [-1, 1]: clipped, as training clips them) its episodes are the task's MuJoCo C twin's step for step:
    observations, rewards, terminations (Hopper-v5 falls), and truncation at the task's time limit."""
    import warnings

    from gymnasium.utils.env_checker import check_env

    import envs

    env = envs.as_gymnasium(task)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded observation boxes, as gymnasium's own MuJoCo tasks have
        check_env(env, skip_render_check=True)
    twin = envs.resolve(task).make_c()
    rng = np.random.default_rng(0)
    ends = []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, twin.reset(seed))
        for t in range(1, env.max_episode_steps + 1):
            action = rng.uniform(-1.5, 1.5, env.action_space.shape)
            obs, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
            want, want_reward, want_done = twin.step(np.clip(action.astype(np.float32), -1.0, 1.0))
            np.testing.assert_array_equal(obs, want)
            assert (reward, terminated) == (want_reward, want_done) and truncated == (t == env.max_episode_steps)
            if terminated or truncated:
                break
        ends.append((t, terminated))
    assert all(t == 200 and not term for t, term in ends) if task.startswith("examples") else all(t < 1000 and term for t, term in ends)
    with pytest.raises(ValueError, match="has no MuJoCo C version"):
        envs.as_gymnasium("inverted_double_pendulum")


def test_a_controller_scores_in_the_gymnasium_env_what_deploy_scores_in_mujoco_c():
    """The committed reacher controller, run by gymnasium_rollout.run_episodes in envs.as_gymnasium, returns what
    mujoco_c.run_episodes (deploy's MuJoCo C episodes) returns for the same start seeds."""
    import glob
    import os

    import envs
    from envs.mujoco_c import make_c
    from envs.mujoco_c import run_episodes as c_episodes
    from gsa_jax.deployment import numpy_policy
    from gsa_jax.deployment.gymnasium_rollout import run_episodes

    root = os.path.join(os.path.dirname(__file__), "..", "experiments", "your_task_reacher", "results", "controllers")
    ctrl = numpy_policy.load(sorted(glob.glob(os.path.join(root, "*K2-s0.npz")))[0])
    task = "examples.reacher:Reacher"
    returns, lengths = run_episodes(envs.as_gymnasium(task), ctrl, 4, seed=5)
    want_returns, want_lengths = c_episodes(make_c(task), ctrl, 4, 200, seed=5)
    np.testing.assert_allclose(returns, want_returns, rtol=1e-12)
    np.testing.assert_array_equal(lengths, want_lengths)
