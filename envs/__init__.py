"""Tasks by name: `envs.make(name)` returns a single-env Brax environment (reset(key), step(state, action))
with a time limit and auto-reset; batch it with jax.vmap. A name is resolved once per process into its record
(`task_record(name)`, envs/registry.py), which holds everything about the task; the functions here read it.

Tasks: Brax's MJX variants of the gym MuJoCo benchmarks used in the paper's Figure 1 (BRAX_TASKS),
`allegro_cylinder`, our MJX port of the paper's Allegro-hand tactile task (envs/allegro.py), and every task
definition (envs/task.py): gymnasium's own v5 tasks (GYM_V5_TASKS, gymnasium's ids: envs/gym_v5.py), the
DeepMind Control Suite's (DMC_TASKS, 'dmc:<domain>-<task>': envs/dmc/, with dm_control installed), the
tasks registered with `register(name, factory)`, and a user's task named by where it is defined,
'my_pkg.my_module:MyTask' or 'path/to/file.py:MyTask'. A task definition runs on both backends (MJX:
envs/task_mjx.py; MuJoCo C in the program: envs/c_backend.py) and in plain MuJoCo C (envs.task.TaskC).
"""

import contextlib
import functools
import hashlib
import importlib
import importlib.util
import io
import os
import sys
import warnings

# No renderer is needed for training. mujoco picks its GL backend when it is first imported, so
# gsa_jax.render (which does need one) sets MUJOCO_GL itself unless the user did: nothing here imports
# mujoco before a function is called.
GL_FROM_USER = "MUJOCO_GL" in os.environ
os.environ.setdefault("MUJOCO_GL", "disable")

BRAX_TASKS = ("inverted_double_pendulum", "hopper", "halfcheetah", "walker2d", "ant")  # Brax's MJX variants
GYM_V5_TASKS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "InvertedDoublePendulum-v5")  # gymnasium's own: envs/gym_v5.py
from envs.dmc import NAMES as DMC_TASKS  # noqa: E402  (the DeepMind Control Suite's: envs/dmc/, 'dmc:<domain>-<task>')

NAMES = BRAX_TASKS + ("allegro_cylinder",) + GYM_V5_TASKS + DMC_TASKS
DEFAULT_EPISODE_LENGTH = 1000
# Every task's action bounds, per action: PPO clips its actions to them (training and evaluation,
# gsa_jax/algorithm/ppo.py) and an exported controller's act() does (gsa_jax/deployment/numpy_policy.py). They are
# the locomotion tasks' actuator ctrlrange and gymnasium's action_space (tests/test_export.py), and the range of
# allegro_cylinder's PD-target steps (envs/allegro.py).
ACTION_RANGE = (-1.0, 1.0)
RESET_MODES = ("first", "fresh")  # where an ended episode restarts (envs/wrappers.py's AutoReset)


_REGISTERED = {}  # name -> factory (a Task subclass, or a callable returning a Task)


def register(name: str, factory) -> None:
    """Make a task known by `name`: factory is a Task subclass (envs/task.py) or a callable returning a Task, or a
    brax.envs.Env or MuJoCo Playground MjxEnv subclass (MJX only). The name then works wherever a task name does
    (Config(env=name), --env name, experiment files) in this process; worker processes of a sweep do not run your registering code: name the task
    'module:Class' there."""
    if not isinstance(name, str) or not name or name in NAMES or ":" in name:
        raise ValueError(f"cannot register {name!r}: a task name is a non-empty string without ':' other than a "
                         "built-in task's")
    if not callable(factory):
        raise ValueError(f"register({name!r}, factory): factory must be a Task subclass or a callable returning a Task")
    _REGISTERED[name] = factory
    _record.cache_clear()


def unregister(name: str) -> None:
    """Forget a task registered with register(name, ...) (KeyError if there is none)."""
    del _REGISTERED[name]
    _record.cache_clear()


def task_record(name):
    """The record of task `name` (envs/registry.py): resolved and checked once per process; ValueError (one line)
    for a name that does not resolve. A TaskRecord is returned as it is; a Task instance or subclass
    (envs/task.py) becomes a record named for its class."""
    from envs import registry  # no JAX, no MuJoCo: a name's record imports what it needs when asked

    if isinstance(name, str):
        return _record(name)
    if isinstance(name, registry.TaskRecord):
        return name
    return registry.definition_record(name)


