"""The task registry: one record per task, and the only way from a task's name to its parts.

    record = resolve("Hopper-v5")                    # resolved and checked once per process (envs.task_record)
    record.episode_length(), record.model()          # the time limit; the MjModel (no JAX, no MJX)
    record.make_mjx(), record.make_c_backend(physics)   # the unwrapped env on MJX / MuJoCo C in the program
    record.make_c()                                  # plain MuJoCo C (deployment, evaluation, robustness)

A record says, for one task, everything the rest of the project asks of it: its family, its time limit, its
MuJoCo C model, how to build it on each backend, its plain MuJoCo C twin and its observation layout, and what
code defines it. Families: a task definition (envs/definition.py: gymnasium's v5 tasks, a registered one, a user's
'module:Class'); Brax's MJX variants of the locomotion tasks (their MuJoCo C ports in envs/brax_ports.py);
allegro_cylinder (envs/allegro.py); another library's environment ('brax:<name>', 'playground:<Name>', or a
user's brax.envs.Env / Playground MjxEnv subclass named 'module:Class'; MJX only).

resolve(task) is the one entry from a name (or a Task, or a record) to its record; the functions at the end answer
what a task's name says (sizes, bounds, time limit, source) through it, and envs/build.py builds environments from
records. This module loads without JAX and without MuJoCo (`import envs` must not load MuJoCo: the renderer picks
MUJOCO_GL after it); the few imports inside functions load them for the record that needs them.
"""

import contextlib
import copy
import difflib
import functools
import hashlib
import importlib
import importlib.util
import io
import inspect
import os
import sys
import types
import warnings
from importlib import metadata
from typing import TYPE_CHECKING, Any, Callable, Optional

import numpy as np

from envs import dmc
from envs.names import ACTION_RANGE, BRAX_TASKS, DEFAULT_EPISODE_LENGTH, DMC_TASKS, GYM_V5_TASKS, NAMES
from envs.physics import C, Physics, mj_model
from envs.randomize import parse as parse_randomize

if TYPE_CHECKING:  # annotations only: MuJoCo and Brax load when a record is asked for them
    import mujoco
    from brax.envs.base import Env

    from envs.definition import Task

TaskLike = Any  # a task's name, its TaskRecord, or a Task instance or subclass (envs/task.py): what resolve() takes


def _mujoco():
    """The records' MuJoCo C side: envs/definition.py (Task, TaskC, validate), envs/brax_ports.py,
    envs/allegro_task.py and envs/gym_v5.py."""
    from envs import allegro_task, brax_ports, definition, gym_v5  # MuJoCo: `import envs` loads none (module docstring)

    return types.SimpleNamespace(allegro=allegro_task, ports=brax_ports, task=definition, v5=gym_v5)


def _mjx():
    """envs/allegro.py and envs/task_mjx.py: the MJX side of the built-in tasks."""
    with contextlib.redirect_stdout(io.StringIO()):  # without mujoco.mjx's "Failed to import warp" notice
        from envs import allegro, task_mjx  # JAX and MJX: imported when an MJX env is first built

    return types.SimpleNamespace(allegro=allegro, task_mjx=task_mjx)


