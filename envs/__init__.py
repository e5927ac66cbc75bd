"""Environment registry: `envs.make(name)` returns a single-env Brax environment (reset(key), step(state, action))
with a time limit and auto-reset; batch it with jax.vmap.

Tasks: Brax's MJX variants of the gym MuJoCo benchmarks used in the paper's Figure 1 (BRAX_TASKS),
`allegro_cylinder`, our MJX port of the paper's Allegro-hand tactile task (envs/allegro.py), and
gymnasium's own v5 tasks (GYM_V5_TASKS, gymnasium's ids: envs/gym_v5.py; MJX: envs/gym_v5_mjx.py).
"""

import contextlib
import io
import os
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


def check_name(name):
    if name not in NAMES:
        raise ValueError(f"unknown env {name!r}; choose one of {', '.join(NAMES)}")


def check_backend(name, physics):
    """ValueError if `physics` (envs.physics.Physics) cannot step task `name`."""
    check_name(name)
    physics.validate()
    if physics.backend == "c" and name not in C_BACKEND_TASKS:
        raise ValueError(f"physics backend 'c' runs {', '.join(C_BACKEND_TASKS)}; {name!r} runs on backend 'mjx'")


def default_episode_length(name):
    check_name(name)
    if name == "allegro_cylinder":
        from envs.allegro_task import DEFAULT_EPISODE_LENGTH as allegro_length  # 2 s at 100 Hz; no JAX import

        return allegro_length
    return DEFAULT_EPISODE_LENGTH


def task_model(name):
    """The MuJoCo C model (MjModel) of a task's MJCF with the solver options its MJX version steps with
    (Brax's for the gym tasks), loaded without JAX or MJX: for sizes and physics records."""
    import mujoco

    from envs import mujoco_c

    check_name(name)
    if name in GYM_V5_TASKS:
        from envs import gym_v5

        return gym_v5.make_task(name).model
    if name in mujoco_c.C_TASKS:
        return mujoco_c.make_c(name).model
    return mujoco.MjModel.from_xml_path(mujoco_c.brax_asset(name + ".xml"))


def action_size(name):
    """Actions of a task, read from its MJCF (no MJX environment is built)."""
    return int(task_model(name).nu)


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
        elif name in GYM_V5_TASKS:
            from envs.gym_v5_mjx import GymV5Mjx

            env = GymV5Mjx(name)
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
