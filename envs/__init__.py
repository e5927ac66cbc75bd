"""Environment registry: `envs.make(name)` returns a single-env Brax environment (reset(key), step(state, action))
with a time limit and auto-reset; batch it with jax.vmap.

Tasks: Brax's MJX ports of the gym MuJoCo benchmarks used in the paper's Figure 1, and
`allegro_cylinder`, our MJX port of the paper's Allegro-hand tactile task (envs/allegro.py).
"""

import contextlib
import io
import os
import warnings

# No renderer is needed for training. mujoco picks its GL backend when it is first imported, so
# envs.render (which does need one) sets MUJOCO_GL itself unless the user did: nothing here imports
# mujoco before a function is called.
GL_FROM_USER = "MUJOCO_GL" in os.environ
os.environ.setdefault("MUJOCO_GL", "disable")

BRAX_TASKS = ("inverted_double_pendulum", "hopper", "halfcheetah", "walker2d", "ant")
NAMES = BRAX_TASKS + ("allegro_cylinder",)
DEFAULT_EPISODE_LENGTH = 1000


def check_name(name):
    if name not in NAMES:
        raise ValueError(f"unknown env {name!r}; choose one of {', '.join(NAMES)}")


def default_episode_length(name):
    check_name(name)
    if name == "allegro_cylinder":
        from envs.allegro_task import DEFAULT_EPISODE_LENGTH as allegro_length  # 2 s at 100 Hz; no JAX import

        return allegro_length
    return DEFAULT_EPISODE_LENGTH


def default_linesearch():
    """The MJX solver's line search where a task allows a choice (envs/linesearch.py): 'exact', or MJX's
    'iterative' one with GSA_JAX_ITERATIVE_LINESEARCH=1. No JAX or MuJoCo import."""
    return "iterative" if os.environ.get("GSA_JAX_ITERATIVE_LINESEARCH", "") not in ("", "0") else "exact"


def check_solver(solver_iterations=None, ls_iterations=None):
    for field, v in (("solver_iterations", solver_iterations), ("ls_iterations", ls_iterations)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise ValueError(f"{field} must be an integer >= 1 (or None: the task's own), got {v!r}")


def make_base(name, solver_iterations=None, ls_iterations=None):
    """The unwrapped task (no time limit, no auto-reset).

    solver_iterations / ls_iterations: None keeps the task's own MJCF settings (hopper: Newton, 4
    iterations, 50 line-search iterations). An integer overrides MuJoCo's opt.iterations /
    opt.ls_iterations in the MJX model only -- a cheaper but *different* simulator (less converged
    contact forces), i.e. a changed task; the MuJoCo C model (mj_model(env), used by deploy, render
    and the bench's reference) keeps the MJCF's settings. See experiments/README.md (solver) for the
    measured effect on trajectories and returns.

    The solver's line search is exact where the model allows it (envs/linesearch.py) unless
    ls_iterations is given (a parameter of MJX's iterative search, which it then uses) or
    GSA_JAX_ITERATIVE_LINESEARCH=1; solver_settings(env)['linesearch'] says which.
    """
    check_name(name)
    check_solver(solver_iterations, ls_iterations)
    with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints "Failed to import warp" (a GPU-only backend)
        from brax import envs as brax_envs

        from envs import allegro, linalg, linesearch
    linalg.install()  # MJX's small Cholesky factor/solves without batched LAPACK (envs/linalg.py)
    linesearch.install()  # MJX's line search as a while loop, not a scan of no-op conds (envs/linesearch.py)
    with warnings.catch_warnings(), _process_local_devices():
        warnings.simplefilter("ignore", UserWarning)  # brax's "not actively maintained" notice, once per env
        env = allegro.AllegroCylinder() if name == "allegro_cylinder" else brax_envs.get_environment(name, backend="mjx")
    override = {k: v for k, v in (("opt.iterations", solver_iterations), ("opt.ls_iterations", ls_iterations)) if v is not None}
    if override:
        env.sys = env.sys.tree_replace(override)
    mode = "iterative" if ls_iterations is not None or not linesearch.exact_applies(env.sys) else default_linesearch()
    env.linesearch_mode = mode
    for name in ("reset", "step"):  # the solver is traced inside these: route its line search
        setattr(env, name, _traced_with(getattr(env, name), mode))
    return env


def _traced_with(fn, mode):
    from envs import linesearch

    def traced(*args, **kwargs):
        with linesearch.using(mode):
            return fn(*args, **kwargs)

    return traced


def solver_settings(env):
    """{'iterations', 'ls_iterations', 'linesearch'} of the MJX model a task made by make_base steps
    with ('linesearch': 'exact' or MJX's 'iterative', see make_base), and the MJCF's own
    ('task_iterations', 'task_ls_iterations')."""
    opt, own = env.sys.opt, mj_model(env).opt
    return {"iterations": int(opt.iterations), "ls_iterations": int(opt.ls_iterations),
            "linesearch": env.linesearch_mode,
            "task_iterations": int(own.iterations), "task_ls_iterations": int(own.ls_iterations)}


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


def make(name, episode_length=None, auto_reset=True, solver_iterations=None, ls_iterations=None):
    """Task `name` with a time limit of `episode_length` steps (default: the task's own,
    `default_episode_length(name)`) and (by default) Brax-style auto-reset. solver_iterations,
    ls_iterations: see make_base (None: the task's own).

    state.info: 'steps', 'truncation' (1 when the time limit, not a termination, ended the
    episode), and with auto_reset 'final_obs' (the true last observation of the step).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        from envs.wrappers import AutoReset, EpisodeLimit
    if episode_length is None:
        episode_length = default_episode_length(name)
    if episode_length < 1:
        raise ValueError(f"episode_length must be >= 1, got {episode_length}")
    env = EpisodeLimit(make_base(name, solver_iterations, ls_iterations), episode_length)
    return AutoReset(env) if auto_reset else env
