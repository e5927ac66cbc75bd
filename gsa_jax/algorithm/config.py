"""The configuration of a training run: the static `Config` (what changes shapes or program structure, one
compile each) and the traced `Hparams` (array scalars a sweep varies and vmaps over), with their defaults, allowed
ranges and checks, run before anything compiles; and their command-line options, declared by the fields (a Config
or Physics field's metadata, HPARAM_FLAGS for Hparams): add_options adds them to a parser, options_config and
options_hparams read a parsed command line, saved_option_values gives back a saved run's settings as option values."""

import argparse
import dataclasses
import json
import math
import re
import typing
from typing import Any, NamedTuple

import envs
from envs.families.record import TaskRecord
from envs.physics import Physics, make_physics
from envs.randomization import parse as parse_randomize
from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.kinds import MIXTURE, POLICY_KINDS, VALUE_TARGETS
from gsa_jax.algorithm.subpolicies import SUBPOLICY_KINDS


def _flag(value: Any, /, *names: str, **keywords: Any) -> Any:
    """A Config field of default `value` with a command-line option: its spellings and argparse keywords beyond what
    the field's type and default give (help, choices, metavar; a default where the command line's differs)."""
    return dataclasses.field(default=value, metadata={"flag": names, **keywords})


@dataclasses.dataclass(frozen=True)
class Config:
    """Static configuration. Defaults: ~2048 samples per iteration (32 envs x 64 steps), 10 epochs,
    32 minibatches of 64 -- the PPO paper's MuJoCo setting, with the batch spread over envs. A field's metadata
    names its command-line option (CONFIG_OPTIONS)."""

    env: str = _flag("inverted_double_pendulum", "--env", help=(
        f"the task (default %(default)s): one of {', '.join(envs.NAMES)}; a task definition of yours, 'module:Class' "
        "or 'path/file.py:Class'; or "
        "another library's environment: 'brax:<name>' (Brax's registry) or 'playground:<Name>' (MuJoCo Playground's "
        "registry) (docs/your_task.md)"))
    policy: str = _flag(MIXTURE, "--policy", help=(
        "mixture (of linear controllers) or mlp (flat PPO baseline) (default %(default)s)"))
    # mixture sub-policy class: constant | linear | quadratic
    subpolicy: str = _flag(subpolicies.DEFAULT, "--subpolicy", help=(
        "sub-policy class of a mixture: constant (one action per cluster), linear (default), quadratic"))
    # mixture partition class: mlp | linear (gsa_jax/algorithm/partitions.py)
    partition: str = _flag(partitions.DEFAULT, "--partition", help=(
        "partition class of a mixture: mlp (the paper's tanh MLP, default) or linear (logits = W z + c on the "
        "normalized observation: polyhedral cells)"))
    k_max: int = _flag(8, "--k-max", default=None, help="pad the cluster axis to this size (default: K)")
    num_envs: int = _flag(32, "--num-envs", help=(
        "training environments stepped in parallel (default %(default)s); a PPO iteration collects --num-envs x "
        "--unroll-length env steps"))
    unroll_length: int = _flag(64, "--unroll-length", help="env steps of each environment per PPO iteration "
                               "(default %(default)s)")
    num_epochs: int = _flag(10, "--epochs", help="passes of PPO updates over each iteration's samples "
                            "(default %(default)s)")
    num_minibatches: int = _flag(32, "--minibatches", help=(
        "minibatches (Adam steps) per epoch, each of --num-envs x --unroll-length / N samples; N must divide that "
        "product (default %(default)s)"))
    hidden: tuple = (64, 64)
    # None: the task's own (filled in by for_task)
    episode_length: int | None = _flag(None, "--episode-length", help="time limit in steps (default: the task's own)")
    # where an ended training episode restarts: "first" (the env's first start state, Brax's convention) or
    # "fresh" (a new draw of the task's start law, as gymnasium and dm_control reset; envs/wrappers.py)
    reset_mode: str = _flag("first", "--reset-mode", choices=envs.RESET_MODES, help=(
        "first: an ended episode restarts from its env's first start (Brax's); fresh: a new draw of the task's "
        "start states (default %(default)s)"))
    normalize_obs: bool = True
    normalize_reward: bool = _flag(True, "--no-normalize-reward", help=(
        "train on raw rewards (default: rewards divided by the running std of the discounted return)"))
    b_init_scale: float = _flag(1.0, "--b-init-scale", help=(
        "a mixture's initial biases b_c spread over [-s, s]^d_a, in action units (default %(default)s)"))
    eval_envs: int = _flag(16, "--eval-envs", help=(
        "episodes of each deterministic evaluation, from random start states (default %(default)s)"))
    # the value function's targets: "gae" (GAE(lambda) on the iteration's own samples) or "retrace"
    # (the paper's critic: Retrace over the samples of the last retrace_iterations iterations, gsa_jax/algorithm/retrace.py)
    value_target: str = _flag("gae", "--value-target", help=(
        f"the value function's targets, one of {', '.join(VALUE_TARGETS)}: GAE(lambda) on each iteration's samples "
        "(default), or Retrace over the samples of the last --retrace-iterations iterations (the paper's critic)"))
    retrace_iterations: int = _flag(4, "--retrace-iterations", help=(
        "iterations of samples the Retrace critic is fitted on (default %(default)s)"))
    # the physics options, one record (envs/physics.py: backend 'mjx' or 'c', MuJoCo C threads, MJX's solver and
    # line-search settings; its fields' metadata name their options); a dict of its fields is taken too
    # (config.json, experiment files' [config.physics])
    physics: Physics = Physics()
    # domain randomization of the training episodes (envs/randomization.py's text, e.g. "mass=0.9:1.1, delay=1"; '':
    # none); evaluation runs the nominal task unless eval_randomized
    randomize: str = _flag("", "--randomize", metavar="TEXT", help=(
        "domain randomization of the training episodes, e.g. 'mass=0.9:1.1, friction=0.75:1.25, gear=0.9:1.1, "
        "damping=0.8:1.2, obs_noise=0.01, delay=1, push=0.125' (docs/randomize.md), or 'task': the task's own "
        "`randomize`; default none"))
    eval_randomized: bool = _flag(False, "--eval-randomized", help=(
        "evaluate under the training randomization (default: the nominal task)"))

    def __post_init__(self):
        if isinstance(self.physics, dict):
            object.__setattr__(self, "physics", make_physics(self.physics))
        if self.randomize == "task":  # the task's own: for_task fills it in from the task's record
            return
        try:  # the canonical text of a text, a table ({name: value}) or a Randomize; validate() names a bad one
            object.__setattr__(self, "randomize", parse_randomize(self.randomize).text())
        except ValueError:
            if not isinstance(self.randomize, str):
                raise

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.unroll_length

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    def validate(self, task: TaskRecord) -> "Config":
        """Raise ValueError naming the first bad field (before anything is compiled). task: the task's record
        (resolved by the caller, envs.resolve), whose name must be self.env; the Config is for_task's (its
        episode_length and randomize filled in)."""
        if task.name != self.env:
            raise ValueError(f"the Config names env {self.env!r} but the task given is {task.name!r}: make the Config "
                             "with env=<the task's name>")
        task.check_traced()  # a task definition's observation with jax.numpy equal to NumPy's (once per process)
        if self.episode_length is None or self.randomize == "task":
            raise ValueError("the Config leaves the task's own episode_length or randomize to fill in: make it "
                             "with for_task(cfg, task)")
        if self.policy not in POLICY_KINDS:
            raise ValueError(f"unknown policy {self.policy!r}; choose one of {', '.join(POLICY_KINDS)}")
        if self.subpolicy not in SUBPOLICY_KINDS:
            raise ValueError(f"unknown subpolicy {self.subpolicy!r}; choose one of {', '.join(SUBPOLICY_KINDS)}")
        partitions.get(self.partition)  # ValueError naming the classes
        if self.reset_mode not in envs.RESET_MODES:
            raise ValueError(f"unknown reset_mode {self.reset_mode!r}; choose one of {', '.join(envs.RESET_MODES)}")
        if self.value_target not in VALUE_TARGETS:
            raise ValueError(f"unknown value_target {self.value_target!r}; choose one of {', '.join(VALUE_TARGETS)}")
        for name in ("k_max", "num_envs", "unroll_length", "num_epochs", "num_minibatches", "episode_length", "eval_envs",
                     "retrace_iterations"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        envs.check_backend(task, self.physics)
        envs.check_randomize(task, self.randomize, self.episode_length, self.physics)
        if self.eval_randomized and not self.randomize:
            raise ValueError("eval_randomized evaluates under the training randomization; randomize is empty")
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"num_envs*unroll_length = {self.batch_size} is not divisible by num_minibatches = {self.num_minibatches}"
            )
        return self