@functools.lru_cache(maxsize=None)
def _record(name):
    from envs import registry

    if not isinstance(name, str) or not name:
        raise ValueError(f"a task name is a non-empty string, got {name!r}")
    builtin = registry.builtin_records().get(name)
    if builtin is not None:
        return builtin(name)
    record = registry.adapted_record(name)
    if record is not None:
        return record
    if name.startswith("dmc:"):
        from envs import dmc

        dmc.task_class(name)  # the name is not one of them: ValueError listing those there are
    if name in _REGISTERED or ":" in name:
        return registry.user_record(name, _REGISTERED.get(name) or _import_factory(name))
    raise ValueError(f"unknown env {name!r}; choose one of {', '.join(NAMES + tuple(_REGISTERED))}, name your "
                     "own task definition 'module:Class', or another library's environment 'brax:<name>' or "
                     "'playground:<Name>' (docs/your_task.md)")


def is_name(name) -> bool:
    """Whether `name` names a task that resolves (no exception)."""
    try:
        check_name(name)
        return True
    except ValueError:
        return False


def check_name(name) -> None:
    """ValueError (one line) unless `name` names a task; a task definition is loaded and checked once here."""
    task_record(name)


def check_task(name) -> None:
    """check_name, and for a user's task definition its observation with jax.numpy equal to NumPy's (once per
    process; the trainer's edge: JAX is imported here)."""
    task_record(name).check_traced()


def resolve_task(name):
    """A new instance of the task definition (envs/task.py's Task) behind `name`, checked once per process
    (TaskError)."""
    from envs.registry import Definition

    record = task_record(name)
    if not isinstance(record, Definition):
        raise ValueError(f"{record.name!r} is not a task definition (envs/task.py) but a {record.family} task")
    return record.new()


def _import_factory(name):
    """The object 'module:attr' or 'path/file.py:attr' names (TaskError in one line if it cannot be had)."""
    from envs.task import TaskError

    module_name, _, attr = name.rpartition(":")
    if not module_name or not attr:
        raise TaskError(f"unknown env {name!r}; a task definition is named 'module:Class' or 'path/file.py:Class'")
    module = _import_module(module_name, name)
    if not hasattr(module, attr):
        import difflib

        from envs.task import Task

        found = [k for k, v in vars(module).items() if isinstance(v, type) and issubclass(v, Task) and v is not Task]
        close = difflib.get_close_matches(attr, found, n=3) or found
        raise TaskError(f"task {name!r}: {module_name} has no {attr!r}" + (f"; did you mean {', '.join(close)}?" if close else ""))
    return getattr(module, attr)


