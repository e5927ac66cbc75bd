"""Domain randomization (envs/randomization.py, envs/randomized_env.py): every draw at its nominal value is the nominal
task (bit for bit on 'c', the same numbers on MJX); a doubled mass steps as MuJoCo C with that mass (step for step); the
scales, the push and the delay do exactly what their definitions say, on a task whose dynamics are exactly linear;
a stopped and resumed randomized run equals an uninterrupted one; bad input is one line before anything compiles."""

import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.c_hosts import STATE_SPEC, float64_rows
from envs.physics import Physics
from envs.randomization import RandomizeError, parse
from gsa_jax.algorithm.config import Config
from gsa_jax.running.spec import SpecError, check_spec
from gsa_jax.running.tasks import config_for
from tests.verify_tasks import DAMPING, GEAR, MASS, TIMESTEP, PointMass

C = Physics(backend="c", threads=1)
N_ENVS, N_STEPS = 3, 30


def rollout(env, actions, key=0):
    """(states after reset, (qpos, obs, reward, done, info) per step [T, N, ...]) of env batched over N envs."""
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(key), actions.shape[1]))  # eager: op by op

    def step(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, (getattr(s.pipeline_state, "qpos", s.obs), s.obs, s.reward, s.done)

    return s0, jax.jit(lambda s: jax.lax.scan(step, s, actions))(s0)[1]


def actions_for(env, n=N_STEPS):
    t, i, j = np.meshgrid(np.arange(n), np.arange(N_ENVS), np.arange(env.action_size), indexing="ij")
    return jnp.asarray(0.5 * np.sin(0.3 * t + i + j), jnp.float32)


@pytest.fixture(scope="module")
def hopper_nominal():
    env = envs.make("Hopper-v5", physics=C)
    acts = actions_for(env)
    return acts, rollout(env, acts)


def test_parse_canonical_text_and_one_line_errors():
    spec = parse({"gear": [0.9, 1.1], "mass": "0.9:1.125", "delay": 2, "push": 0.125, "obs_noise": 0.01})
    assert spec.text() == "gear=0.9:1.1, mass=0.9:1.125, obs_noise=0.01, delay=2, push=0.125"
    assert parse(spec.text()) == spec and parse("") == parse(None) == parse({})
    assert [f for f, _, _ in spec.model_fields] == ["actuator_gear", "body_mass", "body_inertia"]
    for text, message in (("mass=0:1", r"\(0, inf\)"), ("mass=1.2:1.1", "lo <= hi"), ("mass=a", "not a number"),
                          ("delay=1.5", "whole number"), ("push=-1", ">= 0"), ("push_rate=2", r"\[0, 1\]"),
                          ("mass=1, mass=2", "twice"), ("mass=1, body_mass=1", "scaled twice"), ("mass", "name=value")):
        with pytest.raises(RandomizeError, match=message) as e:
            parse(text)
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("text, backend, message", [
    ("masss=0.9:1.1", "c", "unknown parameter 'masss'"),
    ("delay=1000", "c", "not shorter than the episode"),
    ("mass=0.9:1.1", "c", "Ant-v5 takes no per-simulation model on backend 'c'.*--physics mjx"),
])
def test_config_refuses_before_compiling(text, backend, message):
    env = "Ant-v5" if "Ant" in message else "Hopper-v5"
    with pytest.raises(ValueError, match=message) as e:
        config_for(Config(env=env, physics=Physics(backend=backend), randomize=text))
    assert "\n" not in str(e.value)


def test_mjx_refuses_a_field_it_lacks_and_names_backend_c():
    import dataclasses

    from mujoco import mjx

    have = {f.name for f in dataclasses.fields(mjx.Model)}
    model = envs.task_model("Hopper-v5")
    lacking = next(f for f in dir(model) if not f.startswith(("_", "opt", "stat")) and f not in have
                   and isinstance(getattr(model, f), np.ndarray) and getattr(model, f).dtype.kind == "f")
    with pytest.raises(ValueError, match=f"MJX's model has no field {lacking}.*backend 'c'"):
        config_for(Config(env="Hopper-v5", randomize=f"{lacking}=0.9:1.1"))
    config_for(Config(env="Hopper-v5", physics=Physics(backend="c"), randomize=f"{lacking}=0.9:1.1"))  # 'c' scales it


def test_spec_randomize_table_goes_to_config_text():
    raw = {"envs": ["Hopper-v5"], "policies": ["mlp"], "steps": 1000, "config": {"physics": {"backend": "c"}},
           "randomize": {"mass": [0.9, 1.125], "delay": 1}}
    spec = check_spec(raw)
    assert spec.config["randomize"] == "mass=0.9:1.125, delay=1"
    assert check_spec(spec.to_json()).config == spec.config  # sweep.json's spec reads back the same
    with pytest.raises(SpecError, match="not both"):
        check_spec({**raw, "config": {"randomize": "mass=1"}})


def test_c_nominal_draws_equal_the_nominal_task_bit_for_bit(hopper_nominal):
    acts, (_, ref) = hopper_nominal
    env = envs.make("Hopper-v5", physics=C, randomize="mass=1, friction=1:1, gear=1, damping=1, delay=0")
    _, out = rollout(env, acts)
    for a, b in zip(ref, out):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_c_doubled_mass_steps_as_mujoco_c_with_that_mass(hopper_nominal):
    """Every body's mass and inertia x 2 and mj_setConst, stepped by mj_step from the same start rows: equal."""
    acts, (_, ref) = hopper_nominal
    s0, (qpos, _, _, done) = rollout(envs.make("Hopper-v5", physics=C, randomize="mass=2"), acts)
    task = envs.resolve("Hopper-v5").make_c()
    m = task.model
    m.body_mass[:] *= 2
    m.body_inertia[:] *= 2
    d = mujoco.MjData(m)
    mujoco.mj_setConst(m, d)
    rows, n_mj = float64_rows(s0.pipeline_state.rows), mujoco.mj_stateSize(m, STATE_SPEC)
    for i in range(N_ENVS):
        mujoco.mj_setState(m, d, rows[i, :n_mj], STATE_SPEC)
        for t in range(N_STEPS):
            d.ctrl[:] = np.asarray(acts[t, i], np.float64)
            mujoco.mj_step(m, d, nstep=task.n_frames)
            if done[t, i]:  # the env restarted: the rest is another episode
                break
            np.testing.assert_array_equal(np.asarray(qpos[t, i]), d.qpos.astype(np.float32))
    assert not np.array_equal(np.asarray(qpos), np.asarray(ref[0]))


def test_c_delay_applies_each_episodes_draw_of_late_actions(hopper_nominal):
    """delay=1: each env's episode applies its actions d in {0, 1} steps late (zeros first) -- the nominal task
    stepped with the actions shifted by d, bit for bit."""
    acts, _ = hopper_nominal
    env = envs.make("Hopper-v5", physics=C, randomize="delay=1")
    s0, (qpos, _, _, done) = rollout(env, acts, key=3)
    delays = np.asarray(s0.info["randomize_delay"])
    assert set(delays) == {0, 1}  # this key draws both
    shifted = jnp.where(jnp.asarray(delays)[None, :, None] == 1, jnp.concatenate([jnp.zeros_like(acts[:1]), acts[:-1]]), acts)
    _, (ref_qpos, _, _, ref_done) = rollout(envs.make("Hopper-v5", physics=C), shifted, key=3)
    first_end = np.argmax(np.asarray(done) > 0.5, axis=0)  # compare up to each env's first episode end
    for i in range(N_ENVS):
        end = first_end[i] if done[:, i].any() else N_STEPS
        np.testing.assert_array_equal(np.asarray(qpos[:end, i]), np.asarray(ref_qpos[:end, i]))


def linear_step(m, d, g, u, force):
    """(x, v) after one control step of the point mass with mass m, damping d, gear g, control u and an external
    force along x (MuJoCo's Euler step with implicit damping, tests/verify_tasks.py), from the state given."""
    h = TIMESTEP

    def step(x, v):
        for _ in range(PointMass.frame_skip):
            v = (m * v + h * (g * u + force)) / (m + h * d)
            x = x + h * v
        return x, v

    return step


@pytest.mark.parametrize("backend", ["c", "mjx"])
def test_scales_and_push_do_what_they_say_on_a_linear_task(backend):
    """The point mass with mass x 2, damping x 1.5, gear x 0.5 and a push at every step (push_rate 1) of impulse
    0.1 x total mass along +-x: each step equals the linear step of those parameters with force +-0.1 M / dt,
    exactly on 'c' (float32 of the float64 state), to float32 rounding on MJX."""
    physics = C if backend == "c" else Physics()
    env = envs.make(envs.resolve(PointMass), physics=physics,
                    randomize="mass=2, damping=1.5, gear=0.5, push=0.1, push_rate=1")
    acts = actions_for(env, 8)
    s0, (qpos, obs, _, _) = rollout(env, acts)
    x, v = np.asarray(s0.obs[:, 0], np.float64), np.asarray(s0.obs[:, 1], np.float64)
    force = 0.1 * MASS / (TIMESTEP * PointMass.frame_skip)
    tol = dict(rtol=0, atol=1e-6) if backend == "c" else dict(rtol=1e-4, atol=1e-5)
    for t in range(acts.shape[0]):
        u = np.clip(np.asarray(acts[t, :, 0], np.float64), -1, 1)
        pushed = [linear_step(2 * MASS, 1.5 * DAMPING, 0.5 * GEAR, u, s * force)(x, v) for s in (1.0, -1.0)]
        got = np.asarray(obs[t], np.float64)
        err = [np.abs(got - np.stack(p, axis=1)).max(axis=1) for p in pushed]
        sign = np.where(err[0] <= err[1], 1.0, -1.0)
        expect = np.where(sign[:, None] > 0, np.stack(pushed[0], 1), np.stack(pushed[1], 1))
        np.testing.assert_allclose(got, expect, **tol)
        x, v = got[:, 0], got[:, 1]


def test_mjx_nominal_draws_equal_the_nominal_task():
    env = envs.make(envs.resolve(PointMass))
    acts = actions_for(env, 10)
    _, ref = rollout(env, acts)
    _, out = rollout(envs.make(envs.resolve(PointMass), randomize="mass=1, damping=1:1, gear=1"), acts)
    for a, b in zip(ref, out):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-6)


