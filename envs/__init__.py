"""Tasks by name: `envs.make(name)` returns a single-env Brax environment (reset(key), step(state, action))
with a time limit and auto-reset; batch it with jax.vmap. A name is resolved once per process into its record
(`resolve(name)`: envs/registry.py), which holds everything about the task; the functions
here read it.

Tasks: Brax's MJX variants of the gym MuJoCo benchmarks used in the paper's Figure 1 (BRAX_TASKS),
`allegro_cylinder`, our MJX port of the paper's Allegro-hand tactile task (envs/allegro.py), and every task
definition (envs/task.py): gymnasium's own v5 tasks (GYM_V5_TASKS, gymnasium's ids: envs/v5_tasks.py), the
DeepMind Control Suite's (DMC_TASKS, 'dmc:<domain>-<task>': envs/dmc/, with dm_control installed), the
tasks registered with `register(name, factory)`, and a user's task named by where it is defined,
'my_pkg.my_module:MyTask' or 'path/to/file.py:MyTask'. A task definition runs on both backends (MJX:
envs/task_mjx.py; MuJoCo C in the program: envs/c_backend.py) and in plain MuJoCo C (envs.task.TaskC).

This module only re-exports, lazily (a name's module is imported on its first use): the names and shared constants live in envs/names.py, name resolution and what a
name says (sizes, bounds, time limit, source) in envs/registry.py, the families' records in envs/families/, building
environments in envs/build.py. No module of envs/ imports this one back.
"""

import importlib
import os

# No renderer is needed for training. mujoco picks its GL backend when it is first imported, so
# gsa_jax.render (which does need one) sets MUJOCO_GL itself unless the user did: nothing here imports
# mujoco before a function is called.
GL_FROM_USER = "MUJOCO_GL" in os.environ
os.environ.setdefault("MUJOCO_GL", "disable")

from envs import mjx_import  # noqa: E402

mjx_import.install()  # mujoco.mjx without its NVIDIA-only warp backend (envs/mjx_import.py)

# Every name below is loaded on first use (PEP 562), so `import envs.errors` (the user-error base gsa_jax/errors.py
# re-exports) loads nothing else: {name: the module of envs/ that defines it}.
_LAZY = {
    **dict.fromkeys(("as_gymnasium", "check_backend", "check_randomize", "make", "make_base", "solver_settings"),
                    "envs.build"),
    **dict.fromkeys(("ACTION_RANGE", "BRAX_TASKS", "DEFAULT_EPISODE_LENGTH", "DMC_TASKS", "GYM_V5_TASKS", "NAMES",
                     "RESET_MODES"), "envs.names"),
    **dict.fromkeys(("mj_model", "substeps"), "envs.physics"),
    **dict.fromkeys(("action_bounds", "action_size", "check_name", "check_task", "control_range",
                     "default_episode_length", "has_c_backend", "is_name", "max_return", "observation_size", "register",
                     "resolve", "resolve_task", "task_model", "task_randomize", "task_source", "unregister"),
                    "envs.registry"),
}


def __getattr__(name: str):
    """A re-exported name (loaded from its module once, then kept here), or a submodule of envs/ (envs.task, ...)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    if name.startswith("_"):  # dunder and private lookups (copy, pickle, hasattr probes) import nothing
        raise AttributeError(f"module 'envs' has no attribute {name!r}")
    try:
        return importlib.import_module(f"envs.{name}")
    except ModuleNotFoundError as e:
        if e.name != f"envs.{name}":
            raise
        raise AttributeError(f"module 'envs' has no attribute {name!r}") from None


def __dir__() -> list:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "ACTION_RANGE", "BRAX_TASKS", "DEFAULT_EPISODE_LENGTH", "DMC_TASKS", "GL_FROM_USER", "GYM_V5_TASKS", "NAMES",
    "RESET_MODES", "action_bounds", "action_size", "as_gymnasium", "check_backend", "check_name", "check_randomize",
    "check_task", "control_range", "default_episode_length", "has_c_backend", "is_name", "make", "make_base",
    "max_return", "mj_model", "observation_size", "register", "resolve", "resolve_task", "solver_settings", "substeps",
    "task_model", "task_randomize", "task_source", "unregister",
]
