"""gymnasium's own MuJoCo tasks for exported controllers (gsa_jax.deployment.gymnasium_task, deploy --gymnasium):
layouts checked, not assumed; mismatches refused with a reason."""

import json
import subprocess
import sys

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from envs.mujoco_c import BRAX_PORTS  # noqa: E402
from gsa_jax.deployment.gymnasium_task import GymnasiumError, check_layout, make_gym


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
