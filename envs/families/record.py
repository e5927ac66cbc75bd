"""What every task's record answers (TaskRecord), and the lazy imports the families share.

A record says, for one task, everything the rest of the project asks of it: its time limit, its MuJoCo C model,
how to build it on each backend, its plain MuJoCo C twin and its observation layout, what code defines it, and what
each consumer may do with it (deployment's label, verify, domain randomization). A family is a subclass that answers
differently (envs/families/<family>.py); code outside envs/ asks the record and never its class. This module loads
without JAX and without MuJoCo: the loaders below import them when a record first needs them.
"""

import contextlib
import io
import types
import warnings
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from envs.names import ACTION_RANGE, DEFAULT_EPISODE_LENGTH
from envs.physics import C, Physics
from envs.randomization import RandomizeError

if TYPE_CHECKING:  # annotations only: MuJoCo and Brax load when a record is asked for them
    import mujoco
    from brax.envs.base import Env

    from envs.task import Task


def mujoco_side() -> types.SimpleNamespace:
    """The records' MuJoCo C side: envs/task.py (Task, TaskC), envs/task_checks.py (validate, check_jax_agrees),
    envs/brax_ports.py, envs/allegro_task.py and envs/v5_tasks.py."""
    from envs import allegro_task, brax_ports, task, task_checks, v5_tasks  # MuJoCo: `import envs` loads none

    return types.SimpleNamespace(allegro=allegro_task, ports=brax_ports, task=task, checks=task_checks, v5=v5_tasks)


def mjx_side() -> types.SimpleNamespace:
    """envs/allegro.py and envs/task_mjx.py: the MJX side of the built-in tasks."""
    with contextlib.redirect_stdout(io.StringIO()):  # without mujoco.mjx's "Failed to import warp" notice
        from envs import allegro, task_mjx  # JAX and MJX: imported when an MJX env is first built

    return types.SimpleNamespace(allegro=allegro, task_mjx=task_mjx)


def quiet_brax() -> types.ModuleType:
    """brax.envs, imported without mujoco.mjx's "Failed to import warp" notice (a GPU-only backend)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        from brax import envs as brax_envs  # JAX: imported when a Brax env is first named or built
    return brax_envs


def c_backend() -> types.ModuleType:
    """envs/c_backend.py, imported without mujoco.mjx's notice."""
    with contextlib.redirect_stdout(io.StringIO()):
        from envs import c_backend as module  # JAX and mujoco.batch: imported when backend 'c' first builds an env
    return module


def playground() -> types.ModuleType:
    """envs/playground_adapter.py."""
    from envs import playground_adapter  # JAX; MuJoCo Playground (optional) is imported inside it when used

    return playground_adapter


class TaskRecord:
    """One task's parts. Subclasses are the families; `name` is the name it was asked for."""

    family = ""
    builtin = True
    has_c = False  # whether MuJoCo C steps it (backend 'c', deployment, evaluation, robustness)
    verifiable = False  # whether gsa_jax.verify can step it: a task definition, whose start law and state it reads
    mjx_variants = True  # whether model scales and pushes apply on MJX (a Brax PipelineEnv's sys is replaced)

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

    def load(self) -> None:
        """Load what building the task needs (a task definition's code and MJCF), so that a missing dependency is
        refused before any work starts."""

    def episode_length(self) -> int:
        """The task's own time limit (env steps)."""
        return DEFAULT_EPISODE_LENGTH

    def model(self) -> "mujoco.MjModel":
        """The MuJoCo C model (MjModel) with the solver options its MJX version steps with; no JAX, no MJX."""
        raise NotImplementedError

    def action_size(self) -> int:
        """Actions of the task, read from its model."""
        return int(self.model().nu)

    def observation_size(self) -> int:
        """Observation values of the task: the length of its observation layout."""
        return len(self.observation_layout())

    def action_bounds(self, size: Optional[int] = None) -> tuple:
        """(low [d_a], high [d_a]) float32: ACTION_RANGE for each of the d_a actions (size; default action_size())."""
        size = self.action_size() if size is None else int(size)
        return np.full(size, ACTION_RANGE[0], np.float32), np.full(size, ACTION_RANGE[1], np.float32)

    def control_range(self) -> Optional[tuple]:
        """(low [nu], high [nu]) the actions in ACTION_RANGE map onto, or None where the actions are the controls."""
        return None

    def max_return(self) -> Optional[float]:
        """The most an episode can return, where the task declares it; else None."""
        return None

    def declared_randomize(self) -> str:
        """The domain randomization the task declares (envs/randomization.py's text; '' for none)."""
        return ""

    def check_randomizer(self) -> None:
        """RandomizeError (one line) unless the task brings its own domain randomizer (randomize 'playground')."""
        raise RandomizeError(f"randomize: 'playground' (a Playground environment's own randomizer) applies to "
                             f"playground:<Name> tasks, not {self.name!r}; give model scales instead")

    def c_definition(self) -> "Optional[Task]":
        """The task definition backend 'c' steps (whose per-simulation model variants it can step), or None."""
        return None

    def mujoco_c_label(self) -> str:
        """What runs the task in MuJoCo C, for report lines."""
        return "MuJoCo C" if self.builtin else "MuJoCo C (your task)"

    def make_mjx(self) -> "Env":
        """The unwrapped single-env Brax environment on MJX (envs.make_base adds the physics options)."""
        raise NotImplementedError

    def mjx_env(self) -> "Env":
        """make_mjx() as envs.make_base builds it: without Brax's "not actively maintained" notice, and with
        jax.devices() naming this process's devices (envs/task_mjx.py's process_local_devices)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # brax's notice, once per env
            with mjx_side().task_mjx.process_local_devices():
                return self.make_mjx()

    def make_c_backend(self, physics: Physics) -> "Env":
        """The unwrapped env stepped by MuJoCo C inside the program (envs/c_backend.py)."""
        raise ValueError(f"physics backend 'c' does not step {self.name!r} (it steps every task definition, Brax's "
                         "hopper, walker2d, halfcheetah and ant, and allegro_cylinder); it runs on backend 'mjx'")

    def make_c(self) -> Any:
        """The task on one MjData in plain MuJoCo C: reset(seed) -> obs, step(action) -> (obs, reward, done)."""
        raise ValueError(f"no MuJoCo C version of {self.name!r}: MuJoCo C runs every task definition (envs/task.py), "
                         "Brax's hopper, walker2d, halfcheetah and ant, and allegro_cylinder")

    def new(self) -> "Task":
        """A new instance of the task definition (envs/task.py's Task) behind the record."""
        raise ValueError(f"{self.name!r} is not a task definition (envs/task.py) but a {self.family} task")

    def observation_layout(self) -> list:
        """One short description per observation entry (exported controllers' docs)."""
        raise NotImplementedError

    def source(self) -> dict:
        """What says which code defines the task (recorded in config.json and sweep.json)."""
        return {"task": self.name, "builtin": True}
