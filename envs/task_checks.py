"""Checks of a task definition (envs/task.py's Task), each failing in one line that names where the task was
defined: validate (it can be stepped: actions, start noise, frame skip, derived fields, a finite first observation,
outcome's shapes; NumPy only) and check_jax_agrees (its jax.numpy functions give NumPy's values), before anything
compiles. The task registry runs them when it builds a task definition (envs/families/task_definition.py)."""

import numbers
from typing import Any

import mujoco
import numpy as np

from envs.task import Task, TaskC, TaskError


DERIVED_AFTER = ("step", "step1")  # when derived fields are read (Task.derived_after)
POST_CONSTRAINT_FIELDS = ("cacc", "cfrc_int", "cfrc_ext")  # MjData fields only mj_rnePostConstraint computes


def validate(task: Task, where: str) -> None:
    """TaskError (one line, naming `where`) unless the definition can be stepped: actions, start noise shapes,
    the frame skip and episode length, derived fields, a finite first observation [d], and outcome's observation,
    reward and termination of the right shapes (NumPy only; check_jax_agrees adds jax.numpy). An error raised by
    the task's own functions is reported in one line too."""
    try:
        _validate(task, where)
    except TaskError:
        raise
    except Exception as e:
        raise TaskError(f"{where}: stepping it failed: {type(e).__name__}: {' '.join(str(e).split())}") from None


def _validate(task, where):
    m = task.model
    unknown = [f for f in task.derived if not hasattr(mujoco.MjData(m), f)]
    if unknown:
        raise TaskError(f"{where}: derived names {unknown}, which are not MjData fields")
    needs = [f for f in task.derived if f in POST_CONSTRAINT_FIELDS]
    if needs and not task.post_constraint:
        raise TaskError(f"{where}: derived {needs} are computed by mj_rnePostConstraint: set post_constraint = True")
    if m.nu < 1:
        raise TaskError(f"{where}: the model has no actuators (action size 0); a task needs at least one")
    if task.ctrl_range not in ("unit", "model"):
        raise TaskError(f"{where}: ctrl_range must be 'unit' or 'model', got {task.ctrl_range!r}")
    unlimited = np.flatnonzero(~m.actuator_ctrllimited.astype(bool))
    if task.ctrl_range == "model" and len(unlimited):
        raise TaskError(f"{where}: ctrl_range 'model' maps actions onto each actuator's ctrlrange, but actuator "
                        f"{m.actuator(int(unlimited[0])).name or int(unlimited[0])} has none (ctrllimited false)")
    limited = np.flatnonzero(m.actuator_ctrllimited.astype(bool) & np.any(m.actuator_ctrlrange != [-1.0, 1.0], axis=1))
    if task.ctrl_range == "unit" and len(limited):
        raise TaskError(f"{where}: actuator {m.actuator(int(limited[0])).name or int(limited[0])} has ctrlrange "
                        f"{m.actuator_ctrlrange[limited[0]].tolist()}; the policy's actions lie in [-1, 1]: give every "
                        "actuator ctrlrange=\"-1 1\" and scale it with gear")
    body = task.push_body
    if not ((isinstance(body, str) and mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body) >= 0)
            or (isinstance(body, numbers.Integral) and 0 < body < m.nbody)):
        raise TaskError(f"{where}: push_body {task.push_body!r} is not a body of the model (a name, or an index in 1 .. "
                        f"{m.nbody - 1})")
    for field, size in (("noise", m.nq), ("vel_noise", m.nv), ("init_qpos", m.nq)):
        v = getattr(task, field)
        if v is not None and np.ndim(v) > 0 and np.shape(v) != (size,):
            raise TaskError(f"{where}: {field} has shape {np.shape(v)}; use a scalar or [{size}]")
    check_hold_fields(task, where)
    for field in ("qpos_noise", "qvel_noise"):
        if getattr(task, field) not in ("uniform", "normal"):
            raise TaskError(f"{where}: {field} must be 'uniform' or 'normal', got {getattr(task, field)!r}")
    if task.derived_after not in DERIVED_AFTER:
        raise TaskError(f"{where}: derived_after must be one of {DERIVED_AFTER}, got {task.derived_after!r}")
    if task.post_constraint and (task.derived_after == "step1" or task.has_initialize or task.goal_size):
        raise TaskError(f"{where}: post_constraint cannot be combined with derived_after 'step1', initialize() or a goal")
    if task.goal_size and not task.has_initialize:
        raise TaskError(f"{where}: goal_size {task.goal_size} needs an initialize() that returns the goal")
    if int(task.frame_skip) < 1 or int(task.episode_length) < 1:
        raise TaskError(f"{where}: frame_skip and episode_length must be >= 1")
    c = TaskC(task)
    c.reset(0)
    d = c.data
    obs = check_rows(where, "observe()", "observation", task.observe(d.qpos[None], d.qvel[None], c._derived()), 2)[0]
    if not np.all(np.isfinite(obs)):
        raise TaskError(f"{where}: the first observation must be finite; it has non-finite entries at "
                        f"{np.flatnonzero(~np.isfinite(obs)).tolist()}")
    after, reward, terminated = task.outcome(task.before(d.qpos[None], c._derived()), d.qpos[None], d.qvel[None],
                                             c._derived(), np.zeros((1, m.nu)))
    if np.shape(after) != (1,) + obs.shape:
        raise TaskError(f"{where}: outcome() must return obs [n, {obs.size}] (as observe()); got shape "
                        f"{np.shape(after)} for n = 1")
    if not np.all(np.isfinite(check_rows(where, "outcome()", "reward", reward, 1))):
        raise TaskError(f"{where}: outcome() returned the reward {np.asarray(reward).tolist()} at the first state under "
                        "zero action; a reward must be finite on every step")
    check_rows(where, "outcome()", "terminated", terminated, 1, kind="b")