SMALL = ["--env", "InvertedDoublePendulum-v5", "--physics", "c", "--steps", "2048", "--num-envs", "8",
         "--unroll-length", "32", "--minibatches", "4", "--epochs", "1", "--episode-length", "100", "--chunk", "1",
         "--eval-every", "4", "--eval-envs", "2", "--quiet", "--no-tensorboard",
         "--randomize", "mass=0.8:1.25, damping=0.5:2, delay=1, push=0.2, push_rate=0.05, obs_noise=0.01"]


def test_randomized_run_resumes_bit_for_bit(tmp_path):
    """A randomized run stopped after 3 of 8 iterations and resumed ends with the parameters and metrics of an
    uninterrupted one; config.json records the randomization."""
    from gsa_jax.train import main

    whole, parts = tmp_path / "whole", tmp_path / "parts"
    assert main(SMALL + ["--out", str(whole)]) == 0
    assert main(SMALL + ["--out", str(parts), "--stop-after", "3"]) == 0
    assert main(SMALL + ["--out", str(parts), "--resume"]) == 0
    for name in ("params.npz", "metrics.npz"):
        with np.load(whole / name) as a, np.load(parts / name) as b:
            for k in a.files:
                if not k.startswith("meta/") and a[k].dtype.kind in "fiu" and not k.endswith("_s"):  # not clocks
                    np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name}:{k}")
    config = json.loads((whole / "config.json").read_text())["config"]
    assert config["randomize"] == "mass=0.8:1.25, damping=0.5:2, obs_noise=0.01, delay=1, push=0.2, push_rate=0.05"


