"""Physics backend 'c' (envs/c_backend.py): MuJoCo C stepped from inside the compiled program.

The simulation state equals mujoco.mj_step's bit for bit, per task and with contacts; observations
(the Allegro tactile values included), rewards and terminations equal the MuJoCo C ports'; a batch equals each env alone at any thread count;
a run in a sweep equals the run alone, and a stopped and resumed sweep (also a worker the watchdog killed with
SIGKILL and restarted) equals an uninterrupted one."""

import csv
import glob
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.c_hosts import STATE_SPEC, float64_rows
from envs.mujoco_c import C_TASKS, make_c
from envs.physics import Physics
from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.running.tasks import trainer_for
from gsa_jax.running.spec import load_spec
from gsa_jax.running.sweeps import SweepOptions, run_sweep
from gsa_jax.running.tasks import config_for

C = Physics(backend="c")


def mj_row(m, d):
    row = np.zeros(mujoco.mj_stateSize(m, STATE_SPEC))
    mujoco.mj_getState(m, d, row, STATE_SPEC)
    return row


def test_backend_runs_every_ported_task():
    """The Brax variants' and Allegro's MuJoCo C ports (here), gymnasium's v5 tasks (tests/test_gym_v5.py) and the
    DeepMind Control Suite's (tests/test_dmc.py): the records say so; Brax's inverted_double_pendulum has no port and
    is refused in one line."""
    assert {n for n in envs.NAMES if envs.has_c_backend(n)} == set(C_TASKS) | set(envs.GYM_V5_TASKS) | set(envs.DMC_TASKS)
    with pytest.raises(ValueError, match="backend 'c' does not step 'inverted_double_pendulum'"):
        envs.make_base("inverted_double_pendulum", C)


@pytest.mark.parametrize("name", C_TASKS)
def test_steps_equal_mj_step_bit_for_bit(name):
    """From the backend's reset state, 60 random actions (some outside [-1, 1]): every env step's
    mjSTATE_INTEGRATION row (qpos, qvel, solver warmstart, ctrl, time) equals mj_step's in float64, bit
    for bit; observation (Allegro: its tactile values too), reward and termination equal the MuJoCo C
    port's (float32 of the same values; Allegro's reward, computed in float32 in the program, to 1e-5)."""
    env = envs.make_base(name, C)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    task = make_c(name)
    m, d = task.model, task.data
    s = reset(jax.random.PRNGKey(1))
    n_mj = mujoco.mj_stateSize(m, STATE_SPEC)  # a row then carries the task's `before` values (TaskHost)
    mujoco.mj_setState(m, d, float64_rows(s.pipeline_state.rows)[:n_mj], STATE_SPEC)
    mujoco.mj_forward(m, d)
    np.testing.assert_array_equal(np.asarray(s.obs), task.observe().astype(np.float32))
    rng, contacts, touch = np.random.default_rng(0), 0, 0.0
    for t in range(60):
        a = rng.uniform(-1.2, 1.2, env.action_size).astype(np.float32)
        s = step(s, jnp.asarray(a))
        obs, r, done = task.step(a)
        contacts += d.ncon
        touch += float(np.sum(obs[8:])) if name == "allegro_cylinder" else 0.0
        np.testing.assert_array_equal(float64_rows(s.pipeline_state.rows)[:n_mj], mj_row(m, d), err_msg=f"step {t}")
        np.testing.assert_array_equal(np.asarray(s.obs), obs.astype(np.float32), err_msg=f"step {t}")
        assert float(s.reward) == np.float32(r) if name != "allegro_cylinder" else abs(float(s.reward) - r) <= 1e-5 * max(1.0, abs(r)), (t, float(s.reward), r)
        assert bool(s.done > 0.5) == done
        if done:
            break
    assert contacts > 0  # feet on the floor, fingers on the cylinder: the contact solver is compared too
    assert name != "allegro_cylinder" or touch > 1.0  # the tactile values compared are not all zero


@pytest.fixture(scope="module")
def hopper_batch():
    """vmapped reset and step of the hopper at 1 and 2 threads."""
    fns = {}
    for threads in (1, 2):
        env = envs.make_base("hopper", Physics(backend="c", threads=threads))
        fns[threads] = env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    return fns


def rollout_rows(reset, step, keys, actions):
    s = reset(keys)
    for a in actions:
        s = step(s, a)
    return np.asarray(s.pipeline_state.rows), np.asarray(s.obs)


