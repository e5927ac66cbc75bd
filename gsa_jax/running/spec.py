"""An experiment: the TOML file checked once into a frozen SweepSpec, and its grid of run groups.

A SweepSpec is validated at the edge (load_spec / check_spec) and passed whole; sweep.json stores
`spec.to_json()`, which is exactly the checked file (a field left out stays out, so a sweep's identity does
not change when a field is added to the format). The grid: one Group per compiled program, (env, policy) and
one per value of each listed GROUP_AXES field; its runs are table rows (dicts: env, policy, axes, K, seed,
run and the swept hyperparameters, whose names vary by experiment).
"""

import dataclasses
import itertools
import math
import os
import re
import tomllib
from typing import Callable, NamedTuple, NoReturn

import envs
from envs.physics import FLAT_CONFIG_FIELDS, Physics, nest_physics
from envs.randomization import parse as parse_randomize
from gsa_jax.algorithm.config import HPARAM_DEFAULTS, Config, check_hparam, for_task
from gsa_jax.algorithm.kinds import MIXTURE, POLICY_KINDS, VALUE_TARGETS
from gsa_jax.algorithm.partitions import PARTITIONS
from gsa_jax.algorithm.subpolicies import SUBPOLICY_KINDS
from gsa_jax.errors import UserError
from gsa_jax.running.metrics import EVALUATIONS_PER_RUN
from gsa_jax.running.trained import path_part

SPEC_FIELDS = ("name", "envs", "policies", "subpolicies", "partitions", "value_targets", "clusters", "cluster_multipliers", "seeds", "steps", "chunk",
               "eval_every", "eval_at", "eval_seed", "hparams", "hparam_sets", "config")
_STATIC_FIELDS = {f.name for f in dataclasses.fields(Config)} - {"env", "policy"}  # k_max: a floor (group_config)
# Static options a spec may list to compare (one compiled group each): (spec field, run column = Config field,
# the policy it applies to or None for every policy, allowed values). Absent from a spec: no column, no group.
GROUP_AXES = (("subpolicies", "subpolicy", MIXTURE, SUBPOLICY_KINDS), ("partitions", "partition", MIXTURE, tuple(PARTITIONS)),
              ("value_targets", "value_target", None, VALUE_TARGETS))
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
# runs per sequential sub-batch of a group's program (gsa_jax.running.programs; gsa sweep --run-batch), here where
# the commands' parsers read it without JAX; measured in experiments/bench_run_batch/
RUN_BATCH = 8


class SpecError(UserError, ValueError):
    pass


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A checked experiment. Lists are tuples; hparams {name: tuple of values}; config the static
    gsa_jax.algorithm.config.Config fields as written. None: the field is absent from the file (its default applies)."""

    name: str
    envs: tuple
    policies: tuple
    seeds: tuple
    steps: int
    hparams: dict
    config: dict
    clusters: tuple | None = None
    cluster_multipliers: tuple | None = None
    subpolicies: tuple | None = None
    partitions: tuple | None = None
    value_targets: tuple | None = None
    chunk: int | None = None
    eval_every: int | None = None
    eval_at: tuple | None = None  # env steps after whose chunk the deterministic controller is evaluated (eval_every's place)
    eval_seed: int | None = None
    hparam_sets: tuple | None = None  # ({name: value}, ...): configurations, each run with every hparams combination

    def to_json(self) -> dict:
        """The spec as sweep.json stores it: the file's fields (lists), absent ones left out."""
        out = {}
        for field in SPEC_FIELDS:
            v = getattr(self, field)
            if v is not None:
                out[field] = list(v) if isinstance(v, tuple) else v
        out["hparams"] = {k: list(v) for k, v in self.hparams.items()}
        if self.hparam_sets is not None:
            out["hparam_sets"] = [dict(c) for c in self.hparam_sets]
        return out

    def set_names(self) -> list[str]:
        """The hyperparameters the hparam_sets give (each set gives all of them)."""
        return list(self.hparam_sets[0]) if self.hparam_sets else []

    def run_hparam_names(self) -> list[str]:
        """Every hyperparameter a run row carries: the hparams table's and the sets'."""
        return list(self.hparams) + self.set_names()

    def swept_names(self) -> list[str]:
        """The hyperparameters with more than one value (a column each); with hparam_sets, 'hparam_set' (the
        set's index) and every name the sets give."""
        sets = ["hparam_set", *self.set_names()] if self.hparam_sets else []
        return [k for k, v in self.hparams.items() if len(v) > 1] + sets

    def id_columns(self) -> list[str]:
        """Columns that identify a run in runs.csv and the tidy metrics.csv."""
        axes = [column for field, column, _, _ in GROUP_AXES if getattr(self, field) is not None]
        return ["env", "policy", *axes, "K", "seed", "run", *self.swept_names()]

    def cluster_counts(self, env_name: str) -> list[int]:
        """K values of a mixture group: absolute, or ceil(m * action_dim) per multiplier (deduplicated, sorted)."""
        if self.clusters is not None:
            return sorted(set(self.clusters))
        d_a = envs.action_size(env_name)
        return sorted({cluster_count(m, d_a) for m in self.cluster_multipliers})