def for_task(cfg: Config, task: TaskRecord) -> Config:
    """cfg with what it leaves to its task filled in from the task's record (resolved by the caller at the edge,
    envs.resolve; never a name): episode_length None -> the task's own time limit, randomize 'task' -> the
    randomization the task declares (ValueError if none). The one place a Config takes anything from its task."""
    if task.name != cfg.env:
        raise ValueError(f"the Config names env {cfg.env!r} but the task given is {task.name!r}")
    fields = {}
    if cfg.episode_length is None:
        fields["episode_length"] = int(task.episode_length())
    if cfg.randomize == "task":
        declared = task.declared_randomize()
        if not declared:
            raise ValueError(f"task {task.name!r} declares no randomization (Task.randomize); give one, e.g. "
                             "randomize='mass=0.9:1.1, delay=1'")
        fields["randomize"] = parse_randomize(declared).text()
    return dataclasses.replace(cfg, **fields) if fields else cfg


def config_defaults() -> dict:
    """Config's field defaults as config.json holds them (JSON types; physics a dict)."""
    out = {}
    for f in dataclasses.fields(Config):
        out[f.name] = dataclasses.asdict(f.default) if dataclasses.is_dataclass(f.default) else f.default
    return json.loads(json.dumps(out))


def config_record(saved: dict) -> dict:
    """A saved config record (config.json's 'config' or sweep.json's, read into the current layout by
    running.formats) with every field: those it lacks (written before they existed) at their defaults, which is how
    it ran."""
    defaults = config_defaults()
    return {**defaults, **saved, "physics": {**defaults["physics"], **saved.get("physics", {})}}