KINDS = {"f": "a float array", "b": "a bool array (e.g. a comparison, or xp.zeros(n, bool))"}


def check_hold_fields(task: Task, where: str) -> None:
    """TaskError (one line) unless equilibrium_qpos is None or nq finite numbers and convergence_tolerance None, one
    number > 0 or 2 nv of them: what gsa verify reads, checked where every command first loads the task."""
    m, q = task.model, task.equilibrium_qpos
    if q is not None and (np.shape(q) != (m.nq,) or not np.all(np.isfinite(np.asarray(q, np.float64)))):
        raise TaskError(f"{where}: equilibrium_qpos has shape {np.shape(q)}; it is the qpos held, nq = {m.nq} finite "
                        f"numbers (qpos: {', '.join(joint_names(m)) or 'none'}), or None")
    tol = task.convergence_tolerance
    if tol is not None and (np.shape(tol) not in ((), (2 * m.nv,)) or not np.all(np.asarray(tol, np.float64) > 0)):
        raise TaskError(f"{where}: convergence_tolerance has shape {np.shape(tol)}; give one number > 0 or 2 nv = "
                        f"{2 * m.nv} of them (positions, then velocities), or None")


def joint_names(m: mujoco.MjModel) -> list:
    """Each joint's name with the qpos entries it holds ('slider', 'hinge', 'free (7)'), in qpos order."""
    widths = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}
    out = []
    for j in range(m.njnt):
        width, name = widths.get(int(m.jnt_type[j]), 1), m.joint(j).name or f"joint {j}"
        out.append(name if width == 1 else f"{name} ({width})")
    return out


def check_rows(where: str, function: str, what: str, value: Any, ndim: int, kind: str = "f") -> np.ndarray:
    """`value` as an array [1, ...] of ndim dimensions (one row per simulation; here n = 1) of dtype kind 'f' (float)
    or 'b' (bool); else TaskError naming the function, its shape and its dtype."""
    a = np.asarray(value)
    shape = "[n, d]" if ndim == 2 else "[n]"
    if a.ndim != ndim or a.shape[0] != 1:
        raise TaskError(f"{where}: {function} must return the {what} as {shape}, one row per simulation; got shape "
                        f"{a.shape} ({a.dtype}) for n = 1" + (" -- a single [d] vector?" if a.ndim == ndim - 1 else ""))
    if a.dtype.kind != kind and not (kind == "f" and a.dtype.kind in "iu"):
        raise TaskError(f"{where}: {function} must return the {what} as {KINDS[kind]}; got {a.dtype} {list(a.shape)}")
    return a


def check_jax_agrees(task: Task, where: str) -> None:
    """TaskError unless observe(), before() and outcome() trace with jax.numpy inside jax.jit (as both backends
    call them) and the first observation equals NumPy's (shape; values to float32 rounding)."""
    import jax  # JAX: this module loads without it (deployment steps tasks with no JAX)

    jnp = jax.numpy
    c = TaskC(task)
    obs = np.asarray(c.reset(0))
    d = c.data
    qpos, qvel = jnp.asarray(d.qpos[None], jnp.float32), jnp.asarray(d.qvel[None], jnp.float32)
    derived = {f: jnp.asarray(v, jnp.float32) for f, v in c._derived().items()}
    action = jnp.zeros((1, task.model.nu), jnp.float32)
    try:
        got = np.asarray(jax.jit(lambda q, v, x: task.observe(q, v, x, jnp))(qpos, qvel, derived))
        jax.eval_shape(lambda q, v, x, a: task.outcome(task.before(q, x, jnp), q, v, x, a, jnp), qpos, qvel, derived, action)
    except Exception as e:
        raise TaskError(f"{where}: its functions do not run with jax.numpy under jax.jit ({type(e).__name__}: "
                        f"{' '.join(str(e).split())[:200]}); write them with xp (the module passed in) only") from None
    if got.shape != (1,) + obs.shape:
        raise TaskError(f"{where}: observe() gives shape {got.shape[1:]} with jax.numpy but {obs.shape} with NumPy; "
                        "write it with xp (the module passed in) only")
    if not np.allclose(got[0], obs, rtol=1e-4, atol=1e-4):
        worst = int(np.argmax(np.abs(got[0] - obs)))
        raise TaskError(f"{where}: observe() differs between NumPy and jax.numpy at entry {worst} ({obs[worst]} vs "
                        f"{got[0, worst]}); write it with xp (the module passed in) only")
