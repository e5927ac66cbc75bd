"""The MJX Allegro-hand task (envs/allegro.py) against MuJoCo C on the same MJCF.

Compiled functions are shared across the module's tests (single-env reset/step/forward).
"""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import envs
from envs import allegro


@pytest.fixture(scope="module")
def task():
    env = envs.make_base("allegro_cylinder")
    return env, jax.jit(env.reset), jax.jit(env.step), jax.jit(lambda d: env.tactile(mjx.forward(env.sys, d)))


def c_data(m, data):
    """MuJoCo C MjData holding the MJX state's qpos, qvel and PD targets."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:] = (np.asarray(x) for x in (data.qpos, data.qvel, data.ctrl))
    return d


def opened(m, data):
    """The state with both fingers bent away from the cylinder (index and thumb flexion reduced)."""
    q = np.asarray(data.qpos).copy()
    q[1:4] -= 0.3  # index flexion joints
    q[6:8] -= 0.3  # thumb flexion joints
    q[:8] = np.clip(q[:8], *m.jnt_range[:8].T)
    return data.replace(qpos=jnp.asarray(q, jnp.float32), ctrl=jnp.asarray(q[:8], jnp.float32))


def test_interface_sizes():
    env = envs.make("allegro_cylinder")
    assert env.observation_size == 10 and env.action_size == 8
    assert env.episode_length == envs.default_episode_length("allegro_cylinder") == 200


def test_reset_touches_and_opened_fingers_do_not(task):
    env, reset, _, tactile = task
    m = env.mj_model
    for seed in range(3):
        s = reset(jax.random.PRNGKey(seed))
        assert s.obs.shape == (10,)
        assert np.all(np.asarray(s.obs[8:]) > 0.01), s.obs  # both tips in contact at the start
        np.testing.assert_allclose(s.obs[:8], s.pipeline_state.qpos[:8])
    d_open = opened(m, s.pipeline_state)
    np.testing.assert_array_equal(np.asarray(tactile(d_open)), 0.0)
    d = c_data(m, d_open)
    mujoco.mj_forward(m, d)
    np.testing.assert_array_equal(allegro.tactile_numpy(m, d), 0.0)


def test_tactile_matches_mujoco_c_contact_forces(task):
    """On states along a random-action rollout: per-finger normal force (efc rows in MJX) vs
    mj_contactForce summed per fingertip in MuJoCo C, recomputed by mj_forward on the same state."""
    env, reset, step, tactile = task
    m = env.mj_model
    s = reset(jax.random.PRNGKey(1))
    rng = np.random.default_rng(0)
    compared = 0
    for t in range(40):
        s = step(s, jnp.asarray(rng.uniform(-1, 1, 8), jnp.float32))
        if t % 4:
            continue
        ours = np.asarray(tactile(s.pipeline_state))
        d = c_data(m, s.pipeline_state)
        mujoco.mj_forward(m, d)
        ref = allegro.tactile_numpy(m, d)
        np.testing.assert_allclose(ours, ref, rtol=0.03, atol=2e-3)
        compared += int(np.any(ref > 0.01))
    assert compared >= 5  # most compared states had a loaded fingertip


def test_reward_sign_follows_cylinder_rotation(task):
    env, reset, step, _ = task
    s = reset(jax.random.PRNGKey(0))
    free = opened(env.mj_model, s.pipeline_state)
    hinge = env.mj_model.jnt_dofadr[env.mj_model.joint("object_hinge").id]
    for omega in (3.0, -3.0):
        d = free.replace(qvel=free.qvel.at[hinge].set(omega))
        r = float(step(s.replace(pipeline_state=d), jnp.zeros(8)).reward)
        assert np.sign(r) == np.sign(omega) and abs(r - omega) < 0.1 * abs(omega), (omega, r)


def test_mjx_and_mujoco_c_trajectories_agree_for_one_second(task):
    """100 control steps (1 s) of smooth random actions from the same start, MJX vs MuJoCo C."""
    env, reset, step, _ = task
    m = env.mj_model
    s = reset(jax.random.PRNGKey(2))
    d = c_data(m, s.pipeline_state)
    mujoco.mj_forward(m, d)
    actions = np.clip(np.cumsum(np.random.default_rng(1).normal(0, 0.3, (100, 8)), 0), -1, 1).astype(np.float32)
    ret_mjx = ret_c = 0.0
    for a in actions:
        s = step(s, jnp.asarray(a))
        obs_c, r_c = allegro.step_mujoco(m, d, a)
        ret_mjx, ret_c = ret_mjx + float(s.reward), ret_c + r_c
    np.testing.assert_allclose(np.asarray(s.pipeline_state.qpos), d.qpos, atol=5e-3)
    np.testing.assert_allclose(np.asarray(s.obs), obs_c, atol=5e-3)
    assert abs(ret_mjx - ret_c) <= 0.02 * abs(ret_c) + 0.05, (ret_mjx, ret_c)


CURL = np.array([0, 1, -1, -1, 0, 0, 0, 0], np.float32)  # index: flex the base joint, open the others: wraps the cylinder


def object_contacts(names, geom_pairs, dists):
    """{link name: deepest signed distance [m]} of the contacts between the cylinder and the hand's links."""
    out = {}
    for (a, b), dist in zip(geom_pairs, dists):
        if "object" in (names[a], names[b]):
            link = names[b] if names[a] == "object" else names[a]
            out[link] = min(out.get(link, np.inf), float(dist))
    return out