class Group(NamedTuple):
    """The runs one compiled program trains: rows of the grid with the same env, policy and axis values."""

    env: str
    policy: str
    runs: list


# ----------------------------------------------------------------------------------------------- checking
def load_spec(path: str) -> SweepSpec:
    """Read and check an experiment file (or a directory holding sweep.toml / <dir>.toml); errors name the
    file and the bad field."""
    if os.path.isdir(path):
        candidates = [os.path.join(path, n) for n in ("sweep.toml", os.path.basename(path.rstrip("/")) + ".toml")]
        path = next((c for c in candidates if os.path.exists(c)), path)
    return check_spec(read_toml(path, "experiment file"), source=path)


def read_toml(path: str, what: str) -> dict:
    """A TOML file's contents; SpecError in one line if it does not exist or does not parse."""
    if not os.path.exists(path):
        raise SpecError(f"{path}: no such {what}")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML: {e}") from None


def check_spec(raw: dict, source: str = "spec") -> SweepSpec:
    """A SweepSpec from a parsed experiment file (or sweep.json's 'spec'); SpecError names the bad field."""

    def bad(field, msg):
        raise SpecError(f"{source}: field '{field}': {msg}")

    unknown = set(raw) - set(SPEC_FIELDS) - {"randomize"}
    if unknown:
        bad(sorted(unknown)[0], f"unknown field; allowed: {', '.join(SPEC_FIELDS + ('randomize',))}")
    spec = dict(raw)
    if "randomize" in spec:
        spec["config"] = {**spec.get("config", {}), "randomize": randomize_text(spec.pop("randomize"), spec, bad)}
    spec.setdefault("name", os.path.splitext(os.path.basename(source))[0])
    if not isinstance(spec["name"], str) or not NAME_PATTERN.fullmatch(spec["name"]):
        bad("name", f"must be a plain name (letters, digits, '-', '_', '.'; not starting with '.' or '-'), got {spec['name']!r}")
    check_names(spec, bad)
    check_cluster_fields(spec, bad)
    spec["seeds"] = check_seeds(spec.get("seeds", 1), bad)
    check_counts(spec, bad)
    spec["hparams"] = check_hparams_table(spec.get("hparams", {}), bad)
    if "hparam_sets" in spec:
        spec["hparam_sets"] = check_hparam_sets(spec["hparam_sets"], spec["hparams"], bad)
    spec["config"] = check_config_table(spec.get("config", {}), spec["envs"], bad)
    check_group_axes(spec, bad)
    return SweepSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in spec.items()})


def randomize_text(table: dict | str, spec: dict, bad: Callable[[str, str], NoReturn]) -> str:
    """The [randomize] table (envs/randomization.py: {name: value}, a range as "lo:hi" or [lo, hi]) as Config's
    canonical text; it goes to config.randomize, which the file must not also set."""
    if "randomize" in spec.get("config", {}):
        bad("randomize", "set it either as a [randomize] table or as config.randomize, not both")
    if not isinstance(table, (dict, str)):
        bad("randomize", "must be a table, e.g. [randomize] mass = [0.9, 1.1]")
    try:
        return parse_randomize(table).text()
    except ValueError as e:
        bad("randomize", str(e))


