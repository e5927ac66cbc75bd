"""A task a user defines outside the package (envs/task.py; examples/reacher.py, named 'module:Class'): it trains on
backend 'c' and learns, exports and runs in MuJoCo C; MJX steps it like MuJoCo C; a bad definition is one line
before anything compiles; envs.register names one. (Its sweep, resume and run-alone equality:
tests/test_c_backend.py's user_sweep.)"""

import glob
import hashlib
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.physics import Physics
from envs.task import TaskC
from mjx_vs_c import assert_mjx_follows_mujoco_c

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASK = "examples.reacher:Reacher"
ZERO_ACTION_RETURN = -49.5  # examples/reacher.py holding still, over its start distribution (measured; 200 steps)
# measured over 5 episodes x 200 steps: observations within 1.8e-6, rewards within 3.0e-7
MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL = 200, 2e-5, 3e-6


def test_the_example_learns_on_c_exports_and_runs_in_mujoco_c(tmp_path):
    """80k steps of K = 2 on backend 'c' (random actions score about the zero-action return, -49.5): the training
    return crosses -38 (measured: about -28); the exported controller runs in MuJoCo C above -40; config.json
    records the file and sha256 of the code that defined the task."""
    from gsa_jax.deploy import main as deploy_main
    from gsa_jax.export import main as export_main
    from gsa_jax.train import main as train_main

    run = tmp_path / "run"
    assert train_main(["--env", TASK, "--physics", "c", "--clusters", "2", "--steps", "81920", "--out", str(run),
                       "--quiet", "--no-tensorboard"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["result"]["final_episode_return"] > -38.0, config["result"]
    source = os.path.join(os.path.dirname(__file__), "..", "examples", "reacher.py")
    with open(source, "rb") as f:
        assert config["task"]["sha256"] == hashlib.sha256(f.read()).hexdigest() and config["task"]["builtin"] is False
    assert export_main([str(run), "--out", str(tmp_path / "ctrl.npz")]) == 0
    assert deploy_main([str(tmp_path / "ctrl.npz"), "--episodes", "8", "--out", str(tmp_path / "deploy.json")]) == 0
    deployed = json.loads((tmp_path / "deploy.json").read_text())["mujoco_c"]
    assert deployed["return_mean"] > -40.0 and deployed["length_mean"] == 200, deployed


def test_mjx_steps_the_example_like_mujoco_c():
    """From MJX's own start state, under the same random actions, MuJoCo C's observations stay within MJX_OBS_TOL and
    rewards within MJX_REWARD_TOL for a whole episode (MJX_HORIZON steps; no contacts in this model)."""
    assert_mjx_follows_mujoco_c(TASK, MJX_HORIZON, MJX_OBS_TOL, MJX_REWARD_TOL, key=3)


def test_the_start_law_is_the_tasks_on_every_path():
    """qpos ~ init_qpos + U(-noise, noise) and qvel ~ U(-vel_noise, vel_noise) per coordinate, on MuJoCo C (NumPy
    draws) and on backend 'c' (JAX draws): the same bounds, and the still target stays still."""
    task = envs.resolve_task(TASK)
    c = TaskC(task)
    starts = []
    for seed in range(200):
        c.reset(seed)
        starts.append(np.concatenate([c.data.qpos, c.data.qvel]))
    ce = envs.make_base(TASK, Physics(backend="c"))
    s = jax.jit(jax.vmap(ce.reset))(jax.random.split(jax.random.PRNGKey(0), 200))
    jax_starts = np.concatenate([np.asarray(s.pipeline_state.qpos), np.asarray(s.pipeline_state.qvel)], axis=1)
    bound = np.concatenate([task.noise, task.vel_noise]) + 1e-6
    for x in (np.array(starts), jax_starts):
        assert np.all(np.abs(x - np.concatenate([task.start_qpos, np.zeros(4)])) <= bound)
        assert np.all(np.abs(x[:, :4]).max(axis=0) > 0.9 * task.noise)  # the whole range is drawn
        assert np.all(x[:, 6:] == 0.0)


BAD = {
    "no_module": ("no_such_module_xyz:Task", "cannot import 'no_such_module_xyz'"),
    "no_class": ("examples.reacher:Reacherr", "has no 'Reacherr'; did you mean Reacher?"),
    "bad_mjcf": ("FILE:BadMjcf", "the MJCF does not load"),
    "no_actuator": ("FILE:NoActuator", "no actuators (action size 0)"),
    "nan_obs": ("FILE:NanObservation", "non-finite entries at [0, 1"),
    "xp_mismatch": ("FILE:OtherValues", "differs between NumPy and jax.numpy"),
    "np_inside": ("FILE:NumpyInside", "do not run with jax.numpy under jax.jit"),
    "noise_size": ("FILE:BadNoise", "noise has shape (3,); use a scalar or [4]"),
    "outcome_obs": ("FILE:ShortOutcome", "outcome() must return obs [n, 10] (as observe())"),
    "unknown_derived": ("FILE:UnknownField", "derived names ['not_a_field'], which are not MjData fields"),
    "post_constraint": ("FILE:ForcesWithoutFlag", "set post_constraint = True"),
    "raises": ("FILE:Raises", "stepping it failed: ZeroDivisionError"),
    "not_a_task": ("FILE:NotATask", "not an envs.task.Task"),
    "push_body": ("FILE:NoSuchBody", "push_body 'hand' is not a body of the model"),
    "ctrlrange": ("FILE:WideRange", "has ctrlrange [-2.0, 2.0]; the policy's actions lie in [-1, 1]"),
    "vector_obs": ("FILE:VectorObservation", "observe() must return the observation as [n, d], one row per simulation; "
                                             "got shape (10,) (float64) for n = 1"),
    "float_terminated": ("FILE:FloatTerminated", "outcome() must return the terminated as a bool array (e.g. a "
                                                 "comparison, or xp.zeros(n, bool)); got float64 [1]"),
    "scalar_reward": ("FILE:ScalarReward", "outcome() must return the reward as [n], one row per simulation; got "
                                             "shape () (float64)"),
    "nan_reward": ("FILE:NanReward", "outcome() returned the reward [nan] at the first state under zero action"),
    "file_without_class": ("FILE", "name the task class it defines, 'path/file.py:Class' or 'module:Class'"),
    "equilibrium_size": ("FILE:WrongEquilibrium", "equilibrium_qpos has shape (2,); it is the qpos held, nq = 4 finite "
                                                  "numbers (qpos: "),
    "tolerance_size": ("FILE:WrongTolerance", "convergence_tolerance has shape (3,); give one number > 0 or 2 nv = 8"),
}
BAD_TASKS = '''
import numpy as np
from envs.task import Task
from examples.reacher import Reacher

class BadMjcf(Reacher):
    xml = "<mujoco><worldbody><body><joint/></body></worldbody>"

class NoActuator(Reacher):
    xml = Reacher.xml.split("<actuator>")[0] + "</mujoco>"

class NanObservation(Reacher):
    def observe(self, qpos, qvel, derived, xp=np):
        return super().observe(qpos, qvel, derived, xp) / 0.0

class OtherValues(Reacher):
    def observe(self, qpos, qvel, derived, xp=np):
        return super().observe(qpos, qvel, derived, xp) * (2.0 if xp is not np else 1.0)

class NumpyInside(Reacher):
    def observe(self, qpos, qvel, derived, xp=np):
        return np.concatenate([qpos, qvel], axis=1)

class BadNoise(Reacher):
    noise = [0.1, 0.1, 0.1]

class ShortOutcome(Reacher):
    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        obs, reward, terminated = super().outcome(before, qpos, qvel, derived, action, xp)
        return obs[:, :3], reward, terminated

class UnknownField(Reacher):
    derived = ("site_xpos", "not_a_field")

class ForcesWithoutFlag(Reacher):
    derived = ("site_xpos", "cfrc_ext")

class Raises(Reacher):
    def observe(self, qpos, qvel, derived, xp=np):
        return 1 / 0

class WideRange(Reacher):
    xml = Reacher.xml.replace('ctrlrange="-1 1"', 'ctrlrange="-2 2"', 1)

class NotATask:
    pass

class NoSuchBody(Reacher):
    push_body = "hand"

class VectorObservation(Reacher):
    def observe(self, qpos, qvel, derived, xp=np):
        return super().observe(qpos, qvel, derived, xp)[0]

class FloatTerminated(Reacher):
    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        obs, reward, terminated = super().outcome(before, qpos, qvel, derived, action, xp)
        return obs, reward, xp.zeros(qpos.shape[:1])

class NanReward(Reacher):
    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        obs, reward, terminated = super().outcome(before, qpos, qvel, derived, action, xp)
        return obs, reward * xp.nan, terminated

class WrongEquilibrium(Reacher):
    equilibrium_qpos = (0.0, 0.0)

class WrongTolerance(Reacher):
    convergence_tolerance = (0.1, 0.1, 0.1)

class ScalarReward(Reacher):
    def outcome(self, before, qpos, qvel, derived, action, xp=np):
        obs, reward, terminated = super().outcome(before, qpos, qvel, derived, action, xp)
        return obs, xp.sum(reward), terminated
'''


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_task_definition_is_one_line_before_anything_compiles(case, tmp_path, capsys):
    from gsa_jax.train import main as train_main

    (tmp_path / "bad_tasks.py").write_text(BAD_TASKS)
    name, message = BAD[case]
    name = name.replace("FILE", str(tmp_path / "bad_tasks.py"))
    assert train_main(["--env", name, "--physics", "c", "--out", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


def test_a_wrong_size_equilibrium_is_one_line_in_answer_and_verify_too(tmp_path, capsys):
    """The task train refuses (BAD's equilibrium_size) is refused by gsa answer before anything trains and by gsa
    verify for a controller that names it, each in one line (exit 2): the check is where every command loads a task."""
    from gsa_jax.commands.answer import main as answer_main
    from gsa_jax.commands.verify import main as verify_main

    (tmp_path / "bad_tasks.py").write_text(BAD_TASKS)
    name = f"{tmp_path / 'bad_tasks.py'}:WrongEquilibrium"
    ctrl = "experiments/your_task_reacher/results/controllers/examples.reacher.Reacher-mixture-K1-s3.npz"
    with np.load(ctrl) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays["config_json"]))
    meta["config"]["env"] = name
    np.savez(tmp_path / "c.npz", **{**arrays, "config_json": np.array(json.dumps(meta)), "task": np.array(name)})
    for main, argv in ((answer_main, ["--env", name, "--out", str(tmp_path / "answer")]),
                       (verify_main, [str(tmp_path / "c.npz"), "--quick", "--out", str(tmp_path / "verify")])):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "equilibrium_qpos has shape (2,)" in err, err
    assert not (tmp_path / "answer" / "answer.json").exists() and not (tmp_path / "verify").exists()


def test_register_names_a_task_for_library_users():
    """envs.register(name, factory): the name resolves, its sizes are the task's; built-in names are refused."""
    from examples.reacher import Reacher

    envs.register("my_reacher", Reacher)
    try:
        assert envs.action_size("my_reacher") == 2 and envs.default_episode_length("my_reacher") == 200
        assert envs.has_c_backend("my_reacher") and envs.resolve_task("my_reacher").name == "my_reacher"
        with pytest.raises(ValueError, match="built-in"):
            envs.register("Hopper-v5", Reacher)
    finally:
        envs.unregister("my_reacher")
    assert not envs.is_name("my_reacher")


def test_a_trainer_takes_a_task_object_and_trains_it_as_its_name_does():
    """trainer_for(cfg, task) with the Task class itself (no name registered): two iterations on backend 'c' equal,
    bit for bit, the run of the same class named 'module:Class'; a Config naming another task is one line."""
    from examples.reacher import Reacher

    from gsa_jax.algorithm.config import Config, make_hparams
    from gsa_jax.running.tasks import trainer_for

    small = dict(policy="mixture", k_max=2, num_envs=4, unroll_length=8, num_minibatches=2, num_epochs=1,
                 eval_envs=2, physics=Physics(backend="c"))
    key, hp = jax.random.PRNGKey(0), make_hparams(K=2)
    runs = []
    for cfg, task in ((Config(env="Reacher", **small), Reacher), (Config(env=TASK, **small), None)):
        tr = trainer_for(cfg, task)
        assert tr.cfg.episode_length == 200
        runs.append(jax.jit(tr.run_chunk, static_argnums=2)(tr.init(key, hp), hp, 2))
    for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="names env 'hopper' but the task given is 'Reacher'"):
        trainer_for(Config(env="hopper", **small), Reacher)
    mine = Reacher()  # an instance: every use gets its own copy (its own MjModel), the user's object stays as it was
    record = envs.resolve(mine)
    assert record.name == "Reacher" and record.new() is not mine and record.new().model is not mine.model


def test_tools_reading_a_user_tasks_controller_elsewhere_say_so_in_one_line(tmp_path):
    """deploy and robustness run where the task's module cannot be imported: one line naming it, exit 2."""
    ctrl = sorted(glob.glob(os.path.join(ROOT, "experiments", "your_task_reacher", "results", "controllers", "*mlp*.npz")))[0]
    for command in (["gsa_jax.deploy", ctrl], ["gsa_jax.robustness", ctrl, "--out", str(tmp_path / "rob")]):
        done = subprocess.run([sys.executable, "-m", *command], cwd=tmp_path, capture_output=True, text=True, timeout=300)
        err = done.stderr.strip()
        assert done.returncode == 2 and err.count("\n") == 0 and "cannot import 'examples.reacher'" in err, err


def test_a_module_named_envs_that_shadows_ours_is_refused(tmp_path):
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "__init__.py").write_text("")
    done = subprocess.run([sys.executable, "-c", "import gsa_jax"], cwd=tmp_path, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(tmp_path)}, timeout=120)
    assert done.returncode != 0 and "rename your own 'envs' module" in done.stderr, done.stderr


