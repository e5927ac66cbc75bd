"""An equal tuning budget for every policy class: the tuning file checked once into a TuningSpec, each
class's configurations drawn from its stated ranges, the experiment files of the tuning and evaluation
sweeps; `gsa tune` (which selects by IQM over the tuning seeds) is its command.

A tuning file (TOML):

    name = "walker2d_v5"
    env = "Walker2d-v5"
    configurations = 24                 # per class, the same for every class; the first is the defaults
    draw_seed = 0                       # the draws' random stream
    tuning_seeds = [1000, 1001]         # disjoint from evaluation_seeds
    tuning_steps = 300000
    evaluation_seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    evaluation_steps = 1000000
    [config]                            # static Config fields, as in experiment files
    [classes.flat]                      # one table per policy class
    policy = "mlp"
    knobs.lr = [1e-4, 3e-3, "log"]      # [low, high] uniform, or [low, high, "log"] log-uniform
    [classes.mixture_half]
    policy = "mixture"
    cluster_multiplier = 0.5            # K = ceil(m d_a), or clusters = K
    knobs.lr_scale_L = [0.3, 3, "log"]
"""

import dataclasses
import math
import numbers
from typing import Any, Callable

import numpy as np

import envs
from gsa_jax.algorithm.config import HPARAM_DEFAULTS, check_hparam
from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.running.spec import NAME_PATTERN, SpecError, check_config_table, cluster_count, read_toml

FIELDS = ("name", "env", "configurations", "draw_seed", "tuning_seeds", "tuning_steps", "evaluation_seeds",
          "evaluation_steps", "config", "classes")
CLASS_FIELDS = ("policy", "cluster_multiplier", "clusters", "knobs")
# the hyperparameters that act on one policy only (a knob of the other policy's is refused: it would do nothing)
ONLY = {MLP: ("lr_scale_log_std", "init_log_std"),
        MIXTURE: ("lr_scale_partition", "lr_scale_L", "lr_scale_b", "lr_scale_log_sigma", "eps_init", "eps_decay",
                    "sigma_min_init", "sigma_min_decay", "sigma_init_scale")}
NOT_KNOBS = ("K", "total_iterations")


@dataclasses.dataclass(frozen=True)
class TuningSpec:
    name: str
    env: str
    configurations: int
    draw_seed: int
    tuning_seeds: tuple
    tuning_steps: int
    evaluation_seeds: tuple
    evaluation_steps: int
    config: dict
    classes: dict  # {class name: {"policy", "K", "knobs": {name: (low, high, log)}}}


def load_tuning(path: str) -> TuningSpec:
    """Read and check a tuning file; TuningSpec, or SpecError naming the file and the bad field."""
    return check_tuning(read_toml(path, "tuning file"), path)


def check_tuning(raw: dict, source: str = "tuning") -> TuningSpec:
    """A TuningSpec from a parsed tuning file; SpecError (one line) before anything compiles."""

    def bad(field, msg):
        raise SpecError(f"{source}: field '{field}': {msg}")

    unknown = sorted(set(raw) - set(FIELDS))
    if unknown:
        bad(unknown[0], f"unknown field; allowed: {', '.join(FIELDS)}")
    missing = [f for f in FIELDS if f not in raw and f != "config"]
    if missing:
        bad(missing[0], "is required")
    if not isinstance(raw["name"], str) or not NAME_PATTERN.fullmatch(raw["name"]):
        bad("name", f"must be a plain name (letters, digits, '-', '_', '.'), got {raw['name']!r}")
    try:
        envs.check_name(raw["env"])
    except ValueError as e:
        bad("env", str(e))
    for field in ("configurations", "tuning_steps", "evaluation_steps", "draw_seed"):
        if not isinstance(raw[field], int) or isinstance(raw[field], bool) or raw[field] < (0 if field == "draw_seed" else 1):
            bad(field, f"must be an integer >= {0 if field == 'draw_seed' else 1}, got {raw[field]!r}")
    tuning, evaluation = (check_seed_list(raw[f], f, bad) for f in ("tuning_seeds", "evaluation_seeds"))
    shared = sorted(set(tuning) & set(evaluation))
    if shared:
        bad("evaluation_seeds", f"seeds {shared} are also tuning seeds; a configuration must be scored on seeds it was not chosen on")
    config = check_config_table(raw.get("config", {}), [raw["env"]], bad)
    if not isinstance(raw["classes"], dict) or not raw["classes"]:
        bad("classes", "must be a table of at least one policy class ([classes.<name>])")
    classes = {name: check_class(name, c, raw["env"], bad) for name, c in raw["classes"].items()}
    return TuningSpec(raw["name"], raw["env"], raw["configurations"], raw["draw_seed"], tuning, raw["tuning_steps"],
                      evaluation, raw["evaluation_steps"], config, classes)


