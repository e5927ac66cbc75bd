"""MuJoCo Playground's environments as single-env Brax environments: `--env playground:<Name>` (MJX).

    env = envs.make("playground:CartpoleBalance")     # Playground's registry.load(name), impl "jax" (MJX)

Playground (the optional extra `pip install playground`, which brings warp-lang, mediapy, lxml, ml-collections
and orbax-checkpoint beside what this project already has) builds the environment with its own defaults except
`impl`, which is MJX's JAX implementation here (its warp implementation is for NVIDIA GPUs). Its whole state
(MJX data, its info and metrics) is carried as the Brax state's pipeline_state, so the time limit and auto-reset
wrappers (envs/wrappers.py) work on it unchanged. An observation that is a dict is used through its "state" entry
(Playground's name for the proprioceptive state) and refused in one line without one.
"""

import contextlib
import difflib
import io

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

PREFIX = "playground:"
OBS_KEY = "state"


def registry():
    """Playground's registry module; ValueError (one line) naming the pip install if it is missing."""
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            from mujoco_playground import registry as reg  # MuJoCo Playground: an optional extra
    except ImportError as e:
        raise ValueError(f"MuJoCo Playground's environments need its package: pip install playground ({e})") from None
    return reg


def check_name(name):
    """ValueError (one line, with close matches) unless 'playground:<Name>' is in Playground's registry."""
    reg = registry()
    sub = name[len(PREFIX):]
    if sub not in reg.ALL_ENVS:
        close = difflib.get_close_matches(sub, reg.ALL_ENVS, n=3)
        raise ValueError(f"unknown env {name!r}: Playground registers {len(reg.ALL_ENVS)} environments"
                         + (f"; did you mean {', '.join(PREFIX + c for c in close)}?" if close else
                            f", e.g. {', '.join(PREFIX + c for c in list(reg.ALL_ENVS)[:4])}"))


def load(name):
    """Playground's environment `name` ('playground:<Name>') with impl 'jax'; ValueError (one line) if it cannot be
    built here (e.g. assets it would download: these machines may have no internet)."""
    reg = registry()
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return reg.load(name[len(PREFIX):], config_overrides={"impl": "jax"})
    except Exception as e:  # Playground's own loaders: asset downloads, missing files
        raise ValueError(f"{name!r} cannot be built here ({type(e).__name__}: {' '.join(str(e).split())[:160]}); "
                         "environments whose assets Playground downloads need them on disk first") from None


def domain_randomizer(name):
    """Playground's own domain randomizer of 'playground:<Name>' (registry.get_domain_randomizer: (mjx model, keys
    [n, 2]) -> (model with per-key fields, in_axes)); ValueError (one line) where its registry has none."""
    reg = registry()
    with contextlib.redirect_stdout(io.StringIO()):  # "Env ... does not have a domain randomizer" is printed
        fn = reg.get_domain_randomizer(name[len(PREFIX):])
    if fn is None:
        raise ValueError(f"randomize: Playground's registry has no domain randomizer for {name!r} (its locomotion and "
                         "manipulation environments have them); give model scales on a task definition instead")
    return fn


class ModelDraws:
    """One episode's draw of a Playground randomizer: the model fields it randomizes (the leaves where its in_axes
    is 0), drawn from one key, and the model they make (its other leaves the nominal model's)."""

    def __init__(self, randomizer, model):
        self.randomizer, self.model = randomizer, model
        _, in_axes = randomizer(model, jnp.zeros((1, 2), jnp.uint32))  # run once: in_axes holds Python 0 / None
        axes = jax.tree.leaves(in_axes, is_leaf=lambda x: x is None)
        self.leaves, self.treedef = jax.tree.flatten(model)
        if len(axes) != len(self.leaves):
            raise ValueError("randomize: the randomizer's in_axes do not match the model's fields")
        self.drawn = tuple(i for i, ax in enumerate(axes) if ax == 0)

    def draw(self, key):
        """The randomized leaves (a tuple, one per drawn field, without the batch axis) of one episode."""
        model_v, _ = self.randomizer(self.model, key[None])
        leaves = jax.tree.leaves(model_v)
        return tuple(leaves[i][0] for i in self.drawn)

    def model_of(self, drawn):
        """The model with the drawn leaves in place."""
        leaves = list(self.leaves)
        for i, v in zip(self.drawn, drawn):
            leaves[i] = v
        return jax.tree.unflatten(self.treedef, leaves)


class PlaygroundEnv(Env):
    """A Playground MjxEnv as a Brax Env: pipeline_state is Playground's State."""

    def __init__(self, name, env=None):
        """name: 'playground:<Name>' (built from Playground's registry) or a user's task name with its MjxEnv `env`."""
        self.name, self.env = name, (load(name) if env is None else env)
        self.mj_model, self.n_frames = self.env.mj_model, int(getattr(self.env, "n_substeps", 1))
        self.episode_length = int(self.env._config.get("episode_length", 1000))
        obs = jax.eval_shape(self.env.reset, jax.random.PRNGKey(0)).obs
        if isinstance(obs, dict) and OBS_KEY not in obs:
            raise ValueError(f"{name!r} observes a dict without a {OBS_KEY!r} entry ({', '.join(obs)}); the policies here "
                             "take one vector")

    def _obs(self, obs):
        return (obs[OBS_KEY] if isinstance(obs, dict) else obs).astype(jnp.float32)

    def model_draws(self):
        """ModelDraws of this environment's registry randomizer (domain_randomizer)."""
        return ModelDraws(domain_randomizer(self.name), self.env.mjx_model)

    @contextlib.contextmanager
    def model_variant(self, model):
        """Inside (while traced): the environment steps `model` (as Playground's own randomization wrapper swaps it)."""
        old = self.env.unwrapped._mjx_model
        self.env.unwrapped._mjx_model = model
        try:
            yield
        finally:
            self.env.unwrapped._mjx_model = old

    def reset(self, rng):
        s = self.env.reset(rng)
        return State(s, self._obs(s.obs), s.reward.astype(jnp.float32), s.done.astype(jnp.float32), {}, {})

    def step(self, state, action):
        s = self.env.step(state.pipeline_state, action)
        return state.replace(pipeline_state=s, obs=self._obs(s.obs), reward=s.reward.astype(jnp.float32),
                             done=s.done.astype(jnp.float32))

    @property
    def observation_size(self):
        return int(jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs.shape[-1])

    @property
    def action_size(self):
        return int(self.env.action_size)

    @property
    def backend(self):
        return "mjx"
