"""A task trained under domain randomization (envs/randomization.py says what is drawn): a wrapper (envs/interface.py) above the
time limit and auto-reset, and the model variants each backend steps.

    env = Randomized(envs.make(name, physics=physics), base, spec)   # envs.make(..., randomize=spec) does this

The wrapper keeps the episode's draw in state.info ('randomize_scales' [P], 'randomize_delay', the action queue
[D, nu] and its own key), draws a new one where an episode ended, and runs every call of the wrapped env inside
`variant(scales, push)`: on MJX the base env's model (env.sys) with the scaled fields and a pipeline_step that
applies the push; on 'c' the host steps each simulation with its own model fields (c_hosts.TaskHost). A
restarted episode's start state is computed in the step that ended the previous one (under its draw); the first
start of a run under the nominal model.
"""

import contextlib

import jax
import jax.numpy as jnp

from envs.interface import Wrapper
from envs.physics import C, mj_model, substeps
from envs.randomization import push_force


RANDOMIZE_STREAM = 0x52414E44  # folded into a reset's key: the randomization's own key sequence


def _with_push(pipeline_state, body, force):
    """pipeline_state with xfrc_applied[body, :2] = force [2] (MJX data, or a task's WithGoal around it)."""
    data = getattr(pipeline_state, "data", pipeline_state)
    data = data.replace(xfrc_applied=data.xfrc_applied.at[body, :2].set(force))
    return pipeline_state.__class__(data, pipeline_state.goal) if hasattr(pipeline_state, "goal") else data


@contextlib.contextmanager
def mjx_variant(base, spec, scales, push, body):
    """While traced inside: base.sys with the spec's fields scaled by scales [P] (no mj_setConst: MJX has none),
    and pipeline_step applying a horizontal force push [2] (None: none) on `body` during the step."""
    sys0 = base.sys
    fields = {}
    for field, col, i in spec.model_fields:
        value = fields.get(field, getattr(sys0, field))
        fields[field] = value * scales[i] if col is None else value.at[..., col].multiply(scales[i])
    base.sys = sys0.tree_replace(fields) if fields else sys0
    if push is not None:
        step = type(base).pipeline_step

        def pushed(pipeline_state, action):
            out = step(base, _with_push(pipeline_state, body, push), action)
            return _with_push(out, body, jnp.zeros(2, push.dtype))

        base.pipeline_step = pushed
    try:
        yield
    finally:
        base.sys = sys0
        base.__dict__.pop("pipeline_step", None)


def push_body_of(base):
    """The body pushes act on: the task definition's push_body, else body 1."""
    task = getattr(base, "task", None) or getattr(base, "port", None)
    return task.push_body_id() if hasattr(task, "push_body_id") else 1


def is_planar(base):
    """Whether pushes act along +-x only (the task definition's `planar`)."""
    task = getattr(base, "task", None) or getattr(base, "port", None)
    return bool(getattr(task, "planar", False))


class Randomized(Wrapper):
    """Draws the spec's randomization per episode (module docstring). base: the unwrapped task (make_base's)."""

    def __init__(self, env, base, spec):
        super().__init__(env)
        self.spec, self.base = spec, base
        self._lo = jnp.asarray([lo for _, lo, _ in spec.scales], jnp.float32)
        self._hi = jnp.asarray([hi for _, _, hi in spec.scales], jnp.float32)
        self.n_act = int(mj_model(base).nu)
        dt = float(mj_model(base).opt.timestep) * substeps(base)
        self._force = push_force(spec.push, mj_model(base), dt)
        self._planar, self._body = is_planar(base), push_body_of(base)
        self._variant = self._variant_fn()
        self._models = base.model_draws() if spec.registry else None  # a Playground randomizer's draws

    def _variant_fn(self):
        """variant(scales, push) -> context manager for the base's backend (envs.check_randomize has checked that
        the backend applies the spec)."""
        spec, base = self.spec, self.base
        if not spec.model_fields and not spec.push:
            return lambda scales, push: contextlib.nullcontext()
        if getattr(base, "backend", None) == C:
            base.enable_variants(spec, self._body)
            return base.variant
        return lambda scales, push: mjx_variant(base, spec, scales, push, self._body)

    def _draw(self, key):
        """{'randomize_scales' [P], 'randomize_delay', 'randomize_model' (a Playground randomizer's fields)} of a new
        episode."""
        k_s, k_d, k_m = jax.random.split(key, 3)
        scales = jax.random.uniform(k_s, self._lo.shape, minval=self._lo, maxval=self._hi)
        model = self._models.draw(k_m) if self._models else ()
        return {"randomize_scales": scales, "randomize_delay": jax.random.randint(k_d, (), 0, self.spec.delay + 1),
                "randomize_model": model}

    @contextlib.contextmanager
    def _physics(self, info, push):
        """The episode's physics while the wrapped env is traced: its scales and push, or its registry model."""
        with self._variant(info["randomize_scales"], push):
            if self._models is None:
                yield
            else:
                with self.base.model_variant(self._models.model_of(info["randomize_model"])):
                    yield

    def _push(self, key):
        """The horizontal force [2] of this step (zero without a push), or None when the spec has no pushes."""
        if not self.spec.push:
            return None
        k_hit, k_dir = jax.random.split(key)
        hit = jax.random.uniform(k_hit) < self.spec.push_rate
        if self._planar:
            angle = jnp.where(jax.random.uniform(k_dir) < 0.5, 0.0, jnp.pi)
        else:
            angle = jax.random.uniform(k_dir, minval=0.0, maxval=2 * jnp.pi)
        return jnp.where(hit, self._force, 0.0) * jnp.stack([jnp.cos(angle), jnp.sin(angle)])

    def _noisy(self, state, key):
        if not self.spec.obs_noise:
            return state
        noise = self.spec.obs_noise * jax.random.normal(key, state.obs.shape)
        if "final_obs" in state.info:
            state.info["final_obs"] = state.info["final_obs"] + noise
        return state.replace(obs=state.obs + noise)

    def reset(self, rng):
        # the wrapped env resets from rng itself, so that every draw at its nominal value is the nominal task
        k_draw, k_noise, key = jax.random.split(jax.random.fold_in(rng, RANDOMIZE_STREAM), 3)
        draw = self._draw(k_draw)
        if self._models is None:
            state = self.env.reset(rng)
        else:  # the registry's randomizers may change what a reset computes (qpos0, keyframes): draw first
            with self._physics(draw, None):
                state = self.env.reset(rng)
        state.info.update(randomize_key=key, randomize_queue=jnp.zeros((self.spec.delay, self.n_act), jnp.float32), **draw)
        return self._noisy(state, k_noise)

    def step(self, state, action):
        info = dict(state.info)  # this step's draw, before the wrapped env's step writes its info
        key, k_push, k_draw, k_noise = jax.random.split(info["randomize_key"], 4)
        history = jnp.concatenate([action[None].astype(jnp.float32), info["randomize_queue"]])
        with self._physics(info, self._push(k_push)):
            state = self.env.step(state, history[info["randomize_delay"]])
        done = state.done > 0.5
        draw = jax.tree.map(lambda new, old: jnp.where(done, new, old), self._draw(k_draw),
                            {k: info[k] for k in ("randomize_scales", "randomize_delay", "randomize_model")})
        state.info.update(randomize_key=key, randomize_queue=jnp.where(done, 0.0, history[: self.spec.delay]), **draw)
        return self._noisy(state, k_noise)