class Hparams(NamedTuple):
    """Per-run hyperparameters: everything a sweep may vary, as array scalars inside the programs (float32;
    K and total_iterations int32), so runs vmap over them. Defaults: the paper's PPO settings."""

    K: int = 4  # active clusters (mixture); must be <= Config.k_max
    lr: float = 3e-4
    anneal_lr: float = 1.0  # 1: lr decays linearly to 0 over total_iterations; 0: constant
    total_iterations: int = 1000
    clip_eps: float = 0.2
    gamma: float = 0.99
    gae_lambda: float = 0.95
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    eps_init: float = 0.2  # uniform exploration of the partition policy ...
    eps_decay: float = 0.995  # ... times this every iteration
    sigma_min_init: float = 0.1  # floor of every sub-policy std ...
    sigma_min_decay: float = 0.995  # ... times this every iteration
    sigma_init_scale: float = 1.0  # initial sub-policy std = sigma_init_scale / K
    # per-group learning rates, each lr x its scale (1: the one lr of the PPO paper's settings):
    lr_scale_partition: float = 1.0  # mixture: the partition network
    lr_scale_L: float = 1.0  # mixture: the linear pieces' gains L
    lr_scale_b: float = 1.0  # mixture: their offsets b
    lr_scale_log_sigma: float = 1.0  # mixture: their log std
    lr_scale_log_std: float = 1.0  # flat PPO: its state-independent log std (its MLP takes lr itself)
    lr_scale_critic: float = 1.0  # both: the value network
    init_log_std: float = 0.0  # flat PPO: the initial log std of its actions