def test_batch_equals_each_env_alone_at_any_thread_count(hopper_batch):
    env, reset, step = hopper_batch[1]
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (20, 5, env.action_size), minval=-1, maxval=1)
    rows, obs = rollout_rows(reset, step, keys, actions)
    for i in range(5):
        alone, alone_obs = rollout_rows(jax.jit(env.reset), jax.jit(env.step), keys[i], actions[:, i])
        np.testing.assert_array_equal(rows[i], alone)
        np.testing.assert_array_equal(obs[i], alone_obs)
    _, reset2, step2 = hopper_batch[2]
    np.testing.assert_array_equal(rollout_rows(reset2, step2, keys, actions)[0], rows)
    assert len({r.tobytes() for r in rows}) == 5


@pytest.mark.parametrize("kwargs, message", [
    ({"env": "inverted_double_pendulum", "physics": {"backend": "c"}}, "backend 'c' does not step 'inverted_double_pendulum'"),
    ({"env": "hopper", "physics": {"backend": "bullet"}}, "backend must be one of mjx, c"),
    ({"env": "hopper", "physics": {"backend": "c", "threads": -1}}, "threads must be an integer >= 0"),
    ({"env": "hopper", "physics": {"backend": "c", "solver_iterations": 2}}, "change MJX's model only"),
    ({"env": "hopper", "physics": {"backed": "c"}}, "unknown physics option 'backed'"),
])
def test_bad_physics_options_are_refused_before_compiling(kwargs, message):
    with pytest.raises(ValueError, match=message):
        config_for(Config(**kwargs))


def test_cli_physics_flag_errors_in_one_line():
    out = subprocess.run([sys.executable, "-m", "gsa_jax.train", "--env", "inverted_double_pendulum", "--physics", "c"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    lines = [ln for ln in out.stderr.strip().splitlines() if ln.strip()]
    assert "--physics" in lines[-1] and "inverted_double_pendulum" in lines[-1]


SMALL = {"num_envs": 8, "unroll_length": 32, "num_minibatches": 4, "num_epochs": 2, "episode_length": 100, "eval_envs": 4}
SPEC = f"""
name = "c_tiny"
envs = ["{{env}}"]
policies = ["mixture"]
clusters = [1, 2]
seeds = [0, 1]
steps = 1024
chunk = 2
eval_every = 2
[config]
{chr(10).join(f"{k} = {v}" for k, v in SMALL.items())}
[config.physics]
backend = "c"
"""


def read_rows(path):
    with open(path) as f:
        return sorted(csv.DictReader(f), key=lambda r: (int(r["K"]), int(r["seed"]), int(r["iteration"])))


def tiny_sweep(tmp_path_factory, env):
    """The tiny backend-'c' sweep of `env`, uninterrupted, in this process: (spec file, out)."""
    spec_file = tmp_path_factory.mktemp("spec") / "c_tiny.toml"
    spec_file.write_text(SPEC.format(env=env))
    out = tmp_path_factory.mktemp("sweep") / "ref"
    assert run_sweep(load_spec(str(spec_file)), str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), quiet=True))
    return spec_file, out


@pytest.fixture(scope="module")
def c_sweep(tmp_path_factory):
    return tiny_sweep(tmp_path_factory, "hopper")


@pytest.fixture(scope="module")
def v5_sweep(tmp_path_factory):
    """gymnasium's Hopper-v5 (envs/v5_tasks.py) in the same sweep."""
    return tiny_sweep(tmp_path_factory, "Hopper-v5")


@pytest.fixture(scope="module")
def user_sweep(tmp_path_factory):
    """A task defined outside the package (examples/reacher.py, named 'module:Class') in the same sweep."""
    return tiny_sweep(tmp_path_factory, USER_TASK)


USER_TASK = "examples.reacher:Reacher"