def check_seed_list(seeds: Any, field: str, bad: Callable) -> tuple:
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
        bad(field, f"must be a non-empty list of integers >= 0, got {seeds!r}")
    if len(set(seeds)) != len(seeds):
        bad(field, "lists a seed twice")
    return tuple(seeds)


def check_class(name: str, c: dict, env_name: str, bad: Callable) -> dict:
    """One [classes.<name>] table -> {"policy", "K", "knobs": {knob: (low, high, log)}}."""
    where = f"classes.{name}"
    if not NAME_PATTERN.fullmatch(name):
        bad(where, "a class name must be a plain name (letters, digits, '-', '_', '.')")
    if not isinstance(c, dict):
        bad(where, "must be a table")
    unknown = sorted(set(c) - set(CLASS_FIELDS))
    if unknown:
        bad(f"{where}.{unknown[0]}", f"unknown field; allowed: {', '.join(CLASS_FIELDS)}")
    policy = c.get("policy")
    if policy not in ONLY:
        bad(f"{where}.policy", f"must be one of {', '.join(ONLY)}, got {policy!r}")
    k = class_clusters(c, env_name, f"{where}", bad) if policy == MIXTURE else 1
    knobs = c.get("knobs", {})
    if not isinstance(knobs, dict) or not knobs:
        bad(f"{where}.knobs", "must give at least one knob (knobs.<hyperparameter> = [low, high] or [low, high, \"log\"])")
    return {"policy": policy, "K": k, "knobs": {n: check_knob(n, v, policy, f"{where}.knobs.{n}", bad) for n, v in knobs.items()}}


def class_clusters(c: dict, env_name: str, where: str, bad: Callable) -> int:
    """K of a mixture class: clusters, or ceil(cluster_multiplier d_a)."""
    if ("clusters" in c) == ("cluster_multiplier" in c):
        bad(where, "a mixture class gives exactly one of clusters (K) or cluster_multiplier (K = ceil(m d_a))")
    if "clusters" in c:
        if not isinstance(c["clusters"], int) or isinstance(c["clusters"], bool) or c["clusters"] < 1:
            bad(f"{where}.clusters", f"must be an integer >= 1, got {c['clusters']!r}")
        return c["clusters"]
    m = c["cluster_multiplier"]
    if not isinstance(m, (int, float)) or isinstance(m, bool) or m <= 0:
        bad(f"{where}.cluster_multiplier", f"must be a number > 0, got {m!r}")
    return cluster_count(m, envs.action_size(env_name))


