"""The task registry: one record per task, and the only way from a task's name to its parts.

    record = envs.task_record("Hopper-v5")          # resolved and checked once per process
    record.episode_length(), record.model()          # the time limit; the MjModel (no JAX, no MJX)
    record.make_mjx(), record.make_c_backend(physics)   # the unwrapped env on MJX / MuJoCo C in the program
    record.make_c()                                  # plain MuJoCo C (deployment, evaluation, robustness)

A record says, for one task, everything the rest of the project asks of it: its family, its time limit, its
MuJoCo C model, how to build it on each backend, its plain MuJoCo C twin and its observation layout, and what
code defines it. Families: a task definition (envs/task.py: gymnasium's v5 tasks, a registered one, a user's
'module:Class'); Brax's MJX variants of the locomotion tasks (their MuJoCo C ports in envs/mujoco_c.py);
allegro_cylinder (envs/allegro.py); another library's environment ('brax:<name>', 'playground:<Name>', or a
user's brax.envs.Env / Playground MjxEnv subclass named 'module:Class'; MJX only). envs/__init__.py resolves
names into records and keeps no table of its own.
"""

import contextlib
import copy
import functools
import io
from typing import Any, Callable, Optional

DEFAULT_EPISODE_LENGTH = 1000


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

    def check_physics(self, physics) -> None:
        """ValueError (one line) unless `physics` (envs.physics.Physics, validated) can step this task."""
        if physics.backend == "c" and not self.has_c:
            self.make_c_backend(physics)  # raises, saying why

    def episode_length(self) -> int:
        return DEFAULT_EPISODE_LENGTH

    def model(self):
        """The MuJoCo C model (MjModel) with the solver options its MJX version steps with; no JAX, no MJX."""
        raise NotImplementedError

    def make_mjx(self):
        """The unwrapped single-env Brax environment on MJX (envs.make_base adds the physics options)."""
        raise NotImplementedError

    def make_c_backend(self, physics):
        """The unwrapped env stepped by MuJoCo C inside the program (envs/c_backend.py)."""
        raise ValueError(f"physics backend 'c' does not step {self.name!r} (it steps every task definition, Brax's "
                         "hopper, walker2d, halfcheetah and ant, and allegro_cylinder); it runs on backend 'mjx'")

    def make_c(self):
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
        from brax import envs as brax_envs
    return brax_envs


def _c_backend():
    """envs/c_backend.py (imports JAX), imported without mujoco.mjx's notice."""
    with contextlib.redirect_stdout(io.StringIO()):
        from envs import c_backend
    return c_backend


class BraxVariant(TaskRecord):
    """Brax's MJX variant of a gym locomotion task (its registry, backend 'mjx'); MuJoCo C ports of all but
    inverted_double_pendulum in envs/mujoco_c.py."""

    family = "brax"
    _port = None

    @property
    def has_c(self):
        from envs import mujoco_c

        return self.name in mujoco_c.BRAX_PORTS

    def port(self):
        """A new instance of the task's MuJoCo C port, a task definition (envs/mujoco_c.py's BRAX_PORTS)."""
        from envs import mujoco_c

        task = mujoco_c.BRAX_PORTS[self.name]()
        task.name = self.name
        return task

    def model(self):
        import mujoco

        from envs import mujoco_c

        if self.has_c:
            if self._port is None:  # read only (sizes, records): one per record
                self._port = self.port()
            return self._port.model
        return mujoco.MjModel.from_xml_path(mujoco_c.brax_asset(self.name + ".xml"))

    def make_mjx(self):
        return _quiet_brax().get_environment(self.name, backend="mjx")

    def make_c_backend(self, physics):
        if not self.has_c:
            return super().make_c_backend(physics)
        return _c_backend().TaskCEnv(self.name, physics, self.port())

    def make_c(self):
        from envs.task import TaskC

        if not self.has_c:
            return super().make_c()
        return TaskC(self.port())

    def observation_layout(self):
        from envs import mujoco_c

        return self.port().observation_layout() if self.has_c else list(mujoco_c.IDP_LAYOUT)


class AllegroRecord(TaskRecord):
    """allegro_cylinder: the paper's Allegro-hand tactile task (envs/allegro.py; MuJoCo C: envs/allegro_task.py)."""

    family = "allegro"
    has_c = True

    def episode_length(self):
        from envs.allegro_task import DEFAULT_EPISODE_LENGTH as allegro_length  # 2 s at 100 Hz; no JAX import

        return allegro_length

    def model(self):
        from envs import allegro_task

        return allegro_task.load_mj_model()

    def make_mjx(self):
        with contextlib.redirect_stdout(io.StringIO()):
            from envs import allegro
        return allegro.AllegroCylinder()

    def make_c_backend(self, physics):
        return _c_backend().AllegroCTask(self.name, physics)

    def make_c(self):
        from envs import mujoco_c

        return mujoco_c.AllegroC()

    def observation_layout(self):
        from envs import mujoco_c

        return mujoco_c.allegro_layout(self.model())


