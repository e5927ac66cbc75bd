"""Environment registry: `envs.make(name)` returns a single-env Brax environment (reset(key), step(state, action))
with a time limit and auto-reset; batch it with jax.vmap.

Tasks: Brax's MJX variants of the gym MuJoCo benchmarks used in the paper's Figure 1 (BRAX_TASKS),
`allegro_cylinder`, our MJX port of the paper's Allegro-hand tactile task (envs/allegro.py), and every task
definition (envs/task.py): gymnasium's own v5 tasks (GYM_V5_TASKS, gymnasium's ids: envs/gym_v5.py), the
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
NAMES = BRAX_TASKS + ("allegro_cylinder",) + GYM_V5_TASKS
DEFAULT_EPISODE_LENGTH = 1000
C_BACKEND_TASKS = ("hopper", "walker2d", "halfcheetah", "ant", "allegro_cylinder") + GYM_V5_TASKS  # physics backend 'c'
# Every task's action bounds, per action: PPO clips its actions to them (training and evaluation,
# gsa_jax/algorithm/ppo.py) and an exported controller's act() does (gsa_jax/deployment/numpy_policy.py). They are
# the locomotion tasks' actuator ctrlrange and gymnasium's action_space (tests/test_export.py), and the range of
# allegro_cylinder's PD-target steps (envs/allegro.py).
ACTION_RANGE = (-1.0, 1.0)


_REGISTERED = {}  # name -> factory (a Task subclass, or a callable returning a Task)


def register(name, factory):
    """Make a task definition (envs/task.py) known by `name`: factory is a Task subclass or a callable returning
    a Task. The name then works wherever a task name does (Config(env=name), --env name, experiment files) in
    this process; worker processes of a sweep do not run your registering code: name the task
    'module:Class' there."""
    if not isinstance(name, str) or not name or name in NAMES:
        raise ValueError(f"cannot register {name!r}: a task name is a non-empty string other than a built-in task's")
    if not callable(factory):
        raise ValueError(f"register({name!r}, factory): factory must be a Task subclass or a callable returning a Task")
    _REGISTERED[name] = factory
    _factory.cache_clear()
    check_task.cache_clear()


ADAPTERS = ("brax:", "playground:")  # environments of other libraries, '<library>:<their name>' (MJX backend)


def is_adapted(name):
    """Whether `name` names another library's environment: 'brax:<name>' (Brax's registry) or 'playground:<Name>'
    (MuJoCo Playground's, envs/playground_adapter.py), both on MJX."""
    return isinstance(name, str) and name.startswith(ADAPTERS)


def is_defined(name):
    """Whether `name` names a task definition (envs/task.py): a v5 task, a registered one, or 'module:Class'."""
    return name in GYM_V5_TASKS or name in _REGISTERED or (isinstance(name, str) and ":" in name and not is_adapted(name))


def is_name(name):
    """Whether `name` names a task that resolves (no exception)."""
    try:
        check_name(name)
        return True
    except ValueError:
        return False


def check_name(name):
    """ValueError (one line) unless `name` names a task; a task definition is loaded and checked once here."""
    if name in NAMES and not is_defined(name):
        return
    if is_adapted(name):
        _check_adapted_name(name)
        return
    if is_defined(name):
        _factory(name)
        return
    raise ValueError(f"unknown env {name!r}; choose one of {', '.join(NAMES + tuple(_REGISTERED))}, name your "
                     "own task definition 'module:Class', or another library's environment 'brax:<name>' or "
                     "'playground:<Name>' (docs/your_task.md)")


@functools.lru_cache(maxsize=None)
def _check_adapted_name(name):
    """ValueError (one line, with close matches) unless 'brax:<name>' is in Brax's environment registry or
    'playground:<Name>' in MuJoCo Playground's."""
    import difflib

    if name.startswith("playground:"):
        from envs import playground_adapter

        playground_adapter.check_name(name)
        return

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        from brax import envs as brax_envs
    known = sorted(brax_envs._envs)
    sub = name[len("brax:"):]
    if sub not in known:
        close = difflib.get_close_matches(sub, known, n=3)
        raise ValueError(f"unknown env {name!r}: Brax registers {', '.join(known)}"
                         + (f"; did you mean {', '.join('brax:' + c for c in close)}?" if close else ""))


@functools.lru_cache(maxsize=None)
def check_task(name):
    """check_name, and for a task definition its observation with jax.numpy equal to NumPy's (once per process;
    the trainer's edge: JAX is imported here)."""
    check_name(name)
    if is_defined(name) and name not in GYM_V5_TASKS:
        from envs.task import check_jax_agrees

        check_jax_agrees(resolve_task(name), f"task {name!r}")


def resolve_task(name):
    """A new instance of the task definition `name` (envs/task.py), checked once per process (TaskError)."""
    factory = _factory(name)
    task = factory()
    task.name = name
    return task


@functools.lru_cache(maxsize=None)
def _factory(name):
    """The checked factory of a task definition: built-in, registered, or imported from 'module:Class'."""
    from envs.task import Task, TaskError, validate

    if name in GYM_V5_TASKS:
        from envs import gym_v5

        return gym_v5.V5_TASKS[name]
    factory = _REGISTERED.get(name) or _import_factory(name)
    try:
        task = factory()
    except TaskError:
        raise
    except Exception as e:  # a user's constructor: its error in one line
        raise TaskError(f"task {name!r}: making it failed: {type(e).__name__}: {' '.join(str(e).split())}") from None
    if not isinstance(task, Task):
        raise TaskError(f"task {name!r}: {factory!r} gave a {type(task).__name__}, not an envs.task.Task")
    validate(task, f"task {name!r}")
    return factory


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


def task_source(name):
    """What says which code defines task `name` (recorded in config.json and sweep.json): for a task defined
    outside this package, its module, file and the file's sha256."""
    if is_adapted(name):
        library, _, theirs = name.partition(":")
        return {"task": name, "builtin": False, "library": library, "name": theirs, "action_size": action_size(name),
                "version": _installed_version("playground" if library == "playground" else "brax")}
    if not is_defined(name) or name in GYM_V5_TASKS:
        return {"task": name, "builtin": True}
    from envs.task import source_record

    task = resolve_task(name)
    return {"task": name, "builtin": False, **source_record(type(task)), "action_size": int(task.model.nu),
            "observation_size": int(task.observation_size)}


def _installed_version(dist):
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def check_backend(name, physics):
    """ValueError if `physics` (envs.physics.Physics) cannot step task `name`."""
    check_name(name)
    physics.validate()
    if physics.backend == "c" and not has_c_backend(name):
        raise ValueError(f"physics backend 'c' runs {', '.join(C_BACKEND_TASKS)} and every task definition; {name!r} "
                         "runs on backend 'mjx'" + (" (another library's environments step in JAX only)" if is_adapted(name) else ""))
    if name.startswith("playground:") and (physics.solver_iterations is not None or physics.ls_iterations is not None):
        raise ValueError(f"{name!r} runs with Playground's own solver settings; solver_iterations and ls_iterations "
                         "do not apply")


def has_c_backend(name):
    """Whether MuJoCo C steps task `name` (backend 'c', deployment, evaluation and robustness)."""
    return name in C_BACKEND_TASKS or is_defined(name)


def default_episode_length(name):
    check_name(name)
    if name == "allegro_cylinder":
        from envs.allegro_task import DEFAULT_EPISODE_LENGTH as allegro_length  # 2 s at 100 Hz; no JAX import

        return allegro_length
    if is_defined(name):
        return int(resolve_task(name).episode_length)
    if name.startswith("playground:"):
        from envs.playground_adapter import registry

        return int(registry().get_default_config(name[len("playground:"):]).get("episode_length", DEFAULT_EPISODE_LENGTH))
    return DEFAULT_EPISODE_LENGTH


def task_model(name):
    """The MuJoCo C model (MjModel) of a task's MJCF with the solver options its MJX version steps with
    (Brax's for the gym tasks), loaded without JAX or MJX: for sizes and physics records."""
    import mujoco

    from envs import mujoco_c

    check_name(name)
    if is_defined(name):
        return resolve_task(name).model
    if is_adapted(name):
        return _adapted_model(name)
    if name in mujoco_c.C_TASKS:
        return mujoco_c.make_c(name).model
    return mujoco.MjModel.from_xml_path(mujoco_c.brax_asset(name + ".xml"))


@functools.lru_cache(maxsize=None)
def _adapted_model(name):
    """The MjModel of another library's environment: building it builds the environment (seconds), so once per
    process (callers read sizes and records from it)."""
    return mj_model(make_base(name))


def action_size(name):
    """Actions of a task, read from its MJCF (no MJX environment is built, but for another library's environment)."""
    return int(task_model(name).nu)


def action_bounds(name, size=None):
    """(low [d_a], high [d_a]) float32: the bounds of task `name`'s d_a actions (ACTION_RANGE for each); size: d_a
    (default: action_size(name), read from the MJCF)."""
    import numpy as np

    if name not in NAMES and not (is_adapted(name) and size is not None):
        check_name(name)  # a task definition: loaded and checked (a built-in name needs neither)
    size = action_size(name) if size is None else int(size)
    return np.full(size, ACTION_RANGE[0], np.float32), np.full(size, ACTION_RANGE[1], np.float32)


def make_base(name, physics=None):
    """The unwrapped task (no time limit, no auto-reset), stepped as `physics` says (envs.physics.Physics;
    None: the defaults, MJX; backend 'c': MuJoCo C, envs/c_backend.py). An MJX task's reset and step run
    inside physics.applied, so the solver routing holds while they are traced and nothing else in the
    process changes.

    physics.solver_iterations / ls_iterations override opt.iterations / opt.ls_iterations in the MJX
    model only -- a cheaper but *different* simulator; the MuJoCo C model (mj_model(env), used by
    deploy, render and the bench's reference) keeps the MJCF's settings.
    """
    from envs.physics import Physics

    physics = physics or Physics()
    check_backend(name, physics)
    if physics.backend == "c":
        return _make_c_backend(name, physics)
    with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints "Failed to import warp" (a GPU-only backend)
        from brax import envs as brax_envs

        from envs import allegro
    with warnings.catch_warnings(), _process_local_devices():
        warnings.simplefilter("ignore", UserWarning)  # brax's "not actively maintained" notice, once per env
        if name == "allegro_cylinder":
            env = allegro.AllegroCylinder()
        elif is_defined(name):
            from envs.task_mjx import TaskMjx

            env = TaskMjx(resolve_task(name))
        elif name.startswith("playground:"):
            from envs.playground_adapter import PlaygroundEnv

            env = PlaygroundEnv(name)
        elif is_adapted(name):
            env = brax_envs.get_environment(name[len("brax:"):], backend="mjx")
        else:
            env = brax_envs.get_environment(name, backend="mjx")
    override = {k: v for k, v in (("opt.iterations", physics.solver_iterations),
                                  ("opt.ls_iterations", physics.ls_iterations)) if v is not None}
    if override:
        env.sys = env.sys.tree_replace(override)
    env.physics = physics
    for fn in ("reset", "step"):  # the solver is traced inside these
        setattr(env, fn, _applying(getattr(env, fn), physics, mj_model(env)))
    return env


def _make_c_backend(name, physics):
    """The task stepped by MuJoCo C inside the program (envs/c_backend.py)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from envs.c_backend import make_task
    return make_task(name, physics)


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


def make(name, episode_length=None, auto_reset=True, physics=None):
    """Task `name` with a time limit of `episode_length` steps (default: the task's own,
    `default_episode_length(name)`) and (by default) Brax-style auto-reset. physics: see make_base.

    state.info: 'steps', 'truncation' (1 when the time limit, not a termination, ended the
    episode), and with auto_reset 'final_obs' (the true last observation of the step).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        from envs.wrappers import AutoReset, EpisodeLimit
    if episode_length is None:
        episode_length = default_episode_length(name)
    if episode_length < 1:
        raise ValueError(f"episode_length must be >= 1, got {episode_length}")
    env = EpisodeLimit(make_base(name, physics), episode_length)
    return AutoReset(env) if auto_reset else env
