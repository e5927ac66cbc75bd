"""The task registry: the one way from a task's name to its record (envs/families/: one module per family).

    record = resolve("Hopper-v5")                    # resolved and checked once per process
    record.episode_length(), record.model()          # the time limit; the MjModel (no JAX, no MJX)
    record.make_mjx(), record.make_c_backend(physics)   # the unwrapped env on MJX / MuJoCo C in the program
    record.make_c()                                  # plain MuJoCo C (deployment, evaluation, robustness)

A name resolves to a record of one family: a built-in name through its family's ENTRIES, another library's
environment through its family's PREFIX ('brax:<name>', 'playground:<Name>'), a registered or 'module:Class' name
to a task definition or a user's environment class. Adding a family is one module in envs/families/ and its entry
here. The functions at the end answer what a task's name says (sizes, bounds, time limit, source) through its record,
for the command layer. This module loads without JAX and without MuJoCo (`import envs` must not load MuJoCo: the
renderer picks MUJOCO_GL after it).
"""

import difflib
import functools
import hashlib
import importlib
import importlib.util
import os
import sys
from typing import Any, Callable, Optional

from envs import dmc
from envs.families import allegro_cylinder, brax_library, brax_variant, playground, task_definition
from envs.families.task_definition import Definition, definition_record
from envs.families.record import TaskRecord, mujoco_side
from envs.families.user_env import UserEnv, library_of
from envs.names import NAMES
from envs.randomization import parse as parse_randomize

TaskLike = Any  # a task's name, its TaskRecord, or a Task instance or subclass (envs/task.py): what resolve() takes

BUILTIN = {**brax_variant.ENTRIES, **allegro_cylinder.ENTRIES, **task_definition.ENTRIES}  # name -> record factory
ADAPTERS = {brax_library.PREFIX: brax_library.BraxAdapted, playground.PREFIX: playground.PlaygroundAdapted}


def user_record(name: str, factory: Callable[..., Any]) -> TaskRecord:
    """The checked record of a user's task `name` made by `factory`: a task definition (envs/task.py), or a Brax or
    Playground environment class (UserEnv)."""
    library = library_of(factory)
    record = UserEnv(name, factory, library) if library else Definition(name, factory)
    record.check()
    return record


@functools.lru_cache(maxsize=None)
def adapted_record(name: str) -> Optional[TaskRecord]:
    """The checked record of 'brax:<name>' / 'playground:<Name>', or None if `name` has no adapter prefix."""
    for prefix, cls in ADAPTERS.items():
        if name.startswith(prefix):
            record = cls(name)
            record.check()
            return record
    return None


# Resolution: a name (or a Task, or a record) to its record, once per process.

_REGISTERED = {}  # name -> factory (a Task subclass, or a callable returning a Task)


def resolve(task: TaskLike) -> TaskRecord:
    """The record of `task`: a name (resolved and checked once per process; ValueError in one line for a name that
    does not resolve), a TaskRecord (returned as it is), or a Task instance or subclass (envs/task.py: a record
    named for its class). The one way from a task's name to its record; everything else asks it."""
    if isinstance(task, str):
        return _record(task)
    if isinstance(task, TaskRecord):
        return task
    return definition_record(task)


@functools.lru_cache(maxsize=None)
def _record(name):
    if not isinstance(name, str) or not name:
        raise ValueError(f"a task name is a non-empty string, got {name!r}")
    builtin = BUILTIN.get(name)
    if builtin is not None:
        return builtin(name)
    record = adapted_record(name)
    if record is not None:
        return record
    if name.startswith("dmc:"):
        dmc.task_class(name)  # the name is not one of them: ValueError listing those there are
    if name in _REGISTERED or ":" in name:
        return user_record(name, _REGISTERED.get(name) or _import_factory(name))
    TaskError = mujoco_side().task.TaskError
    if name.endswith(".py") or "/" in name or "." in name:  # a file or module without the class it defines
        raise TaskError(f"unknown env {name!r}: name the task class it defines, 'path/file.py:Class' or 'module:Class' "
                        "(docs/your_task.md)")
    raise TaskError(f"unknown env {name!r}; choose one of {', '.join(NAMES + tuple(_REGISTERED))}, name your "
                     "own task definition 'module:Class', or another library's environment 'brax:<name>' or "
                     "'playground:<Name>' (docs/your_task.md)")


def register(name: str, factory: Callable[[], Any]) -> None:
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


