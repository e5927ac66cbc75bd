"""Physics options: what steps a task, chosen when the task is made and recorded with every result.

    physics = Physics(linesearch="exact", cholesky="unrolled")      # the defaults (MJX)
    env = envs.make("hopper", physics=physics)
    env = envs.make("hopper", physics=Physics(backend="c"))          # MuJoCo C inside the program

The options change the compiled program (they are static, like the network sizes):
- backend: 'mjx' (the default; what accelerators run) or 'c' (envs/c_backend.py: MuJoCo C stepped from
  inside the compiled program through a host call (envs/host_call.py), on `threads` threads per process (0: the process's
  share of the cores, resolve_threads);
  the CPU speed path, for hopper, walker2d, halfcheetah, ant and allegro_cylinder). The options below are MJX's.
- solver_iterations / ls_iterations: None keeps the task's own MJCF settings; an integer overrides
  MuJoCo's opt.iterations / opt.ls_iterations in the MJX model only -- a cheaper but *different*
  simulator (a changed task; experiments/solver_hopper/).
- linesearch: 'exact' (envs/linesearch.py: the line cost's minimiser computed directly; used where the
  model allows it -- pyramidal cones, no friction loss -- and ls_iterations is not set) or MJX's
  'iterative' search.
- search_loop: MJX's iterative search as a 'while' loop (stops at the batch's slowest env; bitwise the
  same iterates) or MJX's own 'scan' of conds.
- cholesky: 'unrolled' (envs/linalg.py: small factorizations as elementwise ops) or 'lapack'.

Nothing is patched as a side effect of making a task: `applied(physics, model)` routes MJX's solver
and jax.scipy's Cholesky for the duration of a block, and envs.make_base wraps the task's reset and
step in it, so they take effect exactly while those functions run (are traced) and are restored after.
No JAX or MuJoCo import at module level.
"""

import contextlib
import dataclasses
import os
from typing import TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:  # annotations only: this module loads without MuJoCo
    import mujoco

MJX, C = "mjx", "c"  # the physics backends, named once
BACKENDS = (MJX, C)
LINESEARCHES = ("exact", "iterative")
SEARCH_LOOPS = ("while", "scan")
CHOLESKYS = ("unrolled", "lapack")
# set by gsa_jax.running.supervise for the worker processes it starts: how many of them share this host's cores
LOCAL_WORKERS_ENV = "GSA_LOCAL_WORKERS"


@dataclasses.dataclass(frozen=True)
class Physics:
    """Static physics options of a task (see the module docstring). A field's metadata names its command-line
    option (gsa_jax/algorithm/config.py reads it)."""

    solver_iterations: int | None = dataclasses.field(default=None, metadata={
        "flag": "--solver-iterations", "help": "MJX constraint-solver iterations (default: the task's own; hopper 4). "
        "Fewer is faster but a changed simulator -- see experiments/solver_hopper/"})
    ls_iterations: int | None = dataclasses.field(default=None, metadata={
        "flag": "--ls-iterations",
        "help": "MJX line-search iterations per solver iteration (default: the task's own; hopper 50)"})
    linesearch: str = dataclasses.field(default="exact", metadata={
        "flag": "--linesearch", "choices": LINESEARCHES,
        "help": "MJX solver line search: exact where the model allows it (default), or MJX's iterative one"})
    search_loop: str = "while"
    cholesky: str = dataclasses.field(default="unrolled", metadata={
        "flag": "--cholesky", "choices": CHOLESKYS,
        "help": "MJX's small Cholesky factorizations: unrolled elementwise ops (default) or LAPACK"})
    backend: str = dataclasses.field(default=MJX, metadata={
        "flag": "--physics", "choices": BACKENDS,
        "help": "physics backend: MJX (default; what accelerators run) or MuJoCo C stepped from inside the compiled "
        "program (the CPU speed path; every task but Brax's inverted_double_pendulum)"})
    threads: int = dataclasses.field(default=0, metadata={
        "flag": "--physics-threads",
        "help": "--physics c: MuJoCo C threads in this process (default 0: its share of the cores)"})

    def validate(self) -> "Physics":
        """Raise ValueError naming the bad field."""
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 0:
            raise ValueError(f"threads must be an integer >= 0 (0: this process's share of the cores), got {self.threads!r}")
        if self.backend == C and (self.solver_iterations is not None or self.ls_iterations is not None):
            raise ValueError("solver_iterations and ls_iterations change MJX's model only; backend 'c' steps the "
                             "task's own MJCF settings")
        for field in ("solver_iterations", "ls_iterations"):
            v = getattr(self, field)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise ValueError(f"{field} must be an integer >= 1 (or None: the task's own), got {v!r}")
        for field, allowed in (("linesearch", LINESEARCHES), ("search_loop", SEARCH_LOOPS), ("cholesky", CHOLESKYS)):
            if getattr(self, field) not in allowed:
                raise ValueError(f"{field} must be one of {', '.join(allowed)}, got {getattr(self, field)!r}")
        return self


