"""Environments built from task records (envs/registry.py): `make` (a time limit, auto-reset and, when asked, a
domain randomization around the task), `make_base` (the unwrapped task on MJX or backend 'c', as envs.physics.Physics
says) and the checks that need a backend. Loads without JAX: the wrappers are imported when an environment is made.
"""

import contextlib
import io
from typing import TYPE_CHECKING, Any, Optional

from envs import registry
from envs.families.record import mjx_side
from envs.physics import C, Physics, applied, mj_model, record
from envs.randomization import Randomize, RandomizeError, check_model, parse
from envs.registry import TaskLike

if TYPE_CHECKING:  # annotations only: Brax and gymnasium load when an environment is made
    import gymnasium
    from brax.envs.base import Env


def _wrappers():
    """envs/wrappers.py and envs/randomized_env.py (quietly: mujoco.mjx's "Failed to import warp" notice)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from envs import randomized_env, wrappers  # JAX and Brax: imported when an environment is first made

    return wrappers, randomized_env


def check_backend(name: TaskLike, physics: Physics) -> None:
    """ValueError if `physics` (envs.physics.Physics) cannot step task `name`."""
    task = registry.resolve(name)
    physics.validate()
    task.check_physics(physics)


def make_base(name: TaskLike, physics: Optional[Physics] = None) -> "Env":
    """The unwrapped task (no time limit, no auto-reset) `name` (a name or a TaskRecord), stepped as `physics`
    says (envs.physics.Physics; None: the defaults, MJX; backend 'c': MuJoCo C, envs/c_backend.py). An MJX
    task's reset and step run inside physics.applied, so the solver routing holds while they are traced and
    nothing else in the process changes.

    physics.solver_iterations / ls_iterations override opt.iterations / opt.ls_iterations in the MJX
    model only -- a cheaper but *different* simulator; the MuJoCo C model (mj_model(env), used by
    deploy, render and the bench's reference) keeps the MJCF's settings.
    """
    physics = physics or Physics()
    task = registry.resolve(name)
    check_backend(task, physics)
    if physics.backend == C:
        return task.make_c_backend(physics)
    env = task.mjx_env()
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
    def traced(*args, **kwargs):
        with applied(physics, model):
            return fn(*args, **kwargs)

    return traced


def solver_settings(env: "Env") -> dict:
    """Every physics option in force for a task made by make_base (envs.physics.record)."""
    return record(env.physics, mj_model(env))


def make(name: TaskLike, episode_length: Optional[int] = None, auto_reset: bool = True, physics: Optional[Physics] = None,
         reset_mode: str = "first", randomize: Any = None) -> "Env":
    """Task `name` (a name or a TaskRecord) with a time limit of `episode_length` steps (default: the task's own,
    `resolve(name).episode_length()`) and (by default) auto-reset: an ended episode restarts from the env's first
    start state (reset_mode 'first', Brax's convention) or from a new draw of the task's start law ('fresh',
    as gymnasium and dm_control reset; envs/wrappers.py). physics: see make_base. randomize: a domain
    randomization (envs/randomization.py: its text, a table or a Randomize; None or '': none) drawn per episode
    (envs/randomized_env.py); RandomizeError (one line) where the task or backend cannot apply it.

    state.info: 'steps', 'truncation' (1 when the time limit, not a termination, ended the
    episode), and with auto_reset 'final_obs' (the true last observation of the step).
    """
    wrappers, randomized_env = _wrappers()
    task = registry.resolve(name)
    if episode_length is None:
        episode_length = int(task.episode_length())
    if episode_length < 1:
        raise ValueError(f"episode_length must be >= 1, got {episode_length}")
    spec = check_randomize(task, randomize, episode_length, physics)
    base = make_base(task, physics)
    env = wrappers.EpisodeLimit(base, episode_length)
    env = wrappers.AutoReset(env, reset_mode) if auto_reset else env
    if spec is None:
        return env
    return randomized_env.Randomized(env, base, spec)


def check_randomize(name: TaskLike, randomize: Any, episode_length: Optional[int] = None,
                    physics: Optional[Physics] = None) -> Optional[Randomize]:
    """The Randomize of `randomize` (envs/randomization.py) checked against task `name`'s model and the backend of
    `physics` (None: MJX), or None for none; RandomizeError (one line) for an unknown parameter, a range out of
    bounds, a delay as long as the episode, or model scales or pushes the backend cannot apply (saying which can).
    Builds no environment."""
    spec = parse(randomize)
    if not spec.scales and spec.is_nominal:
        return None
    task = registry.resolve(name)
    check_model(spec, task.model(), episode_length)
    if spec.registry:
        task.check_randomizer()
    if spec.model_fields or spec.push:
        reason = _variant_reason(task, "mjx" if physics is None else physics.backend, spec)
        if reason:
            raise RandomizeError(f"randomize: {reason}; obs_noise and delay apply everywhere")
    return spec


def _variant_reason(task, backend, spec):
    """Why model scales or pushes cannot run for this task on this backend (None: they can)."""
    if backend == C:
        definition = task.c_definition()
        if definition is None or definition.post_constraint:
            why = "its steps run mj_rnePostConstraint outside mujoco.batch" if definition else "its host steps no variants"
            return (f"{task.name} takes no per-simulation model on backend 'c' ({why}); its model scales and pushes "
                    "run on MJX (--physics mjx)")
        return None
    if not task.mjx_variants:
        return f"{task.name} is not a Brax PipelineEnv; model scales and pushes apply to task definitions and Brax's envs"
    have = mjx_side().task_mjx.mjx_model_fields()
    missing = [f for f, _, _ in spec.model_fields if f not in have]
    if missing:
        return f"MJX's model has no field {missing[0]}; backend 'c' (--physics c) scales any float MjModel field"
    return None


def as_gymnasium(task: TaskLike) -> "gymnasium.Env":
    """A gymnasium.Env of `task` (a name, a Task subclass or instance) stepped by its MuJoCo C twin, with the task's
    start law, observation, reward, termination and time limit (envs/gymnasium_wrapper.py); ValueError (one line) for a
    task MuJoCo C does not step. Needs gymnasium (the deploy extra)."""
    found = registry.resolve(task)
    if not found.has_c:
        raise ValueError(f"task {found.name!r} has no MuJoCo C version, so no gymnasium environment: MuJoCo C runs "
                         "every task definition, Brax's hopper, walker2d, halfcheetah and ant, and allegro_cylinder")
    from envs.gymnasium_wrapper import TaskEnv  # gymnasium: an optional extra (deploy)

    return TaskEnv(found)