HPARAM_DEFAULTS = Hparams()._asdict()
# the help of the Hparams options spelled --<field name>
_HPARAM_HELP = {
    "lr": "Adam's learning rate (default %(default)s; it decays linearly to 0 over the run unless --no-anneal-lr)",
    "gamma": "discount factor per env step (default %(default)s)",
    "gae_lambda": "the lambda of GAE's (and Retrace's) targets (default %(default)s)",
    "vf_coef": "weight of the value loss in PPO's loss (default %(default)s)",
    "max_grad_norm": "the gradients are clipped to this global norm before each Adam step (default %(default)s)",
    "eps_init": ("a mixture's exploration of its partition at the first iteration: the share of the cluster "
                 "probabilities spread uniformly over the K clusters (default %(default)s)"),
    "eps_decay": "--eps-init's factor per PPO iteration (default %(default)s)",
    "sigma_min_init": ("a mixture's floor on every sub-policy's action std at the first iteration, in action units "
                       "(default %(default)s)"),
    "sigma_min_decay": "--sigma-min-init's factor per PPO iteration (default %(default)s)",
    "sigma_init_scale": "a mixture's initial sub-policy std is this / K, in action units (default %(default)s)",
    "lr_scale_partition": "a mixture's partition network learns at --lr x this (default %(default)s)",
    "lr_scale_L": "a mixture's gains L learn at --lr x this (default %(default)s)",
    "lr_scale_b": "a mixture's offsets b learn at --lr x this (default %(default)s)",
    "lr_scale_log_sigma": "a mixture's sub-policy log stds learn at --lr x this (default %(default)s)",
    "lr_scale_log_std": "flat PPO's state-independent log std learns at --lr x this (default %(default)s)",
    "lr_scale_critic": "the value network (either policy's) learns at --lr x this (default %(default)s)",
    "init_log_std": "flat PPO's initial log std of its actions (std = e^this, in action units; default %(default)s)",
}
# the command-line option of each Hparams field that has one (total_iterations follows from the steps asked for):
# its spellings and argparse keywords, as a Config field's metadata holds them
HPARAM_FLAGS = {
    "K": {"flag": ("--clusters", "-K"), "help": "K, number of linear controllers of a mixture (default %(default)s)"},
    "anneal_lr": {"flag": ("--no-anneal-lr",),
                  "help": "keep the learning rate constant (default: it decays linearly to 0 over the run)"},
    "clip_eps": {"flag": ("--clip",), "help": "PPO's clip range: the probability ratio is clipped to 1 +- this "
                 "(default %(default)s)"},
    **{name: {"flag": ("--" + name.replace("_", "-"),), "help": text} for name, text in _HPARAM_HELP.items()},
}
_INT_HPARAMS = ("K", "total_iterations")