def check_names(spec: dict, bad: Callable[[str, str], NoReturn]) -> None:
    """envs and policies: non-empty lists of known names (a single name becomes a list), in place."""
    for field in ("envs", "policies"):
        if field not in spec:
            bad(field, "missing")
        if isinstance(spec[field], str):
            spec[field] = [spec[field]]
        if not isinstance(spec[field], list) or not spec[field]:
            bad(field, "must be a non-empty list")
    for e in spec["envs"]:
        try:
            envs.check_name(e)
        except ValueError as err:
            bad("envs", str(err))
    for p in spec["policies"]:
        if p not in POLICY_KINDS:
            bad("policies", f"unknown policy {p!r}; choose from {', '.join(POLICY_KINDS)}")


def check_seeds(seeds: int | list, bad: Callable[[str, str], NoReturn]) -> list[int]:
    """seeds: a count (0..n-1) or a list of distinct non-negative integers -> list."""
    if isinstance(seeds, int):
        if seeds < 1:
            bad("seeds", f"must be >= 1 or a list of seeds, got {seeds}")
        seeds = list(range(seeds))
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        bad("seeds", "must be a count >= 1 or a list of non-negative integers")
    if len(set(seeds)) != len(seeds):
        bad("seeds", "repeats a seed")
    return seeds


def check_counts(spec: dict, bad: Callable[[str, str], NoReturn]) -> None:
    """steps, chunk, eval_every, eval_seed: integers in range."""
    if not isinstance(spec.get("steps"), int) or spec["steps"] < 1:
        bad("steps", f"must be a positive integer, got {spec.get('steps')!r}")
    if "chunk" in spec and (not isinstance(spec["chunk"], int) or spec["chunk"] < 1):
        bad("chunk", f"must be a positive integer, got {spec['chunk']!r}")
    for field in ("eval_every", "eval_seed"):
        if field in spec and (not isinstance(spec[field], int) or isinstance(spec[field], bool) or spec[field] < 0):
            bad(field, f"must be an integer >= 0, got {spec[field]!r}")
    if "eval_at" in spec:
        check_eval_at(spec, bad)


def check_eval_at(spec: dict, bad: Callable[[str, str], NoReturn]) -> None:
    """eval_at: a non-empty increasing list of env steps in [1, steps]; not beside eval_every."""
    at = spec["eval_at"]
    if "eval_every" in spec:
        bad("eval_at", "give eval_every or eval_at, not both")
    if (not isinstance(at, list) or not at or any(not isinstance(s, int) or isinstance(s, bool) for s in at)
            or any(b <= a for a, b in zip(at, at[1:]))):
        bad("eval_at", f"must be a non-empty increasing list of env steps, got {at!r}")
    if at[0] < 1 or at[-1] > spec["steps"]:
        bad("eval_at", f"env steps must lie in [1, steps = {spec['steps']}], got {at!r}")


def check_config_table(cfg: dict, env_names: list[str], bad: Callable[[str, str], NoReturn]) -> dict:
    """The [config] table: known static Config fields that every env's physics backend runs, the physics options
    one table ([config.physics]; the flat fields of files written before are moved into it: envs.physics.nest_physics)."""
    if not isinstance(cfg, dict):
        bad("config", "must be a table")
    for k in cfg:
        if k not in _STATIC_FIELDS and k not in FLAT_CONFIG_FIELDS:
            bad(f"config.{k}", f"unknown; allowed: {', '.join(sorted(_STATIC_FIELDS))} (physics: a table of "
                               f"{', '.join(f.name for f in dataclasses.fields(Physics))})")
    try:
        cfg = nest_physics(cfg)
        for e in env_names:
            task = envs.resolve(e)
            for_task(Config(env=e, **{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}), task).validate(task)
    except (ValueError, TypeError) as e:
        bad("config", str(e))
    return cfg


def check_cluster_fields(spec: dict, bad: Callable[[str, str], NoReturn]) -> None:
    """clusters / cluster_multipliers of a spec, normalized to lists in place."""
    if MIXTURE in spec["policies"]:
        if ("clusters" in spec) == ("cluster_multipliers" in spec):
            bad("clusters", "a mixture sweep needs exactly one of 'clusters' (absolute K) or 'cluster_multipliers' (K / action_dim)")
        if "clusters" in spec:
            ks = spec["clusters"] if isinstance(spec["clusters"], list) else [spec["clusters"]]
            if not ks or not all(isinstance(k, int) and k >= 1 for k in ks):
                bad("clusters", f"must be integers >= 1, got {spec['clusters']!r}")
            spec["clusters"] = ks
        else:
            ms = spec["cluster_multipliers"] if isinstance(spec["cluster_multipliers"], list) else [spec["cluster_multipliers"]]
            if not ms or not all(isinstance(m, (int, float)) and m > 0 for m in ms):
                bad("cluster_multipliers", f"must be positive numbers, got {spec['cluster_multipliers']!r}")
            spec["cluster_multipliers"] = ms