def check_knob(name: str, value: Any, policy: str, where: str, bad: Callable) -> tuple:
    """knobs.<name> = [low, high] or [low, high, "log"] -> (low, high, log), both ends in the hyperparameter's range."""
    if name not in HPARAM_DEFAULTS or name in NOT_KNOBS:
        bad(where, f"unknown knob; known: {', '.join(n for n in HPARAM_DEFAULTS if n not in NOT_KNOBS)}")
    other = next(p for p in ONLY if p != policy)
    if name in ONLY[other]:
        bad(where, f"acts on {other} policies only; a {policy} class would not use it")
    log = len(value) == 3 and value[2] == "log" if isinstance(value, list) else False
    if not isinstance(value, list) or len(value) not in (2, 3) or (len(value) == 3 and not log) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value[:2]):
        bad(where, f"must be [low, high] or [low, high, \"log\"], got {value!r}")
    low, high = float(value[0]), float(value[1])
    if not low < high:
        bad(where, f"the range [{low:g}, {high:g}] is empty (low must be < high)")
    if log and low <= 0:
        bad(where, f"a log range needs low > 0, got {low:g}")
    for v in (low, high):
        try:
            check_hparam(name, v)
        except ValueError as e:
            bad(where, str(e))
    return low, high, log


def draw_configurations(spec: TuningSpec, class_name: str) -> list:
    """[{knob: value}] of one class: spec.configurations sets, the first the defaults, the others drawn
    (uniform or log-uniform, 4 significant digits) from a stream of draw_seed and the class's name alone."""
    knobs = spec.classes[class_name]["knobs"]
    rng = np.random.default_rng([spec.draw_seed, *class_name.encode()])
    sets = [{n: float(HPARAM_DEFAULTS[n]) for n in knobs}]
    for _ in range(spec.configurations - 1):
        draw = {}
        for n, (low, high, log) in knobs.items():
            u = rng.random()
            v = math.exp(math.log(low) + u * (math.log(high) - math.log(low))) if log else low + u * (high - low)
            draw[n] = float(f"{min(max(v, low), high):.4g}")
        sets.append(draw)
    return sets


def toml_value(v: Any) -> str:
    """A TOML literal of a string, bool, number, list of them or table of them (inline: [config]'s physics)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Real):  # NumPy's too, written as plain numbers
        return str(int(v)) if isinstance(v, numbers.Integral) else repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML literal for {v!r}")


def to_toml(experiment: dict, comment: str) -> str:
    """An experiment file's text: top-level fields, [hparams], [config], then [[hparam_sets]] (if any); fields
    that are None are left out (the spec's defaults)."""
    def fields(table: dict) -> list:
        return [f"{k} = {toml_value(v)}" for k, v in table.items() if v is not None]

    lines = [f"# {comment}"] + fields({k: v for k, v in experiment.items() if k not in ("config", "hparam_sets", "hparams")})
    if experiment.get("hparams"):
        lines += ["[hparams]"] + fields(experiment["hparams"])
    lines += ["[config]"] + fields(experiment.get("config") or {})
    for s in experiment.get("hparam_sets", ()):
        lines += ["[[hparam_sets]]"] + fields(s)
    return "\n".join(lines) + "\n"


def class_experiment(spec: TuningSpec, class_name: str, phase: str, sets: list) -> dict:
    """The experiment file (a dict, gsa_jax.running.spec's format) of one class's tuning sweep (every set on the
    tuning seeds), evaluation sweep (the chosen set on the evaluation seeds) or ranking sweep (the given sets on
    the tuning seeds for the evaluation's env steps: does the short tuning's ranking hold?)."""
    c = spec.classes[class_name]
    seeds, steps = {"tuning": (spec.tuning_seeds, spec.tuning_steps),
                    "ranking": (spec.tuning_seeds, spec.evaluation_steps)}.get(phase, (spec.evaluation_seeds, spec.evaluation_steps))
    out = {"name": f"{spec.name}_{class_name}_{phase}", "envs": [spec.env], "policies": [c["policy"]]}
    if c["policy"] == MIXTURE:
        out["clusters"] = [c["K"]]
    out.update(seeds=list(seeds), steps=steps, config=dict(spec.config))
    if phase == "evaluation":
        out["hparams"] = dict(sets[0])
    else:
        out["hparam_sets"] = sets
    return out
