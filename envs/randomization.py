"""Domain randomization: what a training run draws at each episode's start and at each step, declared once.

    spec = parse("mass=0.9:1.125, friction=0.75:1.25, gear=0.9:1.1, delay=1, push=0.125")
    env = envs.make("Hopper-v5", physics=Physics(backend="c"), randomize=spec)

The text is a comma-separated list of `name=value` items (the same text in `--randomize`, an experiment file's
`[randomize]` table and a Task's `randomize` attribute; config.json records it in canonical order):

- model scales, each drawn once per episode, uniformly in [lo, hi] (`lo:hi`, or one number for a fixed scale),
  one draw per item for the whole model:
    mass      every body's mass and rotational inertia (the same shapes, denser), as gsa_jax.robustness's mass shift
    friction  every geom's sliding friction (geom_friction[:, 0])
    gear      every actuator's gear (actuator_gear[:, 0]; weaker or stronger motors)
    damping   every joint's damping (dof_damping)
    <field>   any other float field of MjModel by its name (body_mass, dof_armature, ...): every entry scaled
  On backend 'c' a simulation whose draw changed gets the scaled fields and mj_setConst (the constants derived
  from masses and gears follow, as a model compiled with those values has them); MJX scales the fields alone, as
  MuJoCo Playground's randomizers do (MJX has no mj_setConst), so the two backends differ slightly off nominal.
- obs_noise=s    Gaussian noise of std s (in the observation's own units) added to every observation the policy sees
- delay=D        each episode applies actions d steps late, d drawn uniformly in {0, ..., D} (zero actions first)
- playground     a Playground environment's own domain randomizer (its registry's get_domain_randomizer), one
                 draw per episode: `--env playground:Go1JoystickFlatTerrain --randomize playground`
- push=L         at each step with probability push_rate (default 0.01) a horizontal force on the task's push body
                 (Task.push_body; body 1 otherwise) for one env step, of impulse L x the nominal total mass in a
                 random horizontal direction (+-x for planar robots): gsa_jax.robustness's push, at random times

Draws come from the env's own key, so a run stays a pure function of its seed (and resumes bit for bit). Every
draw at its nominal value (scales 1, no noise, no delay, no push) gives the nominal task: bit for bit on 'c',
the same program on MJX. No JAX or MuJoCo import at module level.
"""

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from envs.errors import UserError

# scale name -> (MjModel fields it scales, the column it scales or None for every entry)
ALIASES = {"mass": (("body_mass", None), ("body_inertia", None)), "friction": (("geom_friction", 0),),
           "gear": (("actuator_gear", 0),), "damping": (("dof_damping", None),)}
OTHER_KEYS = ("obs_noise", "delay", "push", "push_rate")
REGISTRY_KEY = "playground"  # the item that asks for a Playground environment's own registry randomizer
DEFAULT_PUSH_RATE = 0.01


class RandomizeError(UserError, ValueError):
    """A randomization that cannot run (one line, raised before anything is compiled)."""


@dataclasses.dataclass(frozen=True)
class Randomize:
    """A parsed randomization (module docstring). scales: ((name, lo, hi), ...) in the order given."""

    scales: tuple = ()
    obs_noise: float = 0.0
    delay: int = 0
    push: float = 0.0
    push_rate: float = DEFAULT_PUSH_RATE
    registry: bool = False  # a Playground environment's own randomizer (envs/playground_adapter.py), per episode

    @property
    def model_fields(self) -> tuple:
        """((MjModel field, column or None, index of its scale in `scales`), ...)."""
        out = []
        for i, (name, _, _) in enumerate(self.scales):
            out += [(field, col, i) for field, col in ALIASES.get(name, ((name, None),))]
        return tuple(out)

    @property
    def is_nominal(self) -> bool:
        """Whether every draw is the nominal task's (nothing to apply)."""
        return (all(lo == hi == 1.0 for _, lo, hi in self.scales)
                and not (self.obs_noise or self.delay or self.push or self.registry))

    def text(self) -> str:
        """The canonical text (parse(spec.text()) == spec)."""
        items = [REGISTRY_KEY] * self.registry + [f"{n}={lo:g}" if lo == hi else f"{n}={lo:g}:{hi:g}"
                                                  for n, lo, hi in self.scales]
        items += [f"obs_noise={self.obs_noise:g}"] * bool(self.obs_noise) + [f"delay={self.delay}"] * bool(self.delay)
        if self.push:
            items.append(f"push={self.push:g}")
            if self.push_rate != DEFAULT_PUSH_RATE:
                items.append(f"push_rate={self.push_rate:g}")
        return ", ".join(items)

    def record(self) -> dict:
        """What config.json / sweep.json record of it: the text and each item spelled out."""
        return {"text": self.text(), "registry": self.registry, "scales": {n: [lo, hi] for n, lo, hi in self.scales},
                "model_fields": [f if c is None else f"{f}[:, {c}]" for f, c, _ in self.model_fields],
                "obs_noise": self.obs_noise, "delay_max": self.delay, "push": self.push, "push_rate": self.push_rate}