def make_hparams(**overrides: Any) -> Hparams:
    """Hparams of array scalars (float32; K and total_iterations int32): the defaults with `overrides` (names of
    Hparams' fields; an unknown name is a ValueError)."""
    unknown = set(overrides) - set(HPARAM_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown hyperparameter(s) {sorted(unknown)}; known: {', '.join(HPARAM_DEFAULTS)}")
    import jax.numpy as jnp  # here, not at the top: a command's parser reads this module's options without JAX

    hp = dict(HPARAM_DEFAULTS, **overrides)
    return Hparams(**{k: jnp.asarray(v, jnp.int32 if k in _INT_HPARAMS else jnp.float32) for k, v in hp.items()})


# Allowed range of every hyperparameter: (low, high, low included, high included). K is checked against k_max.
HPARAM_RANGES = {
    "K": (1, None, True, True),
    "lr": (0.0, None, False, True),
    "anneal_lr": (0.0, 1.0, True, True),
    "total_iterations": (1, None, True, True),
    "clip_eps": (0.0, None, False, True),
    "gamma": (0.0, 1.0, True, True),
    "gae_lambda": (0.0, 1.0, True, True),
    "vf_coef": (0.0, None, True, True),
    "max_grad_norm": (0.0, None, False, True),
    "eps_init": (0.0, 1.0, True, False),
    "eps_decay": (0.0, 1.0, True, True),
    "sigma_min_init": (0.0, None, True, True),
    "sigma_min_decay": (0.0, 1.0, True, True),
    "sigma_init_scale": (0.0, None, False, True),
    **{f"lr_scale_{g}": (0.0, None, False, True) for g in ("partition", "L", "b", "log_sigma", "log_std", "critic")},
    "init_log_std": (-5.0, 2.0, True, True),
}
# which lr_scale_* sets each parameter group's learning rate (a group absent here takes lr itself)
LR_GROUPS = {"partition": "lr_scale_partition", "L": "lr_scale_L", "b": "lr_scale_b", "log_sigma": "lr_scale_log_sigma",
             "log_std": "lr_scale_log_std"}


def allowed_range(name: str) -> str:
    """A hyperparameter's allowed range as error messages write it, e.g. '>= 1', 'in [0, 1)'."""
    lo, hi, lo_in, hi_in = HPARAM_RANGES[name]
    if hi is None:
        return f">= {lo:g}" if lo_in else f"> {lo:g}"
    return f"in {'[' if lo_in else '('}{lo:g}, {hi:g}{']' if hi_in else ')'}"


def check_hparam(name: str, value: Any) -> None:
    """Raise ValueError '<name> must be <range>, got <value>' unless value is a finite number in range."""
    if name not in HPARAM_RANGES:
        raise ValueError(f"unknown hyperparameter {name!r}; known: {', '.join(HPARAM_RANGES)}")
    lo, hi, lo_in, hi_in = HPARAM_RANGES[name]
    v = float(value)
    ok = math.isfinite(v) and (v >= lo if lo_in else v > lo) and (hi is None or (v <= hi if hi_in else v < hi))
    if name in _INT_HPARAMS and ok:
        ok = v == int(v)
    if not ok:
        kind = "an integer " if name in _INT_HPARAMS else ""
        raise ValueError(f"{name} must be {kind}{allowed_range(name)}, got {value!r}")


def validate_hparams(cfg: Config | None, hp: Hparams | dict) -> None:
    """Every hyperparameter of an Hparams (or a dict of some of them) in range (HPARAM_RANGES) and K <= k_max:
    the one check of train, sweep and bench."""
    values = hp._asdict() if isinstance(hp, Hparams) else hp
    for name in HPARAM_RANGES:
        if name in values:
            check_hparam(name, float(values[name]))
    k = int(values["K"]) if "K" in values else 1
    if cfg is not None and cfg.policy == MIXTURE and not 1 <= k <= cfg.k_max:
        raise ValueError(f"clusters K must be in 1..k_max={cfg.k_max}, got {k}")


class Option(NamedTuple):
    """The command-line option of one configuration field (a Config field, 'physics.<name>' for a field of its Physics
    record, or an Hparams field). A bool field's option is a switch; one spelled '--no-...' (inverted) sets the
    field off (False; 0.0 for a number) where given."""

    field: str
    names: tuple  # its spellings, e.g. ('--clusters', '-K'); the first gives the dest
    kind: type  # the field's type, None removed (int | None -> int)
    inverted: bool
    keywords: dict  # argparse's

    @property
    def dest(self) -> str:
        return self.names[0].lstrip("-").replace("-", "_")


def _option(field: str, annotation: Any, default: Any, metadata: Any) -> Option:
    """The Option a field's metadata ({'flag': spellings, argparse keywords}) declares."""
    names = (metadata["flag"],) if isinstance(metadata["flag"], str) else tuple(metadata["flag"])
    kind = next(t for t in typing.get_args(annotation) or (annotation,) if t is not type(None))
    inverted = names[0].startswith("--no-")
    keywords = {k: v for k, v in metadata.items() if k != "flag"}
    if inverted or kind is bool:
        keywords = {"action": "store_true", **keywords}
    else:
        keywords = {"default": default, **({} if kind is str else {"type": kind}), **keywords}
    return Option(field, names, kind, inverted, keywords)


def _record_fields(record: type, prefix: str = "") -> list:
    """[(name, dataclass field)] of a dataclass's fields, those of a nested record (Config.physics) as
    '<field>.<name>' in its place."""
    out = []
    for f in dataclasses.fields(record):
        if dataclasses.is_dataclass(f.default):
            out += _record_fields(type(f.default), f"{prefix}{f.name}.")
        else:
            out.append((prefix + f.name, f))
    return out


CONFIG_OPTIONS = tuple(_option(name, f.type, f.default, f.metadata) for name, f in _record_fields(Config)
                       if "flag" in f.metadata)
HPARAM_OPTIONS = tuple(_option(name, Hparams.__annotations__[name], HPARAM_DEFAULTS[name], HPARAM_FLAGS[name])
                       for name in Hparams._fields if name in HPARAM_FLAGS)
UNFLAGGED = tuple(name for name, f in _record_fields(Config) if "flag" not in f.metadata)  # Config fields without one


def add_options(parser: argparse.ArgumentParser) -> None:
    """Add the option of every flagged field: Config's (its Physics record's in its place), then Hparams', each in
    field order."""
    for o in CONFIG_OPTIONS + HPARAM_OPTIONS:
        parser.add_argument(*o.names, dest=o.dest, **o.keywords)


def _field_value(o: Option, given: Any) -> Any:
    """The field's value of an option's parsed value (an inverted switch turns it off)."""
    return o.kind(not given) if o.inverted else given


def _option_value(o: Option, value: Any) -> Any:
    """The option's parsed value that gives a field's value back (_field_value's inverse)."""
    return not value if o.inverted else value


def options_config(args: argparse.Namespace, **fields: Any) -> Config:
    """The Config a parsed command line sets (not validated): every option's field, the unflagged ones from
    args.unflagged where set (a saved run's, see saved_option_values) else their defaults, and `fields` over them."""
    values = {o.field: _field_value(o, getattr(args, o.dest)) for o in CONFIG_OPTIONS}
    values.update(getattr(args, "unflagged", {}), **fields)
    physics = {k.split(".", 1)[1]: v for k, v in values.items() if k.startswith("physics.")}
    return Config(**{k: v for k, v in values.items() if not k.startswith("physics.")}, physics=Physics(**physics))


def options_hparams(args: argparse.Namespace) -> dict:
    """{Hparams field: value} of the hyperparameters a parsed command line sets (Python numbers)."""
    return {o.field: _field_value(o, getattr(args, o.dest)) for o in HPARAM_OPTIONS}


def saved_option_values(config: dict, hparams: dict) -> dict:
    """{option dest: value} that give back a saved run's Config record (config_record's layout) and hyperparameters
    (those it holds), with 'unflagged': {field: value} of the Config fields no option sets (options_config reads
    it back)."""

    def value(name: str) -> Any:
        v = config["physics"][name.split(".", 1)[1]] if name.startswith("physics.") else config[name]
        return tuple(v) if isinstance(v, list) else v

    opts = {o.dest: _option_value(o, value(o.field)) for o in CONFIG_OPTIONS}
    opts.update({o.dest: _option_value(o, hparams[o.field]) for o in HPARAM_OPTIONS if o.field in hparams})
    return {**opts, "unflagged": {name: value(name) for name in UNFLAGGED}}


def flag_names(msg: str) -> str:
    """A Config error message with each field an option sets named by its flag (where the two differ)."""
    for o in CONFIG_OPTIONS:
        name = o.field.split(".")[-1]
        if o.names[0] != "--" + name:
            msg = re.sub(rf"\b{name}\b", o.names[0], msg)
    return msg