@pytest.mark.parametrize("sweep, env", [("c_sweep", "hopper"), ("v5_sweep", "Hopper-v5"), ("user_sweep", USER_TASK)])
def test_sweep_records_the_backend_and_its_run_equals_the_run_alone(sweep, env, request):
    _, out = request.getfixturevalue(sweep)
    from gsa_jax.running.trained import path_part

    physics = json.loads((out / "sweep.json").read_text())["physics"][f"{path_part(env)}-mixture"]
    assert physics["backend"] == "c" and physics["linesearch_in_force"] == "mujoco_c"
    rows = [r for r in read_rows(out / "metrics.csv") if r["K"] == "2" and r["seed"] == "1"]
    tr = trainer_for(Config(env=env, policy="mixture", k_max=2, physics=Physics(backend="c"), **SMALL))
    hp = make_hparams(K=2, total_iterations=4)
    _, m = jax.jit(tr.run_chunk, static_argnums=2)(jax.jit(tr.init)(jax.random.PRNGKey(1), hp), hp, 2)
    for col in ("episode_return", "episodes", "policy_loss", "value_loss", "approx_kl"):
        got = np.array([float(r[col]) if r[col] != "" else np.nan for r in rows[:2]])  # "": no episode ended
        np.testing.assert_allclose(got, np.asarray(m[col], np.float64), rtol=2e-3, atol=1e-5, err_msg=col)


def compare_rows(a, b):
    """Two sweeps' metrics.csv rows: the same runs and iterations, and the same numbers bit for bit."""
    assert [(r["K"], r["seed"], r["iteration"]) for r in a] == [(r["K"], r["seed"], r["iteration"]) for r in b]
    for col in ("episode_return", "policy_loss", "value_loss", "eval_return"):
        assert [r[col] for r in a] == [r[col] for r in b], col


@pytest.mark.parametrize("sweep", ["c_sweep", "v5_sweep", "user_sweep"])
def test_stopped_and_resumed_sweep_equals_uninterrupted(sweep, tmp_path, request):
    spec_file, ref = request.getfixturevalue(sweep)
    out = tmp_path / "resumed"
    spec = load_spec(str(spec_file))
    assert not run_sweep(spec, str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), quiet=True, stop_after_chunks=1))
    assert run_sweep(spec, str(out), SweepOptions(devices=tuple(jax.local_devices()[:1]), quiet=True))
    compare_rows(read_rows(ref / "metrics.csv"), read_rows(out / "metrics.csv"))
    assert len(glob.glob(str(out / "groups" / "*" / "DONE"))) == 1


def test_watchdog_kills_a_stalled_worker_and_its_restart_equals_uninterrupted(c_sweep, tmp_path):
    """A backend-'c' worker that stalls after its 1st chunk (tests/hang_worker.py; MuJoCo C's threads in it) is
    killed with SIGKILL by the watchdog and restarted from its checkpoint: the sweep equals the uninterrupted one."""
    from hang_worker import supervise_stalling_worker

    spec_file, ref = c_sweep
    out = tmp_path / "stalled"
    out.mkdir()
    code, lines = supervise_stalling_worker(1, tmp_path / "hung_once", spec_file, out)
    assert code == 0
    assert any("watchdog: worker 0 made no progress" in line for line in lines), lines
    assert (tmp_path / "hung_once").exists()
    compare_rows(read_rows(ref / "metrics.csv"), read_rows(out / "metrics.csv"))


def test_threads_zero_takes_this_process_share_of_the_cores(monkeypatch):
    """Backend 'c' threads 0: the cores this process may run on, divided among the local workers a sweep
    started (supervise.worker_env says how many); an explicit count is kept."""
    from envs.physics import LOCAL_WORKERS_ENV, resolve_threads
    from gsa_jax.running.supervise import worker_env

    monkeypatch.setattr("os.sched_getaffinity", lambda pid: set(range(8)), raising=False)
    monkeypatch.delenv(LOCAL_WORKERS_ENV, raising=False)
    assert resolve_threads(0) == 8 and resolve_threads(3) == 3
    for workers, share in ((2, 4), (3, 2), (8, 1), (16, 1)):
        monkeypatch.setenv(LOCAL_WORKERS_ENV, worker_env(workers)[LOCAL_WORKERS_ENV])
        assert resolve_threads(0) == share


def test_host_seconds_count_the_calls_and_the_time_inside_mujoco_c():
    """host_seconds(): every host call is counted once, with its seconds inside MuJoCo C a part of its seconds
    in the host function, summed over the process's live hosts (what gsa_jax.bench splits a sweep with)."""
    from envs.c_hosts import TaskHost, host_seconds
    from envs.mujoco_c import BRAX_PORTS

    port = BRAX_PORTS["hopper"]()
    host = TaskHost(port, threads=1)
    before = host_seconds()
    rows, *_ = host.reset(np.zeros((4, port.model.nq), np.float32), np.zeros((4, port.model.nv), np.float32))
    for _ in range(3):
        rows, *_ = host.step(np.ascontiguousarray(rows), np.zeros((4, port.model.nu), np.float32))
    after = host_seconds()
    assert host.clock["calls"] == 4 and after["calls"] - before["calls"] == 4
    assert 0 < host.clock["mujoco_c_s"] <= host.clock["host_s"]
    assert after["host_s"] - before["host_s"] == pytest.approx(host.clock["host_s"])