def check_group_axes(spec: dict, bad: Callable[[str, str], NoReturn]) -> None:
    """subpolicies / partitions / value_targets (GROUP_AXES) of a spec, normalized to lists in place; absent stays absent
    (a spec's identity, sweep.json, must not change)."""
    for field, column, policy, allowed in GROUP_AXES:
        if field not in spec:
            continue
        values = spec[field] if isinstance(spec[field], list) else [spec[field]]
        if policy is not None and policy not in spec["policies"]:
            bad(field, f"applies to {policy} policies; add '{policy}' to policies")
        if not values or any(x not in allowed for x in values) or len(set(values)) != len(values):
            bad(field, f"must be distinct names from {', '.join(allowed)}, got {spec[field]!r}")
        if column in spec.get("config", {}):
            bad(field, f"set {column} either here or in [config], not both")
        spec[field] = values


def check_hparams_table(hps: dict, bad: Callable[[str, str], NoReturn]) -> dict:
    """The [hparams] table: known names, numbers (or lists of numbers) in their ranges -> {name: (values)}."""
    if not isinstance(hps, dict):
        bad("hparams", "must be a table")
    out = {}
    for k, v in hps.items():
        if k in ("K", "total_iterations"):
            bad(f"hparams.{k}", "is set by the sweep (use 'clusters'/'cluster_multipliers' and 'steps')")
        if k not in HPARAM_DEFAULTS:
            bad(f"hparams.{k}", f"unknown hyperparameter; known: {', '.join(h for h in HPARAM_DEFAULTS if h not in ('K', 'total_iterations'))}")
        values = v if isinstance(v, (list, tuple)) else [v]
        if not values or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values):
            bad(f"hparams.{k}", f"must be a number or a list of numbers, got {v!r}")
        for x in values:
            try:
                check_hparam(k, x)
            except ValueError as e:
                bad(f"hparams.{k}", str(e))
        out[k] = tuple(values)
    return out


def check_hparam_sets(sets: list, hparams: dict, bad: Callable[[str, str], NoReturn]) -> tuple:
    """hparam_sets: a non-empty list of tables, each giving the same hyperparameters (none of the hparams
    table's), numbers in range -> tuple of dicts."""
    if not isinstance(sets, list) or not sets or not all(isinstance(c, dict) and c for c in sets):
        bad("hparam_sets", "must be a non-empty list of non-empty tables ([[hparam_sets]] name = value)")
    names = list(sets[0])
    for i, c in enumerate(sets):
        if sorted(c) != sorted(names):
            bad(f"hparam_sets[{i}]", f"gives {sorted(c)}; every set must give the same hyperparameters as the first, {sorted(names)}")
        for k, v in c.items():
            if k in hparams:
                bad(f"hparam_sets[{i}].{k}", "is also in the hparams table; give it in one place")
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                bad(f"hparam_sets[{i}].{k}", f"must be a number, got {v!r}")
            checked = check_hparams_table({k: v}, lambda field, msg, i=i: bad(f"hparam_sets[{i}].{field[8:]}", msg))
            c[k] = checked[k][0]
    return tuple(dict((k, c[k]) for k in names) for c in sets)


# ----------------------------------------------------------------------------------------------- the grid
def cluster_count(multiplier: float, action_dim: int) -> int:
    """K of a cluster multiplier m on a task with action_dim actions: ceil(m * action_dim), at least 1."""
    return max(1, math.ceil(multiplier * action_dim - 1e-9))


def axis_values(spec: SweepSpec, axis: tuple, policy: str) -> list:
    """A group axis's values for one policy: [None] (not in the spec: no column), the listed values,
    or [""] (listed, but it does not apply to this policy)."""
    field, _, applies_to, _ = axis
    values = getattr(spec, field)
    if values is None:
        return [None]
    return list(values) if applies_to in (None, policy) else [""]