class Definition(TaskRecord):
    """A task definition (envs/task.py): gymnasium's v5 tasks, a registered one, a user's 'module:Class'.
    factory: a Task subclass or a callable returning a Task, checked once (envs.task.validate)."""

    family = "definition"
    has_c = True

    def __init__(self, name: str, factory: Callable[[], Any], builtin: bool = False):
        super().__init__(name)
        self.factory, self.builtin = factory, builtin
        self._task, self._traced = None, False

    def task(self):
        """The Task instance read for sizes, layouts and records (made and validated on first use; TaskError in one
        line). Not to be stepped or changed: new() makes one for that."""
        if self._task is None:
            self._task = make_definition(self.name, self.factory)
        return self._task

    def new(self):
        """A new Task instance with its own MjModel (the definition validated once, by task())."""
        self.task()
        task = self.factory()
        task.name = self.name
        return task

    def check(self):
        if not self.builtin:  # a user's: loaded and validated when named; the built-in ones when used
            self.task()

    def check_traced(self):
        if not self.builtin and not self._traced:  # the v5 tasks are checked against gymnasium by the test suite
            from envs.task import check_jax_agrees

            check_jax_agrees(self.task(), f"task {self.name!r}")
            self._traced = True

    def episode_length(self):
        return int(self.task().episode_length)

    def model(self):
        return self.task().model

    def make_mjx(self):
        from envs.task_mjx import TaskMjx

        return TaskMjx(self.new())

    def make_c_backend(self, physics):
        return _c_backend().TaskCEnv(self.name, physics, self.new())

    def make_c(self):
        from envs.task import TaskC

        return TaskC(self.new())

    def observation_layout(self):
        return self.task().observation_layout()

    def source(self):
        if self.builtin:
            return super().source()
        from envs.task import source_record

        task = self.task()
        return {"task": self.name, "builtin": False, **source_record(type(task)), "action_size": int(task.model.nu),
                "observation_size": int(task.observation_size)}


def definition_record(task, name: str = "") -> "Definition":
    """The record of a task definition given as an object (a Task instance or subclass, envs/task.py) rather
    than a name: for library users who train a task without registering it (make_train(cfg, task)). name:
    what results call it (default: the class's name). Validated here (TaskError in one line)."""
    from envs.task import Task, TaskError

    if isinstance(task, type) and issubclass(task, Task):
        factory = task
    elif isinstance(task, Task):
        factory = lambda: copy.deepcopy(task)  # noqa: E731  (new() promises its own MjModel)
    else:
        raise TaskError(f"a task is a name, a TaskRecord or an envs.task.Task (instance or subclass), got {task!r}")
    record = Definition(name or (task if isinstance(task, type) else type(task)).__name__, factory)
    record.check()
    return record


def make_definition(name, factory):
    """factory() as a validated Task named `name` (TaskError in one line for anything else)."""
    from envs.task import Task, TaskError, validate

    try:
        task = factory()
    except TaskError:
        raise
    except Exception as e:  # a user's constructor: its error in one line
        raise TaskError(f"task {name!r}: making it failed: {type(e).__name__}: {' '.join(str(e).split())}") from None
    if not isinstance(task, Task):
        raise TaskError(f"task {name!r}: {factory!r} gave a {type(task).__name__}, not an envs.task.Task")
    task.name = name
    validate(task, f"task {name!r}")
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

    def model(self):
        if self._model is None:
            import envs

            self._model = envs.mj_model(envs.make_base(self))
        return self._model

    def observation_layout(self):
        return [f"obs[{i}]" for i in range(int(self.make_mjx().observation_size))]

    def source(self):
        return {"task": self.name, "builtin": False, "library": self.library, "name": self.theirs,
                "action_size": int(self.model().nu), "version": _installed_version(self.version_of)}

    def make_c_backend(self, physics):
        raise ValueError(f"physics backend 'c' does not step {self.name!r}: another library's environments step "
                         "in JAX only; use backend 'mjx'")

    def make_c(self):
        raise ValueError(f"no MuJoCo C version of {self.name!r}: another library's environments step in JAX only "
                         "(gsa_jax.deploy --compare-mjx RUN_DIR runs its controller in MJX)")