def doubled_masses(model, rng):
    """A randomizer in Playground's protocol (registry.get_domain_randomizer): every body's mass x 2, one per key."""
    in_axes = jax.tree.map(lambda _: None, model).tree_replace({"body_mass": 0})
    masses = jnp.broadcast_to(model.body_mass * 2, (rng.shape[0],) + model.body_mass.shape)
    return model.tree_replace({"body_mass": masses}), in_axes


def test_playground_registry_randomizer_equals_playgrounds_own_wrapper(monkeypatch):
    """--randomize playground draws a Playground environment's own randomizer per episode: with a randomizer of its
    protocol, each env steps as Playground's BraxDomainRandomizationVmapWrapper steps it; a task it does not apply to,
    or one whose registry has no randomizer, is one line."""
    from mujoco_playground._src.wrapper import BraxDomainRandomizationVmapWrapper

    from envs import playground_adapter

    name = "playground:CartpoleBalance"
    with pytest.raises(ValueError, match="has no domain randomizer for 'playground:CartpoleBalance'"):
        envs.make(name, randomize="playground")
    with pytest.raises(ValueError, match="applies to playground:<Name> tasks"):
        config_for(Config(env="Hopper-v5", randomize="playground"))
    reg = playground_adapter.registry()
    monkeypatch.setattr(reg, "get_domain_randomizer", lambda n: doubled_masses if n == "CartpoleBalance" else None)
    env = envs.make(name, episode_length=1000, randomize="playground")
    acts = actions_for(env, 10)
    _, (_, obs, _, _) = rollout(env, acts)
    keys = jax.random.split(jax.random.PRNGKey(0), N_ENVS)
    own = BraxDomainRandomizationVmapWrapper(playground_adapter.load(name), lambda m: doubled_masses(m, keys))
    s = jax.jit(own.reset)(keys)
    step = jax.jit(own.step)
    for t in range(acts.shape[0]):
        s = step(s, acts[t])
        np.testing.assert_allclose(np.asarray(obs[t]), np.asarray(s.obs["state"] if isinstance(s.obs, dict) else s.obs),
                                   rtol=1e-5, atol=1e-6)