def test_curled_index_finger_stops_at_the_cylinder(task):
    """1.2 s of CURL from the grasp: the index finger's middle and distal links touch the cylinder and stay
    on its surface (penetration < 3 mm at every step), in MJX and in MuJoCo C alike."""
    env, reset, step, _ = task
    m = env.mj_model
    names = [m.geom(g).name for g in range(m.ngeom)]
    s = reset(jax.random.PRNGKey(0))
    d = c_data(m, s.pipeline_state)
    mujoco.mj_forward(m, d)
    deepest = {"mjx": 0.0, "c": 0.0}
    for _ in range(120):
        s = step(s, jnp.asarray(CURL))
        allegro.step_mujoco(m, d, CURL)
        c = s.pipeline_state._impl.contact
        touching = {"mjx": object_contacts(names, np.asarray(c.geom), np.asarray(c.dist)),
                    "c": object_contacts(names, [(x.geom1, x.geom2) for x in d.contact], d.contact.dist)}
        for k, got in touching.items():
            deepest[k] = min([deepest[k], *got.values()])
    assert deepest["mjx"] > -0.003 and deepest["c"] > -0.003, deepest
    for k, got in touching.items():
        links = {link for link, dist in got.items() if dist < 0}
        assert {"ff_med", "ff_dist"} <= links, (k, got)  # link contact, not only the tip
    np.testing.assert_allclose(np.asarray(s.pipeline_state.qpos[:4]), d.qpos[:4], atol=0.02)


def test_wrong_action_shape_is_a_clear_error(task):
    env, reset, step, _ = task
    s = reset(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"takes \(8,\)"):
        env.step(s, jnp.zeros(7))
    wrapped = envs.make("allegro_cylinder")  # the wrappers check before anything runs
    with pytest.raises(ValueError, match=r"takes \(8,\)"):
        wrapped.step(s, jnp.zeros(3))
    with pytest.raises(ValueError, match=r"takes \(8,\)"):
        allegro.step_mujoco(env.mj_model, mujoco.MjData(env.mj_model), np.zeros(9))


def test_render_scene_png(tmp_path):
    from gsa_jax.deployment.rendering import pick_gl

    if pick_gl() is None:
        pytest.skip("no libOSMesa or libEGL on this machine (`make scene` installs libosmesa6)")
    out = tmp_path / "scene.png"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    r = subprocess.run([sys.executable, "-m", "gsa_jax.render", "allegro_cylinder", "--out", str(out)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    import matplotlib.pyplot as plt

    img = plt.imread(out)
    assert img.shape[0] == 480 and img.shape[1] == 2 * 640  # the model's two cameras side by side
    assert img[..., :3].std() > 0.05  # a picture, not a blank frame
    bad = subprocess.run([sys.executable, "-m", "gsa_jax.render", "allegro_cylinder", "--out", str(tmp_path / "x.jpg")],
                         capture_output=True, text=True, env=env, timeout=300)
    assert bad.returncode == 2 and "must end in .png" in bad.stderr