class BraxAdapted(Adapted):
    """'brax:<name>': any environment of Brax's registry, on MJX."""

    family, library, version_of = "brax_adapter", "brax", "brax"

    def check(self):
        import difflib

        known = sorted(_quiet_brax()._envs)
        if self.theirs not in known:
            close = difflib.get_close_matches(self.theirs, known, n=3)
            raise ValueError(f"unknown env {self.name!r}: Brax registers {', '.join(known)}"
                             + (f"; did you mean {', '.join('brax:' + c for c in close)}?" if close else ""))

    def make_mjx(self):
        return _quiet_brax().get_environment(self.theirs, backend="mjx")


class PlaygroundAdapted(Adapted):
    """'playground:<Name>': any environment of MuJoCo Playground's registry, on MJX (envs/playground_adapter.py)."""

    family, library, version_of = "playground", "playground", "playground"

    def check(self):
        from envs import playground_adapter

        playground_adapter.check_name(self.name)

    def episode_length(self):
        from envs.playground_adapter import registry

        return int(registry().get_default_config(self.theirs).get("episode_length", DEFAULT_EPISODE_LENGTH))

    def check_physics(self, physics):
        super().check_physics(physics)
        if physics.solver_iterations is not None or physics.ls_iterations is not None:
            raise ValueError(f"{self.name!r} runs with Playground's own solver settings; solver_iterations and "
                             "ls_iterations do not apply")

    def make_mjx(self):
        from envs.playground_adapter import PlaygroundEnv

        return PlaygroundEnv(self.name)


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

    def check(self):
        self.model()

    def episode_length(self):
        if self.library != "playground":
            return DEFAULT_EPISODE_LENGTH
        if self._length is None:  # building the env takes seconds: once per record
            self._length = int(self.make_mjx().episode_length)
        return self._length

    def make_mjx(self):
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                if self.library == "playground":
                    from envs.playground_adapter import PlaygroundEnv

                    return PlaygroundEnv(self.name, _make_playground(self.cls))
                env = _make_brax(self.cls)
        except Exception as e:  # the user's constructor, or the library's: one line naming the task
            raise ValueError(f"task {self.name!r}: making it failed: {type(e).__name__}: "
                             f"{' '.join(str(e).split())[:200]}") from None
        on_mjx = hasattr(env, "mj_model") or hasattr(getattr(env, "sys", None), "mj_model")
        if getattr(env, "backend", "mjx") != "mjx" or not on_mjx:
            raise ValueError(f"task {self.name!r}: a Brax environment here steps on MJX (a PipelineEnv with backend "
                             f"'mjx'); {self.theirs} has backend {getattr(env, 'backend', None)!r}")
        return env

    def source(self):
        from envs.task import source_record

        return {**super().source(), **source_record(self.cls)}


def _make_brax(cls):
    """A brax.envs.Env subclass made as Brax's registry makes one: backend='mjx' where its constructor takes one."""
    import inspect

    takes = inspect.signature(cls.__init__).parameters
    if "backend" in takes or any(p.kind is p.VAR_KEYWORD for p in takes.values()):
        return cls(backend="mjx")
    return cls()


def _make_playground(cls):
    """A Playground MjxEnv subclass made as its registry makes one, with impl 'jax' (MJX) where its constructor
    takes config_overrides."""
    import inspect

    if "config_overrides" in inspect.signature(cls.__init__).parameters:
        return cls(config_overrides={"impl": "jax"})
    return cls()


def library_of(obj) -> Optional[str]:
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


def user_record(name: str, factory) -> TaskRecord:
    """The checked record of a user's task `name` made by `factory`: a task definition (envs/task.py), or a Brax or
    Playground environment class (UserEnv)."""
    library = library_of(factory)
    record = UserEnv(name, factory, library) if library else Definition(name, factory)
    record.check()
    return record


ADAPTERS = {"brax:": BraxAdapted, "playground:": PlaygroundAdapted}


def _installed_version(dist):
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def builtin_records() -> dict:
    """{name: record factory} of the tasks this package ships."""
    def v5(name):
        def make():  # gymnasium's MJCF and MuJoCo are loaded when the task is first used
            from envs import gym_v5

            return gym_v5.V5_TASKS[name]()

        return Definition(name, make, builtin=True)

    def dmc(name):
        def make():  # dm_control's MJCF is read when the task is first used (TaskError without dm_control)
            from envs import dmc as dmc_tasks

            return dmc_tasks.task_class(name)()

        return Definition(name, make, builtin=True)

    from envs import BRAX_TASKS, DMC_TASKS, GYM_V5_TASKS

    table = {name: BraxVariant for name in BRAX_TASKS}
    table["allegro_cylinder"] = AllegroRecord
    table.update({name: v5 for name in GYM_V5_TASKS})
    table.update({name: dmc for name in DMC_TASKS})
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