def _import_module(module_name, name):
    from envs.task import TaskError

    try:
        if module_name.endswith(".py"):
            if not os.path.exists(module_name):
                raise TaskError(f"task {name!r}: no file {module_name!r}")
            path = os.path.abspath(module_name)
            key = "gsa_jax_task_" + hashlib.sha256(path.encode()).hexdigest()[:16]  # one module per file
            if key in sys.modules:
                return sys.modules[key]
            spec = importlib.util.spec_from_file_location(key, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[key] = module
            spec.loader.exec_module(module)
            return module
        return _import_from_here(module_name)
    except TaskError:
        raise
    except ModuleNotFoundError as e:
        raise TaskError(f"task {name!r}: cannot import {module_name!r} ({e}); run from the directory that holds it, or "
                        "name its file: 'path/to/file.py:Class'") from None
    except Exception as e:
        raise TaskError(f"task {name!r}: importing {module_name!r} failed: {type(e).__name__}: {' '.join(str(e).split())}") from None


def _import_from_here(module_name):
    """importlib.import_module, also finding modules under the working directory (as `python -m` does) when it is
    not on sys.path, e.g. in a script run from elsewhere; sys.path is left as it was."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError:
        here = os.getcwd()
        if here in sys.path or "" in sys.path:
            raise
        sys.path.insert(0, here)
        try:
            return importlib.import_module(module_name)
        finally:
            sys.path.remove(here)


def task_source(name) -> dict:
    """What says which code defines task `name` (recorded in config.json and sweep.json): for a task defined
    outside this package, its module, file and the file's sha256; for another library's, its version."""
    return task_record(name).source()


def check_backend(name, physics) -> None:
    """ValueError if `physics` (envs.physics.Physics) cannot step task `name`."""
    record = task_record(name)
    physics.validate()
    record.check_physics(physics)


def has_c_backend(name) -> bool:
    """Whether MuJoCo C steps task `name` (backend 'c', deployment, evaluation and robustness)."""
    return task_record(name).has_c


def default_episode_length(name) -> int:
    """The task's own time limit (env steps)."""
    return int(task_record(name).episode_length())


def task_model(name):
    """The MuJoCo C model (MjModel) of a task's MJCF with the solver options its MJX version steps with
    (Brax's for the gym tasks), loaded without JAX or MJX (but for another library's environment, built once):
    for sizes and physics records. The record's own, shared by every caller: read it, never change it (a task to
    change, e.g. under a shift, comes from task_record(name).make_c())."""
    return task_record(name).model()


def action_size(name) -> int:
    """Actions of a task, read from its MJCF (no MJX environment is built, but for another library's environment)."""
    return int(task_model(name).nu)


def observation_size(name) -> int:
    """Observation values of task `name` as its definition is now (a task definition's observe(); else the length of
    its observation layout)."""
    from envs.registry import Definition

    record = task_record(name)
    if isinstance(record, Definition):
        return int(record.task().observation_size)
    return len(record.observation_layout())


def as_gymnasium(task):
    """A gymnasium.Env of `task` (a name, a Task subclass or instance) stepped by its MuJoCo C twin, with the task's
    start law, observation, reward, termination and time limit (envs/gymnasium_env.py); ValueError (one line) for a
    task MuJoCo C does not step. Needs gymnasium (the deploy extra)."""
    record = task_record(task)
    if not record.has_c:
        raise ValueError(f"task {record.name!r} has no MuJoCo C version, so no gymnasium environment: MuJoCo C runs "
                         "every task definition, Brax's hopper, walker2d, halfcheetah and ant, and allegro_cylinder")
    from envs.gymnasium_env import TaskEnv

    return TaskEnv(record)


def action_bounds(name, size=None):
    """(low [d_a], high [d_a]) float32: the bounds of task `name`'s d_a actions (ACTION_RANGE for each); size: d_a
    (default: action_size(name), read from the MJCF). A task with ctrl_range 'model' maps these actions onto its
    actuators' ctrlrange (control_range())."""
    import numpy as np

    task_record(name)
    size = action_size(name) if size is None else int(size)
    return np.full(size, ACTION_RANGE[0], np.float32), np.full(size, ACTION_RANGE[1], np.float32)


def control_range(name):
    """(low [nu], high [nu]) float64 a task maps its actions in ACTION_RANGE onto (envs/task.py's ctrl_range 'model':
    ctrl = low + (a + 1) (high - low) / 2), or None where the actions are the controls."""
    from envs.registry import Definition

    record = task_record(name)
    if not isinstance(record, Definition) or record.task().ctrl_range != "model":
        return None
    low, high = record.model().actuator_ctrlrange.T
    return low.copy(), high.copy()


def make_base(name, physics=None):
    """The unwrapped task (no time limit, no auto-reset) `name` (a name or a TaskRecord), stepped as `physics`
    says (envs.physics.Physics; None: the defaults, MJX; backend 'c': MuJoCo C, envs/c_backend.py). An MJX
    task's reset and step run inside physics.applied, so the solver routing holds while they are traced and
    nothing else in the process changes.

    physics.solver_iterations / ls_iterations override opt.iterations / opt.ls_iterations in the MJX
    model only -- a cheaper but *different* simulator; the MuJoCo C model (mj_model(env), used by
    deploy, render and the bench's reference) keeps the MJCF's settings.
    """
    from envs.physics import Physics

    physics = physics or Physics()
    record = task_record(name)
    check_backend(record, physics)
    if physics.backend == "c":
        return record.make_c_backend(physics)
    with warnings.catch_warnings(), _process_local_devices():
        warnings.simplefilter("ignore", UserWarning)  # brax's "not actively maintained" notice, once per env
        env = record.make_mjx()
    override = {k: v for k, v in (("opt.iterations", physics.solver_iterations),
                                  ("opt.ls_iterations", physics.ls_iterations)) if v is not None}
    if override:
        env.sys = env.sys.tree_replace(override)
    env.physics = physics
    for fn in ("reset", "step", "reset_where"):  # the solver is traced inside these
        if hasattr(env, fn):
            setattr(env, fn, _applying(getattr(env, fn), physics, mj_model(env)))
    return env


def _applying(fn, physics, model):
    from envs.physics import applied

    def traced(*args, **kwargs):
        with applied(physics, model):
            return fn(*args, **kwargs)

    return traced


def solver_settings(env):
    """Every physics option in force for a task made by make_base (envs.physics.record)."""
    from envs.physics import record

    return record(env.physics, mj_model(env))


@contextlib.contextmanager
def _process_local_devices():
    """mjx.put_model places the model on jax.devices()[0], which in a multi-process (jax.distributed) run
    is process 0's device; while an env is built, let jax.devices() name this process's devices."""
    import jax

    if jax.process_count() == 1:
        yield
        return
    original = jax.devices
    jax.devices = lambda backend=None: jax.local_devices(backend=backend)
    try:
        yield
    finally:
        jax.devices = original


def mj_model(env):
    """The MuJoCo C model (MjModel) behind a task made by make_base: ours or a Brax MJX env."""
    return env.mj_model if hasattr(env, "mj_model") else env.sys.mj_model


def substeps(env):
    """Physics steps per env step of a task made by make_base."""
    return int(getattr(env, "n_frames", None) or getattr(env, "_n_frames", 1))


def make(name, episode_length=None, auto_reset=True, physics=None, reset_mode="first", randomize=None):
    """Task `name` (a name or a TaskRecord) with a time limit of `episode_length` steps (default: the task's own,
    `default_episode_length(name)`) and (by default) auto-reset: an ended episode restarts from the env's first
    start state (reset_mode 'first', Brax's convention) or from a new draw of the task's start law ('fresh',
    as gymnasium and dm_control reset; envs/wrappers.py). physics: see make_base. randomize: a domain
    randomization (envs/randomize.py: its text, a table or a Randomize; None or '': none) drawn per episode
    (envs/randomized.py); RandomizeError (one line) where the task or backend cannot apply it.

    state.info: 'steps', 'truncation' (1 when the time limit, not a termination, ended the
    episode), and with auto_reset 'final_obs' (the true last observation of the step).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        from envs.wrappers import AutoReset, EpisodeLimit
    if episode_length is None:
        episode_length = default_episode_length(name)
    if episode_length < 1:
        raise ValueError(f"episode_length must be >= 1, got {episode_length}")
    spec = check_randomize(name, randomize, episode_length, physics)
    base = make_base(name, physics)
    env = EpisodeLimit(base, episode_length)
    env = AutoReset(env, reset_mode) if auto_reset else env
    if spec is None:
        return env
    from envs.randomized import Randomized

    return Randomized(env, base, spec)


def task_randomize(name) -> str:
    """The randomization a task definition declares (Task.randomize, envs/randomize.py's text); ValueError if none."""
    from envs.registry import Definition

    record = task_record(name)
    text = record.task().randomize if isinstance(record, Definition) else ""
    if not text:
        raise ValueError(f"task {record.name!r} declares no randomization (Task.randomize); give one, e.g. "
                         "randomize='mass=0.9:1.1, delay=1'")
    from envs.randomize import parse

    return parse(text).text()


def check_randomize(name, randomize, episode_length=None, physics=None):
    """The Randomize of `randomize` (envs/randomize.py) checked against task `name`'s model and the backend of
    `physics` (None: MJX), or None for none; RandomizeError (one line) for an unknown parameter, a range out of
    bounds, a delay as long as the episode, or model scales or pushes the backend cannot apply (saying which can).
    Builds no environment."""
    from envs.randomize import RandomizeError, check_model, parse

    spec = parse(randomize)
    if not spec.scales and spec.is_nominal:
        return None
    record = task_record(name)
    check_model(spec, record.model(), episode_length)
    if spec.registry:
        from envs.registry import PlaygroundAdapted

        if not isinstance(record, PlaygroundAdapted):
            raise RandomizeError(f"randomize: 'playground' (a Playground environment's own randomizer) applies to "
                                 f"playground:<Name> tasks, not {record.name!r}; give model scales instead")
        from envs.playground_adapter import domain_randomizer

        domain_randomizer(record.name)
    if spec.model_fields or spec.push:
        reason = _variant_reason(record, "mjx" if physics is None else physics.backend, spec)
        if reason:
            raise RandomizeError(f"randomize: {reason}; obs_noise and delay apply everywhere")
    return spec


def _variant_reason(record, backend, spec):
    """Why model scales or pushes cannot run for this task on this backend (None: they can)."""
    from envs.registry import BraxVariant, Definition, PlaygroundAdapted, UserEnv

    if backend == "c":
        task = record.task() if isinstance(record, Definition) else record.port() if isinstance(record, BraxVariant) else None
        if task is None or task.post_constraint:
            why = "its steps run mj_rnePostConstraint outside mujoco.batch" if task else "its host steps no variants"
            return (f"{record.name} takes no per-simulation model on backend 'c' ({why}); its model scales and pushes "
                    "run on MJX (--physics mjx)")
        return None
    if isinstance(record, (PlaygroundAdapted, UserEnv)):
        return f"{record.name} is not a Brax PipelineEnv; model scales and pushes apply to task definitions and Brax's envs"
    import dataclasses

    from mujoco import mjx

    have = {f.name for f in dataclasses.fields(mjx.Model)}
    missing = [f for f, _, _ in spec.model_fields if f not in have]
    if missing:
        return f"MJX's model has no field {missing[0]}; backend 'c' (--physics c) scales any float MjModel field"
    return None