def test_a_brax_environment_trains_on_mjx_and_what_it_cannot_do_is_one_line(tmp_path, capsys):
    """'brax:reacher' (Brax's registry, MJX): 61k steps of K = 2 with 100-step episodes lift the training return from
    about -95 to above -60 (measured: -31.6); the controller exports; MuJoCo C deployment, backend 'c' and a
    misspelled name are one line each."""
    from gsa_jax.deploy import main as deploy_main
    from gsa_jax.export import main as export_main
    from gsa_jax.train import main as train_main

    run = tmp_path / "run"
    assert train_main(["--env", "brax:reacher", "--clusters", "2", "--steps", "61440", "--episode-length", "100",
                       "--out", str(run), "--quiet", "--no-tensorboard"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["result"]["final_episode_return"] > -60.0 and config["task"]["library"] == "brax", config["result"]
    assert export_main([str(run), "--out", str(tmp_path / "ctrl.npz")]) == 0
    capsys.readouterr()
    for command, message in ((lambda: deploy_main([str(tmp_path / "ctrl.npz")]), "no MuJoCo C version of 'brax:reacher'"),
                             (lambda: train_main(["--env", "brax:reacher", "--physics", "c", "--out", str(tmp_path / "c")]),
                              "another library's environments step in JAX only"),
                             (lambda: train_main(["--env", "brax:reachr", "--out", str(tmp_path / "x")]),
                              "did you mean brax:reacher?")):
        assert command() == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err


def test_a_playground_environment_trains_on_mjx(tmp_path):
    """'playground:CartpoleBalance' (MuJoCo Playground's registry, impl 'jax'): 123k steps of one linear controller
    with 200-step episodes lift the training return from about 100 to above 120 (measured: 132.6; the maximum is
    200); a misspelled name lists close matches."""
    from gsa_jax.train import main as train_main

    run = tmp_path / "run"
    assert train_main(["--env", "playground:CartpoleBalance", "--clusters", "1", "--steps", "122880", "--episode-length",
                       "200", "--out", str(run), "--quiet", "--no-tensorboard"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["result"]["final_episode_return"] > 120.0 and config["task"]["library"] == "playground", config["result"]
    with pytest.raises(ValueError, match="did you mean playground:CartpoleBalance"):
        envs.check_name("playground:CartpoleBalanse")


USER_ENVS = '''
from brax.envs import reacher
from mujoco_playground._src.dm_control_suite import cartpole


class MyReacher(reacher.Reacher):
    """Brax's reacher as a user's subclass (made with backend='mjx', as Brax's registry makes its own)."""


class MyBalance(cartpole.Balance):
    def __init__(self, config=cartpole.default_config(), config_overrides=None):
        super().__init__(swing_up=False, sparse=False, config=config, config_overrides=config_overrides)


class OnGeneralized(reacher.Reacher):
    def __init__(self):
        super().__init__(backend="generalized")
'''


@pytest.mark.parametrize("mine, theirs", [("MyReacher", "brax:reacher"), ("MyBalance", "playground:CartpoleBalance")])
def test_a_users_brax_or_playground_env_class_steps_as_the_librarys_own(mine, theirs, tmp_path):
    """A brax.envs.Env or Playground MjxEnv subclass named 'file.py:Class' (MJX): reset and 8 random steps equal, bit
    for bit, the library's registered environment it subclasses; its record names its file and sha256; one not on
    MJX and backend 'c' are one line each."""
    (tmp_path / "user_envs.py").write_text(USER_ENVS)
    name = f"{tmp_path / 'user_envs.py'}:{mine}"
    source = envs.task_source(name)
    assert source["builtin"] is False and source["class"] == mine and len(source["sha256"]) == 64, source

    def roll(env):
        def body(s, a):
            s = env.step(s, a)
            return s, (s.obs, s.reward, s.done)

        actions = jax.random.uniform(jax.random.PRNGKey(1), (8, env.action_size), minval=-1, maxval=1)
        s = env.reset(jax.random.PRNGKey(0))
        return s.obs, jax.lax.scan(body, s, actions)[1]

    got, want = (jax.jit(roll, static_argnums=0)(envs.make(n, episode_length=50)) for n in (name, theirs))
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="another library's environments step in JAX only"):
        envs.make_base(name, Physics(backend="c"))
    if mine == "MyReacher":
        with pytest.raises(ValueError, match="steps on MJX .* has backend 'generalized'"):
            envs.check_name(f"{tmp_path / 'user_envs.py'}:OnGeneralized")


def test_reset_mode_fresh_starts_every_episode_from_a_new_draw_and_first_from_the_first():
    """envs.make(..., reset_mode): with 'fresh' each of 4 envs' 6 episodes (5-step time limit, backend 'c') starts
    from a different target (the example draws its target at reset), and a run of 4 envs sees 24 targets; with
    'first' (Brax's convention, the default) every episode of an env restarts where its first did."""
    def targets(mode):
        env = envs.make(TASK, episode_length=5, physics=Physics(backend="c"), reset_mode=mode)
        s = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 4))

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, (s.obs[:, 4:6], s.done)  # the target's position, obs after any reset

        actions = jnp.zeros((30, 4, env.action_size))
        _, (obs, done) = jax.jit(lambda s, a: jax.lax.scan(body, s, a))(s, actions)
        first = np.asarray(s.obs[:, 4:6])
        return first, np.asarray(obs)[np.asarray(done) > 0.5].reshape(6, 4, 2)  # each env's 6 restarts

    first, restarts = targets("first")
    np.testing.assert_array_equal(restarts, np.broadcast_to(first, restarts.shape))
    first, restarts = targets("fresh")
    all_targets = np.concatenate([first[None], restarts]).reshape(-1, 2)
    assert len({t.tobytes() for t in all_targets}) == 28 and np.all(np.abs(all_targets) <= 0.14 + 1e-6)
    with pytest.raises(ValueError, match="reset mode must be one of first, fresh"):
        envs.make(TASK, reset_mode="again")
    from gsa_jax.algorithm.config import Config
    from gsa_jax.running.tasks import config_for

    with pytest.raises(ValueError, match="unknown reset_mode 'again'; choose one of first, fresh"):
        config_for(Config(env=TASK, reset_mode="again"))