def _number(name, value):
    try:
        x = float(value)
    except ValueError:
        raise RandomizeError(f"randomize: {name}={value!r} is not a number") from None
    if not math.isfinite(x):
        raise RandomizeError(f"randomize: {name}={value!r} must be finite")
    return x


def _scale(name, value):
    """(lo, hi) of a scale item 'lo:hi' or 'x'."""
    parts = str(value).split(":")
    if len(parts) > 2:
        raise RandomizeError(f"randomize: {name}={value!r}: a scale is 'lo:hi' or one number")
    lo, hi = _number(name, parts[0]), _number(name, parts[-1])
    if not 0 < lo <= hi:
        raise RandomizeError(f"randomize: the scale range of {name} must lie in (0, inf) with lo <= hi, got {value!r}")
    return lo, hi


def _items(text):
    """[(name, value)] of 'a=1, b=2:3' (a dict's items as they are)."""
    if isinstance(text, dict):
        return [(str(k), str(v) if not isinstance(v, (list, tuple)) else ":".join(map(str, v))) for k, v in text.items()]
    out = []
    for item in filter(None, (s.strip() for s in str(text).split(","))):
        if item == REGISTRY_KEY:
            out.append((item, "1"))
            continue
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise RandomizeError(f"randomize: {item!r} is not name=value (e.g. mass=0.9:1.1, delay=1)")
        out.append((name.strip(), value.strip()))
    return out


def parse(text: "str | dict | Randomize | None") -> Randomize:
    """A Randomize from its text (module docstring), a {name: value} table, or a Randomize; '' or None: none.
    Raises RandomizeError (one line) for a malformed item or a value out of range; names that are not an alias
    or a key are taken as MjModel fields, checked against a model by check()."""
    if isinstance(text, Randomize):
        return text
    scales, other, seen = [], {}, set()
    for name, value in _items(text or ""):
        if name in seen:
            raise RandomizeError(f"randomize: {name} is given twice")
        seen.add(name)
        if name in OTHER_KEYS or name == REGISTRY_KEY:
            other[name] = _number(name, value)
        else:
            scales.append((name, *_scale(name, value)))
    delay = other.get("delay", 0)
    if delay < 0 or delay != int(delay):
        raise RandomizeError(f"randomize: delay must be a whole number of steps >= 0, got {delay:g}")
    for key in ("obs_noise", "push"):
        if other.get(key, 0) < 0:
            raise RandomizeError(f"randomize: {key} must be >= 0, got {other[key]:g}")
    rate = other.get("push_rate", DEFAULT_PUSH_RATE)
    if not 0 <= rate <= 1:
        raise RandomizeError(f"randomize: push_rate is a probability per step, in [0, 1], got {rate:g}")
    spec = Randomize(tuple(scales), other.get("obs_noise", 0.0), int(delay), other.get("push", 0.0), rate,
                     bool(other.get(REGISTRY_KEY, 0)))
    _check_fields_unique(spec)
    return spec


def _check_fields_unique(spec):
    fields = [f for f, _, _ in spec.model_fields]
    twice = sorted({f for f in fields if fields.count(f) > 1})
    if twice:
        raise RandomizeError(f"randomize: {', '.join(twice)} would be scaled twice (an alias already scales it)")


def check_model(spec: Randomize, model: Any, episode_length: Optional[int] = None) -> None:
    """RandomizeError (one line) for a name that is no float field of this MjModel, or a delay as long as the
    episode."""
    for field, col, _ in spec.model_fields:
        value = getattr(model, field, None)
        if not isinstance(value, np.ndarray) or value.dtype.kind != "f" or field.startswith(("opt", "stat")):
            known = ", ".join(list(ALIASES) + list(OTHER_KEYS) + [REGISTRY_KEY])
            raise RandomizeError(f"randomize: unknown parameter {field!r}; use one of {known} or a float field of "
                                 "MjModel (body_mass, dof_armature, ...)")
        if col is not None and (value.ndim != 2 or value.shape[1] <= col):
            raise RandomizeError(f"randomize: {field} has no column {col} in this model")
    if episode_length is not None and spec.delay >= episode_length:
        raise RandomizeError(f"randomize: delay={spec.delay} is not shorter than the episode ({episode_length} steps)")


def push_force(level: float, model: Any, dt: float) -> float:
    """The horizontal force of a push of size `level` (m/s) held for one env step dt: an impulse of level x the
    model's total mass, the momentum of a `level` velocity change of the whole robot as one rigid body (the push of
    the randomization and of gsa_jax.robustness alike)."""
    return float(level) * float(np.sum(model.body_mass)) / float(dt)


def scaled_values(nominal: np.ndarray, col: Optional[int], scale: np.ndarray) -> np.ndarray:
    """The field's values [n, ...] for per-row scales [n] from its nominal values (NumPy, float64; the C backend)."""
    out = np.broadcast_to(nominal, (len(scale),) + nominal.shape).copy()
    s = np.asarray(scale, np.float64).reshape((-1,) + (1,) * nominal.ndim)
    if col is None:
        return out * s
    out[..., col] = out[..., col] * s[..., 0]
    return out