class TaskRecord:
    """One task's parts. Subclasses are the families; `name` is the name it was asked for."""

    family = ""
    builtin = True
    has_c = False  # whether MuJoCo C steps it (backend 'c', deployment, evaluation, robustness)

    def __init__(self, name: str):
        self.name = name

    def __repr__(self):
        return f"TaskRecord({self.name!r}, family={self.family!r})"

    def check(self) -> None:
        """ValueError (one line) unless the task can be built; cheap for built-in tasks."""

    def check_traced(self) -> None:
        """check(), and whatever can be checked only with JAX (once per process, at the trainer's edge)."""
        self.check()

    def check_physics(self, physics: Physics) -> None:
        """ValueError (one line) unless `physics` (envs.physics.Physics, validated) can step this task."""
        if physics.backend == C and not self.has_c:
            self.make_c_backend(physics)  # raises, saying why

    def episode_length(self) -> int:
        return DEFAULT_EPISODE_LENGTH

    def model(self) -> "mujoco.MjModel":
        """The MuJoCo C model (MjModel) with the solver options its MJX version steps with; no JAX, no MJX."""
        raise NotImplementedError

    def make_mjx(self) -> "Env":
        """The unwrapped single-env Brax environment on MJX (envs.make_base adds the physics options)."""
        raise NotImplementedError

    def mjx_env(self) -> "Env":
        """make_mjx() as envs.make_base builds it: without Brax's "not actively maintained" notice, and with
        jax.devices() naming this process's devices (envs/task_mjx.py's process_local_devices)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # brax's notice, once per env
            with _mjx().task_mjx.process_local_devices():
                return self.make_mjx()

    def make_c_backend(self, physics: Physics) -> "Env":
        """The unwrapped env stepped by MuJoCo C inside the program (envs/c_backend.py)."""
        raise ValueError(f"physics backend 'c' does not step {self.name!r} (it steps every task definition, Brax's "
                         "hopper, walker2d, halfcheetah and ant, and allegro_cylinder); it runs on backend 'mjx'")

    def make_c(self) -> Any:
        """The task on one MjData in plain MuJoCo C: reset(seed) -> obs, step(action) -> (obs, reward, done)."""
        raise ValueError(f"no MuJoCo C version of {self.name!r}: MuJoCo C runs every task definition (envs/task.py), "
                         "Brax's hopper, walker2d, halfcheetah and ant, and allegro_cylinder")

    def observation_layout(self) -> list:
        """One short description per observation entry (exported controllers' docs)."""
        raise NotImplementedError

    def source(self) -> dict:
        """What says which code defines the task (recorded in config.json and sweep.json)."""
        return {"task": self.name, "builtin": True}


def _quiet_brax():
    """brax.envs, imported without mujoco.mjx's "Failed to import warp" notice (a GPU-only backend)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        from brax import envs as brax_envs  # JAX: imported when a Brax env is first named or built
    return brax_envs


def _c_backend():
    """envs/c_backend.py, imported without mujoco.mjx's notice."""
    with contextlib.redirect_stdout(io.StringIO()):
        from envs import c_backend  # JAX and mujoco.batch: imported when backend 'c' first builds an env
    return c_backend


def _playground():
    """envs/playground_adapter.py."""
    from envs import playground_adapter  # JAX; MuJoCo Playground (optional) is imported inside it when used

    return playground_adapter


class BraxVariant(TaskRecord):
    """Brax's MJX variant of a gym locomotion task (its registry, backend 'mjx'); MuJoCo C ports of all but
    inverted_double_pendulum in envs/mujoco_c.py."""

    family = "brax"
    _port = None

    @property
    def has_c(self) -> bool:
        return self.name in _mujoco().ports.BRAX_PORTS

    def port(self) -> "Task":
        """A new instance of the task's MuJoCo C port, a task definition (envs/brax_ports.py's BRAX_PORTS)."""
        task = _mujoco().ports.BRAX_PORTS[self.name]()
        task.name = self.name
        return task

    def model(self) -> "mujoco.MjModel":
        if self.has_c:
            if self._port is None:  # read only (sizes, records): one per record
                self._port = self.port()
            return self._port.model
        return _mujoco().ports.brax_model(self.name)

    def make_mjx(self) -> "Env":
        return _quiet_brax().get_environment(self.name, backend="mjx")

    def make_c_backend(self, physics: Physics) -> "Env":
        if not self.has_c:
            return super().make_c_backend(physics)
        return _c_backend().TaskCEnv(self.name, physics, self.port())

    def make_c(self) -> Any:
        if not self.has_c:
            return super().make_c()
        return _mujoco().task.TaskC(self.port())

    def observation_layout(self) -> list:
        return self.port().observation_layout() if self.has_c else list(_mujoco().ports.IDP_LAYOUT)


class AllegroRecord(TaskRecord):
    """allegro_cylinder: the paper's Allegro-hand tactile task (envs/allegro.py; MuJoCo C: envs/allegro_task.py)."""

    family = "allegro"
    has_c = True

    def episode_length(self) -> int:
        return _mujoco().allegro.DEFAULT_EPISODE_LENGTH  # 2 s at 100 Hz

    def model(self) -> "mujoco.MjModel":
        return _mujoco().allegro.load_mj_model()

    def make_mjx(self) -> "Env":
        return _mjx().allegro.AllegroCylinder()

    def make_c_backend(self, physics: Physics) -> "Env":
        return _c_backend().AllegroCTask(self.name, physics)

    def make_c(self) -> Any:
        return _mujoco().allegro.AllegroC()

    def observation_layout(self) -> list:
        return _mujoco().allegro.allegro_layout(self.model())


class Definition(TaskRecord):
    """A task definition (envs/task.py): gymnasium's v5 tasks, a registered one, a user's 'module:Class'.
    factory: a Task subclass or a callable returning a Task, checked once (envs.task.validate)."""

    family = "definition"
    has_c = True

    def __init__(self, name: str, factory: Callable[[], Any], builtin: bool = False):
        super().__init__(name)
        self.factory, self.builtin = factory, builtin
        self._task, self._traced = None, False

    def task(self) -> "Task":
        """The Task instance read for sizes, layouts and records (made and validated on first use; TaskError in one
        line). Not to be stepped or changed: new() makes one for that."""
        if self._task is None:
            self._task = make_definition(self.name, self.factory)
        return self._task

    def new(self) -> "Task":
        """A new Task instance with its own MjModel (the definition validated once, by task())."""
        self.task()
        task = self.factory()
        task.name = self.name
        return task

    def check(self) -> None:
        if not self.builtin:  # a user's: loaded and validated when named; the built-in ones when used
            self.task()

    def check_traced(self) -> None:
        if not self.builtin and not self._traced:  # the v5 tasks are checked against gymnasium by the test suite
            _mujoco().task.check_jax_agrees(self.task(), f"task {self.name!r}")
            self._traced = True

    def episode_length(self) -> int:
        return int(self.task().episode_length)

    def model(self) -> "mujoco.MjModel":
        return self.task().model

    def make_mjx(self) -> "Env":
        return _mjx().task_mjx.TaskMjx(self.new())

    def make_c_backend(self, physics: Physics) -> "Env":
        return _c_backend().TaskCEnv(self.name, physics, self.new())

    def make_c(self) -> Any:
        return _mujoco().task.TaskC(self.new())

    def observation_layout(self) -> list:
        return self.task().observation_layout()

    def source(self) -> dict:
        if self.builtin:
            return super().source()
        task = self.task()
        return {"task": self.name, "builtin": False, **_mujoco().task.source_record(type(task)), "action_size": int(task.model.nu),
                "observation_size": int(task.observation_size)}


def definition_record(task: Any, name: str = "") -> "Definition":
    """The record of a task definition given as an object (a Task instance or subclass, envs/task.py) rather
    than a name: for library users who train a task without registering it (make_train(cfg, task)). name:
    what results call it (default: the class's name). Validated here (TaskError in one line)."""
    Task, TaskError = _mujoco().task.Task, _mujoco().task.TaskError
    if isinstance(task, type) and issubclass(task, Task):
        factory = task
    elif isinstance(task, Task):
        factory = lambda: copy.deepcopy(task)  # noqa: E731  (new() promises its own MjModel)
    else:
        raise TaskError(f"a task is a name, a TaskRecord or an envs.task.Task (instance or subclass), got {task!r}")
    record = Definition(name or (task if isinstance(task, type) else type(task)).__name__, factory)
    record.check()
    return record


def make_definition(name: str, factory: Callable[[], Any]) -> "Task":
    """factory() as a validated Task named `name` (TaskError in one line for anything else)."""
    Task, TaskError = _mujoco().task.Task, _mujoco().task.TaskError
    try:
        task = factory()
    except TaskError:
        raise
    except Exception as e:  # a user's constructor: its error in one line
        raise TaskError(f"task {name!r}: making it failed: {type(e).__name__}: {' '.join(str(e).split())}") from None
    if not isinstance(task, Task):
        raise TaskError(f"task {name!r}: {factory!r} gave a {type(task).__name__}, not an envs.task.Task")
    task.name = name
    _mujoco().task.validate(task, f"task {name!r}")
    return task


class Adapted(TaskRecord):
    """Another library's environment, '<library>:<their name>' (MJX only): its MjModel is read from the built
    environment (seconds), so once per record."""

    builtin = False
    library = ""
    version_of = ""  # the distribution whose version the results record

    def __init__(self, name: str):
        super().__init__(name)
        self.theirs = name.partition(":")[2]
        self._model = None

    def model(self) -> "mujoco.MjModel":
        if self._model is None:
            self._model = mj_model(self.mjx_env())  # as envs.make_base(self) builds it (the default physics)
        return self._model

    def observation_layout(self) -> list:
        return [f"obs[{i}]" for i in range(int(self.make_mjx().observation_size))]

    def source(self) -> dict:
        return {"task": self.name, "builtin": False, "library": self.library, "name": self.theirs,
                "action_size": int(self.model().nu), "version": _installed_version(self.version_of)}

    def make_c_backend(self, physics: Physics) -> "Env":
        raise ValueError(f"physics backend 'c' does not step {self.name!r}: another library's environments step "
                         "in JAX only; use backend 'mjx'")

    def make_c(self) -> Any:
        raise ValueError(f"no MuJoCo C version of {self.name!r}: another library's environments step in JAX only "
                         "(gsa_jax.deploy --compare-mjx RUN_DIR runs its controller in MJX)")


class BraxAdapted(Adapted):
    """'brax:<name>': any environment of Brax's registry, on MJX."""

    family, library, version_of = "brax_adapter", "brax", "brax"

    def check(self) -> None:
        known = sorted(_quiet_brax()._envs)
        if self.theirs not in known:
            close = difflib.get_close_matches(self.theirs, known, n=3)
            raise ValueError(f"unknown env {self.name!r}: Brax registers {', '.join(known)}"
                             + (f"; did you mean {', '.join('brax:' + c for c in close)}?" if close else ""))

    def make_mjx(self) -> "Env":
        return _quiet_brax().get_environment(self.theirs, backend="mjx")


class PlaygroundAdapted(Adapted):
    """'playground:<Name>': any environment of MuJoCo Playground's registry, on MJX (envs/playground_adapter.py)."""

    family, library, version_of = "playground", "playground", "playground"

    def check(self) -> None:
        _playground().check_name(self.name)

    def episode_length(self) -> int:
        return int(_playground().registry().get_default_config(self.theirs).get("episode_length", DEFAULT_EPISODE_LENGTH))

    def check_physics(self, physics: Physics) -> None:
        super().check_physics(physics)
        if physics.solver_iterations is not None or physics.ls_iterations is not None:
            raise ValueError(f"{self.name!r} runs with Playground's own solver settings; solver_iterations and "
                             "ls_iterations do not apply")

    def make_mjx(self) -> "Env":
        return _playground().PlaygroundEnv(self.name)

    def check_randomizer(self) -> None:
        """ValueError (one line) unless Playground's registry has a domain randomizer for this environment."""
        _playground().domain_randomizer(self.name)


class UserEnv(Adapted):
    """A user's environment class of another library, named 'module:Class' or registered: a `brax.envs.Env`
    subclass (made as Brax's registry makes its own, with backend='mjx' where the class takes a backend) or a
    MuJoCo Playground `MjxEnv` subclass (made with impl 'jax'). MJX only; built once here to check it."""

    family = "user_env"

    def __init__(self, name: str, cls: type, library: str):
        super().__init__(name)
        self.cls, self.library, self.version_of = cls, library, library
        self.theirs = f"{cls.__module__}.{cls.__qualname__}"
        self._length = None

    def check(self) -> None:
        self.model()

    def episode_length(self) -> int:
        if self.library != "playground":
            return DEFAULT_EPISODE_LENGTH
        if self._length is None:  # building the env takes seconds: once per record
            self._length = int(self.make_mjx().episode_length)
        return self._length

    def make_mjx(self) -> "Env":
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                if self.library == "playground":
                    return _playground().PlaygroundEnv(self.name, _make_playground(self.cls))
                env = _make_brax(self.cls)
        except Exception as e:  # the user's constructor, or the library's: one line naming the task
            raise ValueError(f"task {self.name!r}: making it failed: {type(e).__name__}: "
                             f"{' '.join(str(e).split())[:200]}") from None
        on_mjx = hasattr(env, "mj_model") or hasattr(getattr(env, "sys", None), "mj_model")
        if getattr(env, "backend", "mjx") != "mjx" or not on_mjx:
            raise ValueError(f"task {self.name!r}: a Brax environment here steps on MJX (a PipelineEnv with backend "
                             f"'mjx'); {self.theirs} has backend {getattr(env, 'backend', None)!r}")
        return env

    def source(self) -> dict:
        return {**super().source(), **_mujoco().task.source_record(self.cls)}


def _make_brax(cls):
    """A brax.envs.Env subclass made as Brax's registry makes one: backend='mjx' where its constructor takes one."""
    takes = inspect.signature(cls.__init__).parameters
    if "backend" in takes or any(p.kind is p.VAR_KEYWORD for p in takes.values()):
        return cls(backend="mjx")
    return cls()


def _make_playground(cls):
    """A Playground MjxEnv subclass made as its registry makes one, with impl 'jax' (MJX) where its constructor
    takes config_overrides."""
    if "config_overrides" in inspect.signature(cls.__init__).parameters:
        return cls(config_overrides={"impl": "jax"})
    return cls()


def library_of(obj: Any) -> Optional[str]:
    """'brax' for a brax.envs.Env subclass, 'playground' for a MuJoCo Playground MjxEnv subclass, else None (read
    from the class's bases, so nothing is imported)."""
    if not isinstance(obj, type):
        return None
    bases = {(c.__module__, c.__name__) for c in obj.__mro__}
    if ("brax.envs.base", "Env") in bases:
        return "brax"
    if ("mujoco_playground._src.mjx_env", "MjxEnv") in bases:
        return "playground"
    return None


def user_record(name: str, factory: Callable[..., Any]) -> TaskRecord:
    """The checked record of a user's task `name` made by `factory`: a task definition (envs/task.py), or a Brax or
    Playground environment class (UserEnv)."""
    library = library_of(factory)
    record = UserEnv(name, factory, library) if library else Definition(name, factory)
    record.check()
    return record


ADAPTERS = {"brax:": BraxAdapted, "playground:": PlaygroundAdapted}


def _installed_version(dist):
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def builtin_records() -> dict:
    """{name: record factory} of the tasks this package ships."""
    def v5(name):
        def make():  # gymnasium's MJCF and MuJoCo are loaded when the task is first used
            return _mujoco().v5.V5_TASKS[name]()

        return Definition(name, make, builtin=True)

    def suite(name):
        def make():  # dm_control's MJCF is read when the task is first used (TaskError without dm_control)
            return dmc.task_class(name)()

        return Definition(name, make, builtin=True)

    table = {name: BraxVariant for name in BRAX_TASKS}
    table["allegro_cylinder"] = AllegroRecord
    table.update({name: v5 for name in GYM_V5_TASKS})
    table.update({name: suite for name in DMC_TASKS})
    return table


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


task_record = resolve  # the name the rest of the project has long used


@functools.lru_cache(maxsize=None)
def _record(name):
    if not isinstance(name, str) or not name:
        raise ValueError(f"a task name is a non-empty string, got {name!r}")
    builtin = builtin_records().get(name)
    if builtin is not None:
        return builtin(name)
    record = adapted_record(name)
    if record is not None:
        return record
    if name.startswith("dmc:"):
        dmc.task_class(name)  # the name is not one of them: ValueError listing those there are
    if name in _REGISTERED or ":" in name:
        return user_record(name, _REGISTERED.get(name) or _import_factory(name))
    TaskError = _mujoco().task.TaskError
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
    TaskError = _mujoco().task.TaskError
    module_name, _, attr = name.rpartition(":")
    if not module_name or not attr:
        raise TaskError(f"unknown env {name!r}; a task definition is named 'module:Class' or 'path/file.py:Class'")
    module = _import_module(module_name, name)
    if not hasattr(module, attr):
        Task = _mujoco().task.Task
        found = [k for k, v in vars(module).items() if isinstance(v, type) and issubclass(v, Task) and v is not Task]
        close = difflib.get_close_matches(attr, found, n=3) or found
        raise TaskError(f"task {name!r}: {module_name} has no {attr!r}" + (f"; did you mean {', '.join(close)}?" if close else ""))
    return getattr(module, attr)


def _import_module(module_name, name):
    TaskError = _mujoco().task.TaskError
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


# What a task's name says, read from its record (no environment is built).

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
    record = resolve(name)
    if not isinstance(record, Definition):
        raise ValueError(f"{record.name!r} is not a task definition (envs/task.py) but a {record.family} task")
    return record.new()


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


def max_return(name: TaskLike) -> float | None:
    """The most an episode of task `name` can return where its definition declares it (Task.max_return), else None."""
    record = resolve(name)
    value = getattr(record.task(), "max_return", None) if isinstance(record, Definition) else None
    return None if value is None else float(value)


def task_model(name: TaskLike) -> Any:
    """The MuJoCo C model (MjModel) of a task's MJCF with the solver options its MJX version steps with
    (Brax's for the gym tasks), loaded without JAX or MJX (but for another library's environment, built once):
    for sizes and physics records. The record's own, shared by every caller: read it, never change it (a task to
    change, e.g. under a shift, comes from resolve(name).make_c())."""
    return resolve(name).model()


def action_size(name: TaskLike) -> int:
    """Actions of a task, read from its MJCF (no MJX environment is built, but for another library's environment)."""
    return int(task_model(name).nu)


def observation_size(name: TaskLike) -> int:
    """Observation values of task `name` as its definition is now (a task definition's observe(); else the length of
    its observation layout)."""
    record = resolve(name)
    if isinstance(record, Definition):
        return int(record.task().observation_size)
    return len(record.observation_layout())


def action_bounds(name: TaskLike, size: Optional[int] = None) -> tuple:
    """(low [d_a], high [d_a]) float32: the bounds of task `name`'s d_a actions (ACTION_RANGE for each); size: d_a
    (default: action_size(name), read from the MJCF). A task with ctrl_range 'model' maps these actions onto its
    actuators' ctrlrange (control_range())."""
    resolve(name)
    size = action_size(name) if size is None else int(size)
    return np.full(size, ACTION_RANGE[0], np.float32), np.full(size, ACTION_RANGE[1], np.float32)


def control_range(name: TaskLike) -> Optional[tuple]:
    """(low [nu], high [nu]) float64 a task maps its actions in ACTION_RANGE onto (envs/task.py's ctrl_range 'model':
    ctrl = low + (a + 1) (high - low) / 2), or None where the actions are the controls."""
    record = resolve(name)
    if not isinstance(record, Definition) or record.task().ctrl_range != "model":
        return None
    low, high = record.model().actuator_ctrlrange.T
    return low.copy(), high.copy()


def task_randomize(name: TaskLike) -> str:
    """The randomization a task definition declares (Task.randomize, envs/randomize.py's text); ValueError if none."""
    record = resolve(name)
    text = record.task().randomize if isinstance(record, Definition) else ""
    if not text:
        raise ValueError(f"task {record.name!r} declares no randomization (Task.randomize); give one, e.g. "
                         "randomize='mass=0.9:1.1, delay=1'")
    return parse_randomize(text).text()