# where records written before the physics options were one record (config.json, sweep.json, exported controllers,
# experiment files) kept them: {flat Config field: Physics field}
FLAT_CONFIG_FIELDS = {"solver_iterations": "solver_iterations", "ls_iterations": "ls_iterations",
                      "linesearch": "linesearch", "search_loop": "search_loop", "cholesky": "cholesky",
                      "backend": "backend", "physics_threads": "threads"}


def make_physics(fields: dict) -> Physics:
    """Physics from a dict of its fields (config.json's, an experiment file's [config.physics]); an unknown
    field is a ValueError naming the allowed ones. Not validated (Physics.validate)."""
    allowed = [f.name for f in dataclasses.fields(Physics)]
    unknown = sorted(set(fields) - set(allowed))
    if unknown:
        raise ValueError(f"unknown physics option {unknown[0]!r}; allowed: {', '.join(allowed)}")
    return Physics(**fields)


def nest_physics(config: dict) -> dict:
    """A config record with its physics options as one record, config['physics'] ({Physics field: value}): the
    flat fields of records written before (FLAT_CONFIG_FIELDS) moved into it. A field set both ways is a
    ValueError. The input is not changed."""
    flat = {k: config[k] for k in FLAT_CONFIG_FIELDS if k in config}
    nested = config.get("physics", {})
    if isinstance(nested, Physics):
        nested = dataclasses.asdict(nested)
    if not isinstance(nested, dict):
        raise ValueError(f"physics must be a table of physics options, got {nested!r}")
    both = [k for k in flat if FLAT_CONFIG_FIELDS[k] in nested]
    if both:
        raise ValueError(f"{both[0]} is set both as a config field and as physics.{FLAT_CONFIG_FIELDS[both[0]]}; "
                         "set it once, in physics")
    out = {k: v for k, v in config.items() if k not in flat}
    if flat or "physics" in config:
        out["physics"] = {**nested, **{FLAT_CONFIG_FIELDS[k]: v for k, v in flat.items()}}
    return out


def record_backend(config: dict) -> str:
    """The physics backend a config record names, in either layout (nest_physics); MJX where it names none."""
    return nest_physics(config).get("physics", {}).get("backend", MJX)


def resolve_threads(threads: int) -> int:
    """MuJoCo C threads for backend 'c' in this process: `threads`, or for 0 this process's share of the
    cores it may run on -- divided among the worker processes a sweep or bench started on this host
    (LOCAL_WORKERS_ENV), so that workers do not oversubscribe the cores. Results are the same at any count."""
    if threads:
        return int(threads)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        workers = max(1, int(os.environ.get(LOCAL_WORKERS_ENV, "1")))
    except ValueError:
        workers = 1
    return max(1, cores // workers)


def exact_applies(mj_model: "mujoco.MjModel") -> bool:
    """Whether the solver cost along a line is piecewise quadratic for this MjModel: pyramidal cones and
    no friction loss (the exact line search's condition)."""
    import mujoco  # this module loads without MuJoCo (it is read before `import envs` may load it)

    disabled = bool(mj_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    frictionloss = (bool((mj_model.dof_frictionloss > 0).any()) or bool((mj_model.tendon_frictionloss > 0).any())) and not disabled
    return int(mj_model.opt.cone) == int(mujoco.mjtCone.mjCONE_PYRAMIDAL) and not frictionloss


def linesearch_in_force(physics: Physics, mj_model: "mujoco.MjModel") -> str:
    """'exact' or 'iterative': the line search a task with this MjModel steps with under `physics`."""
    exact = physics.linesearch == "exact" and physics.ls_iterations is None and exact_applies(mj_model)
    return "exact" if exact else "iterative"


def record(physics: Physics, mj_model: "mujoco.MjModel") -> dict:
    """Every physics option in force, as written to config.json / sweep.json: the options, the line
    search they resolve to for this model (MuJoCo C's own for backend 'c'), and the MJCF's own solver
    settings."""
    own = mj_model.opt
    search = linesearch_in_force(physics, mj_model) if physics.backend == MJX else "mujoco_c"
    return {**dataclasses.asdict(physics), "linesearch_in_force": search,
            "iterations_in_force": physics.solver_iterations or int(own.iterations),
            "task_iterations": int(own.iterations), "task_ls_iterations": int(own.ls_iterations)}


@contextlib.contextmanager
def applied(physics: Physics, mj_model: "mujoco.MjModel") -> Iterator[None]:
    """Inside this block MJX's solver and jax.scipy's Cholesky run as `physics` says for a task with this
    MjModel; the previous routing is restored on exit (blocks nest)."""
    from envs import linalg, linesearch  # JAX and MJX: this module loads without them

    mode = linesearch_in_force(physics, mj_model)
    with linalg.routed(physics.cholesky == "unrolled"), linesearch.routed(mode, physics.search_loop):
        yield


def mj_model(env: Any) -> "mujoco.MjModel":
    """The MuJoCo C model (MjModel) behind a task made by envs.make_base: ours or a Brax MJX env."""
    return env.mj_model if hasattr(env, "mj_model") else env.sys.mj_model


def substeps(env: Any) -> int:
    """Physics steps per env step of a task made by envs.make_base."""
    return int(getattr(env, "n_frames", None) or getattr(env, "_n_frames", 1))