# a process that rolls out a few steps of backend 'c' hopper (2 envs, auto-reset) as one compiled program, with
# JAX's persistent cache in argv[1], and reports the cache hits of that program, its outputs' hash and which of Brax,
# Flax and MJX it imported (with the modules a sweep worker and a training run import)
CACHED_PROGRAM = """
import hashlib, json, sys
import jax, numpy as np
from jax._src import monitoring
import envs
import gsa_jax.running.driver, gsa_jax.orchestration.sweep_job
from envs.physics import Physics
from gsa_jax.running import xla_cache

events = []
monitoring.register_event_listener(lambda name, **kw: events.append(name))
xla_cache.enable(sys.argv[1], min_compile_s=0)
env = envs.make("hopper", physics=Physics(backend="c"), episode_length=3)

def rollout(keys, actions):
    state, rewards = jax.vmap(env.reset)(keys), []
    for a in actions:
        state = jax.vmap(env.step)(state, a)
        rewards.append(state.reward)
    return state.pipeline_state.rows, state.obs, rewards

keys = jax.random.split(jax.random.PRNGKey(0), 2)
actions = np.random.default_rng(0).uniform(-1, 1, (5, 2, env.action_size)).astype(np.float32)
lowered = jax.jit(rollout).lower(keys, actions)
hits = events.count("/jax/compilation_cache/cache_hits")
out = jax.tree.leaves(lowered.compile()(keys, actions))
digest = hashlib.sha256(b"".join(np.asarray(x).tobytes() for x in out)).hexdigest()
heavy = sorted({m.split(".")[0] if m != "mujoco.mjx" else m for m in sys.modules if m.startswith(("brax", "flax", "mujoco.mjx"))})
print(json.dumps({"hits": events.count("/jax/compilation_cache/cache_hits") - hits, "digest": digest, "heavy": heavy}))
"""


def test_cached_program_loads_in_a_new_process_and_computes_the_same(tmp_path):
    """A backend-'c' program holds no Python callback (envs/host_call.py): a second process with the same program
    loads it from the persistent cache, quietly, and its host calls step that process's MuJoCo C to the same bits.
    Neither process imports Brax or MJX (envs/interface.py): seconds of every 'c' worker's start."""
    script = tmp_path / "program.py"
    script.write_text(CACHED_PROGRAM)

    def run():
        out = subprocess.run([sys.executable, str(script), str(tmp_path / "cache")], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "PYTHONPATH": os.getcwd()})
        assert out.returncode == 0, out.stderr[-2000:]
        assert "cpu_aot_loader" not in out.stderr
        return json.loads(out.stdout.strip().splitlines()[-1])

    first, second = run(), run()
    assert first["hits"] == 0 and second["hits"] == 1
    assert second["digest"] == first["digest"]
    assert first["heavy"] == [] and second["heavy"] == []


def test_the_c_state_flattens_as_brax_state_does():
    """envs.interface.State has Brax's fields in Brax's order and the same leaf paths, so a checkpoint's keys
    (gsa_jax.running.checkpoint: keystr of each leaf) are the same whichever State a run carried."""
    from brax.envs.base import State as BraxState

    from envs.interface import State

    fields = dict(pipeline_state={"q": jnp.zeros(2)}, obs=jnp.ones(3), reward=jnp.zeros(()), done=jnp.zeros(()),
                  metrics={"m": jnp.ones(())}, info={"steps": jnp.zeros((), jnp.int32)})
    ours, theirs = jax.tree_util.tree_flatten_with_path(State(**fields)), jax.tree_util.tree_flatten_with_path(BraxState(**fields))
    assert [jax.tree_util.keystr(p) for p, _ in ours[0]] == [jax.tree_util.keystr(p) for p, _ in theirs[0]]
    assert State(**fields).replace(obs=jnp.zeros(3)).obs.sum() == 0
