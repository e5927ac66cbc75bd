"""Task definitions (envs/task.py): gymnasium's v5 tasks, the DeepMind Control Suite's, a registered one, a user's
'module:Class'. Each runs on both backends and in plain MuJoCo C."""

import copy
from typing import TYPE_CHECKING, Any, Callable, Optional

from envs import dmc
from envs.families.record import TaskRecord, c_backend, mjx_side, mujoco_side
from envs.names import DMC_TASKS, GYM_V5_TASKS
from envs.physics import Physics

if TYPE_CHECKING:
    import mujoco
    from brax.envs.base import Env

    from envs.task import Task


class Definition(TaskRecord):
    """A task definition. factory: a Task subclass or a callable returning a Task, checked once
    (envs.task_checks.validate)."""

    family = "definition"
    has_c = True
    verifiable = True

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
            mujoco_side().checks.check_jax_agrees(self.task(), f"task {self.name!r}")
            self._traced = True

    def load(self) -> None:
        self.task()

    def episode_length(self) -> int:
        return int(self.task().episode_length)

    def model(self) -> "mujoco.MjModel":
        return self.task().model

    def observation_size(self) -> int:
        return int(self.task().observation_size)

    def control_range(self) -> Optional[tuple]:
        """(low [nu], high [nu]) float64 with ctrl_range 'model' (ctrl = low + (a + 1) (high - low) / 2), else None."""
        if self.task().ctrl_range != "model":
            return None
        low, high = self.model().actuator_ctrlrange.T
        return low.copy(), high.copy()

    def max_return(self) -> Optional[float]:
        value = getattr(self.task(), "max_return", None)
        return None if value is None else float(value)

    def declared_randomize(self) -> str:
        return self.task().randomize

    def c_definition(self) -> "Optional[Task]":
        return self.task()

    def make_mjx(self) -> "Env":
        return mjx_side().task_mjx.TaskMjx(self.new())

    def make_c_backend(self, physics: Physics) -> "Env":
        return c_backend().TaskCEnv(self.name, physics, self.new())

    def make_c(self) -> Any:
        return mujoco_side().task.TaskC(self.new())

    def observation_layout(self) -> list:
        return self.task().observation_layout()

    def source(self) -> dict:
        if self.builtin:
            return super().source()
        task = self.task()
        return {"task": self.name, "builtin": False, **mujoco_side().task.source_record(type(task)),
                "action_size": int(task.model.nu), "observation_size": int(task.observation_size)}


def definition_record(task: Any, name: str = "") -> Definition:
    """The record of a task definition given as an object (a Task instance or subclass, envs/task.py) rather
    than a name: for library users who train a task without registering it (gsa_jax.running.tasks.trainer_for(cfg, task)). name:
    what results call it (default: the class's name). Validated here (TaskError in one line)."""
    Task, TaskError = mujoco_side().task.Task, mujoco_side().task.TaskError
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
    Task, TaskError = mujoco_side().task.Task, mujoco_side().task.TaskError
    try:
        task = factory()
    except TaskError:
        raise
    except Exception as e:  # a user's constructor: its error in one line
        raise TaskError(f"task {name!r}: making it failed: {type(e).__name__}: {' '.join(str(e).split())}") from None
    if not isinstance(task, Task):
        raise TaskError(f"task {name!r}: {factory!r} gave a {type(task).__name__}, not an envs.task.Task")
    task.name = name
    mujoco_side().checks.validate(task, f"task {name!r}")
    return task


def gym_v5_record(name: str) -> Definition:
    """The record of one of gymnasium's v5 tasks (its MJCF and MuJoCo are loaded when the task is first used)."""
    return Definition(name, lambda: mujoco_side().v5.V5_TASKS[name](), builtin=True)


def dmc_record(name: str) -> Definition:
    """The record of one of the DeepMind Control Suite's tasks (dm_control's MJCF is read when the task is first
    used; TaskError without dm_control)."""
    return Definition(name, lambda: dmc.task_class(name)(), builtin=True)


ENTRIES = {**{name: gym_v5_record for name in GYM_V5_TASKS}, **{name: dmc_record for name in DMC_TASKS}}