def build_grid(spec: SweepSpec) -> list[Group]:
    """[Group]: every combination of K x swept hparams x seed exactly once, per group."""
    names = list(spec.hparams)
    sets = [{"hparam_set": i, **c} for i, c in enumerate(spec.hparam_sets)] if spec.hparam_sets else [{}]
    combos = [(combo, c) for combo in itertools.product(*(spec.hparams[n] for n in names)) for c in sets]
    groups = []
    for env_name in spec.envs:
        for policy in spec.policies:
            ks = spec.cluster_counts(env_name) if policy == MIXTURE else [1]
            for values in itertools.product(*(axis_values(spec, axis, policy) for axis in GROUP_AXES)):
                axes = {axis[1]: v for axis, v in zip(GROUP_AXES, values) if v is not None}
                runs = []
                for k in ks:
                    for combo, chosen in combos:
                        for seed in spec.seeds:
                            runs.append({"run": len(runs), "env": env_name, "policy": policy, **axes,
                                         "K": k, "seed": seed, **dict(zip(names, combo)), **chosen})
                groups.append(Group(env_name, policy, runs))
    return groups


def group_name(group: Group) -> str:
    """The group's directory name: env-policy[-<axis value>...] (a partition class as <class>-partition)."""
    first = group.runs[0] if group.runs else {}
    return f"{path_part(group.env)}-{group.policy}" + "".join(
        f"-{first[c]}" + ("-partition" if c == "partition" else "") for _, c, _, _ in GROUP_AXES if first.get(c))


def group_config(spec: SweepSpec, group: Group) -> Config:
    """The group's static Config (k_max: its largest K, or the spec's config k_max where larger: programs of several
    sweeps with different K then share one shape; masking the clusters beyond K is exact)."""
    static = {k: tuple(v) if isinstance(v, list) else v for k, v in spec.config.items()}
    static.update({c: group.runs[0][c] for _, c, _, _ in GROUP_AXES if group.runs[0].get(c)})
    k_max = max([int(static.pop("k_max", 1))] + [r["K"] for r in group.runs])
    return for_task(Config(env=group.env, policy=group.policy, k_max=k_max, **static), envs.resolve(group.env))


def single_group(env: str, policy: str, K: int, seeds: list[int], backend: str,
                 source: str = "spec") -> tuple[Group, Config]:
    """(Group, Config) of the one group a sweep of `seeds` (a list) of one task, policy and K would train: its
    defaults, this physics backend (the benchmark's workers and gsa profile build their programs from it)."""
    spec = check_spec({"envs": [env], "policies": [policy], "clusters": [K], "seeds": seeds, "steps": 10**9,
                       "config": {"physics": {"backend": backend}}}, source=source)
    group = build_grid(spec)[0]
    return group, group_config(spec, group)


def default_chunk(spec: SweepSpec, cfg: Config) -> int:
    """PPO iterations per compiled chunk: the spec's, or ~1/20 of the run (at most 10)."""
    return spec.chunk or max(1, min(10, math.ceil(spec.steps / cfg.batch_size) // 20))


def chunk_end(steps: int, batch: int, chunk: int) -> int:
    """The iteration that ends the chunk holding env step `steps` (batch env steps per iteration): steps rounded up
    to whole chunks of iterations."""
    return -(-(-(-int(steps) // batch)) // chunk) * chunk


def group_iterations(spec: SweepSpec, cfg: Config, chunk: int) -> int:
    """PPO iterations of every run of a group: the spec's steps rounded up to whole chunks."""
    return chunk_end(spec.steps, cfg.batch_size, chunk)


def group_eval_every(spec: SweepSpec, iterations: int) -> int:
    """Iterations between deterministic evaluations of a group's runs (0: none, or eval_at's list); default ~25 per
    run."""
    if spec.eval_at is not None:
        return 0
    return spec.eval_every if spec.eval_every is not None else max(1, iterations // EVALUATIONS_PER_RUN)


def group_eval_at(spec: SweepSpec, batch: int, chunk: int) -> tuple:
    """The iterations after which a group's runs are evaluated where the spec lists env steps (eval_at): each at the
    end of the chunk holding it (a run evaluates only between chunks); () where it does not."""
    if spec.eval_at is None:
        return ()
    return tuple(sorted({chunk_end(s, batch, chunk) for s in spec.eval_at}))