def _import_factory(name):
    """The object 'module:attr' or 'path/file.py:attr' names (TaskError in one line if it cannot be had)."""
    TaskError = mujoco_side().task.TaskError
    module_name, _, attr = name.rpartition(":")
    if not module_name or not attr:
        raise TaskError(f"unknown env {name!r}; a task definition is named 'module:Class' or 'path/file.py:Class'")
    module = _import_module(module_name, name)
    if not hasattr(module, attr):
        Task = mujoco_side().task.Task
        found = [k for k, v in vars(module).items() if isinstance(v, type) and issubclass(v, Task) and v is not Task]
        close = difflib.get_close_matches(attr, found, n=3) or found
        raise TaskError(f"task {name!r}: {module_name} has no {attr!r}" + (f"; did you mean {', '.join(close)}?" if close else ""))
    return getattr(module, attr)


def _import_module(module_name, name):
    TaskError = mujoco_side().task.TaskError
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


# What a task's name says, read from its record (no environment is built): for the command layer.

def is_name(name: TaskLike) -> bool:
    """Whether `name` names a task that resolves (no exception)."""
    try:
        check_name(name)
        return True
    except ValueError:
        return False


def check_name(name: TaskLike) -> None:
    """ValueError (one line) unless `name` names a task; a task definition is loaded and checked once here."""
    resolve(name)


def check_task(name: TaskLike) -> None:
    """check_name, and for a user's task definition its observation with jax.numpy equal to NumPy's (once per
    process; the trainer's edge: JAX is imported here)."""
    resolve(name).check_traced()


def resolve_task(name: TaskLike) -> Any:
    """A new instance of the task definition (envs/task.py's Task) behind `name`, checked once per process
    (TaskError)."""
    return resolve(name).new()


def task_source(name: TaskLike) -> dict:
    """What says which code defines task `name` (recorded in config.json and sweep.json): for a task defined
    outside this package, its module, file and the file's sha256; for another library's, its version."""
    return resolve(name).source()


def has_c_backend(name: TaskLike) -> bool:
    """Whether MuJoCo C steps task `name` (backend 'c', deployment, evaluation and robustness)."""
    return resolve(name).has_c


def default_episode_length(name: TaskLike) -> int:
    """The task's own time limit (env steps)."""
    return int(resolve(name).episode_length())


def max_return(name: TaskLike) -> Optional[float]:
    """The most an episode of task `name` can return where its definition declares it (Task.max_return), else None."""
    return resolve(name).max_return()


def task_model(name: TaskLike) -> Any:
    """The MuJoCo C model (MjModel) of a task's MJCF with the solver options its MJX version steps with
    (Brax's for the gym tasks), loaded without JAX or MJX (but for another library's environment, built once):
    for sizes and physics records. The record's own, shared by every caller: read it, never change it (a task to
    change, e.g. under a shift, comes from resolve(name).make_c())."""
    return resolve(name).model()


def action_size(name: TaskLike) -> int:
    """Actions of a task, read from its MJCF (no MJX environment is built, but for another library's environment)."""
    return resolve(name).action_size()


def observation_size(name: TaskLike) -> int:
    """Observation values of task `name` as its definition is now (a task definition's observe(); else the length of
    its observation layout)."""
    return resolve(name).observation_size()


def action_bounds(name: TaskLike, size: Optional[int] = None) -> tuple:
    """(low [d_a], high [d_a]) float32: the bounds of task `name`'s d_a actions (ACTION_RANGE for each); size: d_a
    (default: action_size(name), read from the MJCF). A task with ctrl_range 'model' maps these actions onto its
    actuators' ctrlrange (control_range())."""
    return resolve(name).action_bounds(size)


def control_range(name: TaskLike) -> Optional[tuple]:
    """(low [nu], high [nu]) float64 a task maps its actions in ACTION_RANGE onto (envs/task.py's ctrl_range 'model':
    ctrl = low + (a + 1) (high - low) / 2), or None where the actions are the controls."""
    return resolve(name).control_range()


def task_randomize(name: TaskLike) -> str:
    """The randomization a task definition declares (Task.randomize, envs/randomization.py's text); ValueError if
    none."""
    record = resolve(name)
    text = record.declared_randomize()
    if not text:
        raise ValueError(f"task {record.name!r} declares no randomization (Task.randomize); give one, e.g. "
                         "randomize='mass=0.9:1.1, delay=1'")
    return parse_randomize(text).text()
