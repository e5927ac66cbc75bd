"""The batched-program layer: one compiled program trains many runs at once.

A group of runs (same Config, any hyperparameters and seeds) becomes one program: `jax.vmap` over
the runs, optionally in sequential sub-batches (sub_batched), and with several devices the run axis
sharded over them (shard_map). Used by gsa sweep and gsa_jax.bench.

    shape = GroupShape(cfg, chunk, tuple(devices))
    states, run, hps, place, how = compile_group(shape, GroupRuns(pad_runs(runs, len(devices)), names, iterations))
    states, metrics = run(states, hps)          # metrics [R, chunk]
"""

import functools
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

from envs import host_call
from gsa_jax.algorithm import ppo
from gsa_jax.algorithm.config import Config, Hparams, make_hparams
from gsa_jax.running.tasks import trainer_for
from gsa_jax.running import xla_cache
from gsa_jax.running.driver import Program
from gsa_jax.running.spec import RUN_BATCH


def stack_hparams(runs: list, names: Sequence[str], iterations: int) -> Hparams:
    """The runs' hyperparameters stacked along the run axis: Hparams of [R] arrays (make_hparams per run)."""

    per_run = [make_hparams(K=r["K"], total_iterations=iterations, **{n: r[n] for n in names}) for r in runs]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_run)


def sub_batched(fn: Callable, size: int) -> Callable:
    """fn (vmapped over a leading run axis R) applied to sequential slices of `size` runs in a lax.scan,
    when size divides R and is smaller; else fn itself. (Explicit shapes: jax.lax.map(batch_size=) fails
    on MJX's zero-size arrays.)"""
    def run(*xs):
        n = jax.tree.leaves(xs)[0].shape[0]
        if not size or size >= n or n % size:
            return fn(*xs)
        split = jax.tree.map(lambda x: x.reshape((n // size, size) + x.shape[1:]), xs)
        _, ys = jax.lax.scan(lambda c, x: (c, fn(*x)), None, split)
        return jax.tree.map(lambda y: y.reshape((n,) + y.shape[2:]), ys)

    return run


def make_group_program(cfg: Config, chunk: int, devices: list, run_batch: int = RUN_BATCH) -> tuple:
    """(init(keys [R], hps [R]) -> states, run(states, hps) -> (states, metrics [R, chunk])), jit-compiled,
    vmapped over runs and, with several devices, sharded over them (R must be a multiple of len(devices)).
    run_batch: train each device's runs in sequential sub-batches of this many (sub_batched) instead of
    all at once (0 or None) -- the same per-run computation; MJX's batched solver loops then stop at each sub-batch's
    slowest env instead of the whole device's."""

    trainer = trainer_for(cfg)
    init = jax.vmap(trainer.init)
    once = xla_cache.once_options(devices[0].platform)
    run = sub_batched(jax.vmap(lambda s, h: trainer.run_chunk(s, h, chunk)), run_batch)
    if len(devices) > 1:
        # check_vma=False: MJX's solver has lax.cond branches whose outputs shard_map's varying-axis
        # type check rejects; every op here is per-run, so nothing needs that check.
        mesh = jax.sharding.Mesh(np.array(devices), ("runs",))
        init = jax.shard_map(init, mesh=mesh, in_specs=(P("runs"), P("runs")), out_specs=P("runs"), check_vma=False)
        run = jax.shard_map(run, mesh=mesh, in_specs=(P("runs"), P("runs")), out_specs=P("runs"), check_vma=False)
        sharding = NamedSharding(mesh, P("runs"))
    else:
        sharding = jax.sharding.SingleDeviceSharding(devices[0])
    place = lambda tree: jax.device_put(tree, sharding)  # noqa: E731
    return trainer, jax.jit(init, compiler_options=once), jax.jit(run, donate_argnums=0), place


def make_group_evaluate(cfg: Config, run_batch: int = RUN_BATCH, platform: "str | None" = None) -> Callable:
    """jit of evaluate(params, obs_stats, hps, keys) -> ([R] deterministic mean returns, [R] failed
    episodes), vmapped over runs in
    sequential sub-batches of run_batch (each sub-batch's episodes stop at its own slowest one); compiled for
    `platform` (default JAX's default backend) as programs run now and then are (xla_cache.once_options)."""
    trainer = trainer_for(cfg)
    once = xla_cache.once_options(platform)
    return jax.jit(sub_batched(jax.vmap(trainer.evaluate), run_batch), compiler_options=once)


def pad_runs(runs: list, multiple: int, at_least: int = 0) -> list:
    """Pad with copies of the last run to at least `at_least` runs and a multiple of `multiple` (the
    devices), so the run axis splits evenly (copies are dropped later)."""
    n = max(len(runs), at_least)
    pad = n - len(runs) + (-n) % multiple
    return runs + [dict(runs[-1], run=-1)] * pad


class GroupShape(NamedTuple):
    """What fixes a group program's compiled code (with the run count): the Config, iterations per chunk,
    the devices the run axis is sharded over and the sub-batch size (make_group_program)."""

    cfg: Config
    chunk: int
    devices: tuple
    run_batch: int = RUN_BATCH


class GroupRuns(NamedTuple):
    """The runs a group program trains: run rows (already padded: pad_runs), the hyperparameter names they
    set beyond K, and the run length in iterations (the learning-rate schedule's)."""

    runs: list
    hparam_names: list
    iterations: int


_COMPILED = {}  # kind -> {key: compiled}, most recent last: reused within a process
_KEEP = {"single": 8}  # programs kept per kind (default 1: a group program holds its runs' device buffers)


def cached(kind: str, key: Any, build: Callable) -> Any:
    """The one compile cache: build() once per process for `key`; the last _KEEP[kind] keys of each kind
    are kept (a resumed group, a second run of the same shapes and the tests reuse them)."""
    programs = _COMPILED.setdefault(kind, {})
    if key not in programs:
        while len(programs) >= _KEEP.get(kind, 1):
            programs.pop(next(iter(programs)))
            host_call.release_recent()  # its envs' hosts (MuJoCo C) go with it
        programs[key] = build()
    programs[key] = programs.pop(key)  # most recent last
    return programs[key]


def stacked_inputs(group: GroupRuns, place: Callable) -> tuple:
    """(keys [R], hps [R]) of a group's runs, placed on its devices."""
    hps = place(stack_hparams(group.runs, group.hparam_names, group.iterations))
    keys = place(jnp.stack([jax.random.PRNGKey(r["seed"]) for r in group.runs]))
    return keys, hps


def compile_group(shape: GroupShape, group: GroupRuns, share: "tuple | None" = None, log: Callable = print) -> tuple:
    """The group program for `group`, compiled, and its initial state.
    share: None, or (mark_dir, leader) to compile once for all worker processes (xla_cache.compile_with;
    inside xla_cache.enabled(...) or after xla_cache.enable(...), with the same cache for every process).
    Returns (states, run, hps, place, how): run(states, hps) -> (states, metrics [R, chunk])."""
    how = ["reused (compiled earlier in this process)"]

    def build():
        _, init, run, place = make_group_program(shape.cfg, shape.chunk, list(shape.devices), shape.run_batch)
        keys, hps = stacked_inputs(group, place)
        init, _ = xla_cache.compile_with(init.lower(keys, hps), share, log)
        run, how[0] = xla_cache.compile_with(run.lower(init(keys, hps), hps), share, log)
        return init, run, place

    init, run, place = cached("group", (shape, len(group.runs)), build)
    keys, hps = stacked_inputs(group, place)
    return init(keys, hps), run, hps, place, how[0]


class RunInit(NamedTuple):
    """A single run's init, jitted: init(key, hp) -> state. rest alone is ppo.init_state; where the evaluation env is
    the training env without the auto-reset (ppo.resets_shared), reset is that env's reset over N = max(num_envs,
    eval_envs) keys, shared with the evaluation (RunEvaluation), keys_of gives the run's training keys
    (ppo.start_keys), and rest is ppo.init_from_starts: (key, hp, starts) -> state."""

    rest: Callable
    reset: "Callable | None" = None
    keys_of: "Callable | None" = None

    def __call__(self, key: jax.Array, hp: Hparams) -> Any:
        if self.reset is None:
            return self.rest(key, hp)
        return self.rest(key, hp, self.reset(self.keys_of(key)))


class RunEvaluation(NamedTuple):
    """A single run's evaluation (params, obs_stats, hp, key) -> (mean return, failed episodes): rest alone is
    ppo.evaluate; with a reset shared with init (RunInit), rest is ppo.evaluate_from, from reset(keys_of(key))."""

    rest: Callable
    reset: "Callable | None" = None
    keys_of: "Callable | None" = None

    def __call__(self, params: dict, obs_stats: dict, hp: Hparams, key: jax.Array) -> tuple:
        if self.reset is None:
            return self.rest(params, obs_stats, hp, key)
        return self.rest(params, obs_stats, hp, self.reset(self.keys_of(key)))


def compile_single(cfg: Config, chunk: int, evaluate: bool = True, task: Any = None) -> tuple:
    """(trainer, init, compiled run_chunk of `chunk` iterations, evaluate) of one run of a Config (not vmapped:
    train.py's program) on `task` (its record, as the command resolved it; default: cfg.env's), compiled once per
    process for these shapes; evaluate is compiled with them
    (so a run's compile time includes it) unless `evaluate` is False (a run without evaluations: jitted only).
    Where the training env auto-resets the evaluation env itself (ppo.resets_shared), init and the evaluation
    reset their envs with one compiled program (single_run_parts)."""

    def build():
        trainer = trainer_for(cfg, task)
        once = xla_cache.once_options()  # init and the evaluation run once or now and then
        init, evaluation, ahead = single_run_parts(trainer.parts, once)
        hp = make_hparams(**{"K": 1})  # shapes only: every hyperparameter is a scalar
        state = jax.eval_shape(trainer.init, jax.random.PRNGKey(0), hp)
        run_chunk = jax.jit(trainer.run_chunk, static_argnums=2, donate_argnums=0).lower(state, hp, chunk).compile()
        if evaluate:
            evaluation = ahead(state.params, state.obs_stats, hp)
        return trainer, init, run_chunk, evaluation

    return cached("single", (cfg, chunk, evaluate), build)


def single_run_parts(p: Any, once: dict) -> tuple:
    """(init: RunInit, evaluate: RunEvaluation, ahead(params, obs_stats, hp) -> evaluate with its rest compiled ahead
    of its first call) of one run, jitted with `once`. With ppo.resets_shared, the envs' resets are one program over
    max(num_envs, eval_envs) keys (ppo.start_keys): init takes the first num_envs of its states
    (ppo.init_from_starts), the evaluation the first eval_envs (ppo.evaluate_from); else init and evaluate
    each reset their own envs."""
    if not ppo.resets_shared(p):
        evaluation = RunEvaluation(jax.jit(functools.partial(ppo.evaluate, p), compiler_options=once))
        init, last = RunInit(jax.jit(functools.partial(ppo.init_state, p), compiler_options=once)), jax.random.PRNGKey(0)
    else:
        reset = jax.jit(jax.vmap(p.eval_env.reset), compiler_options=once)
        keys_of = jax.jit(lambda key: ppo.start_keys(p, key, p.cfg.eval_envs))
        evaluation = RunEvaluation(jax.jit(functools.partial(ppo.evaluate_from, p), compiler_options=once), reset, keys_of)
        init = RunInit(jax.jit(functools.partial(ppo.init_from_starts, p), compiler_options=once), reset,
                       jax.jit(lambda key: ppo.start_keys(p, ppo.env_key(key), p.cfg.num_envs)))
        last = jax.eval_shape(lambda key: jax.vmap(p.eval_env.reset)(ppo.start_keys(p, key, p.cfg.eval_envs)),
                              jax.random.PRNGKey(0))

    def ahead(params, obs_stats, hp):
        return evaluation._replace(rest=evaluation.rest.lower(params, obs_stats, hp, last).compile())

    return init, evaluation, ahead


@jax.jit
def with_run_axis(tree: Any) -> Any:
    """A leading run axis of one on every leaf: one run as a group of one. Jitted: one compile per tree structure,
    where eager indexing compiles one small op per leaf shape."""
    return jax.tree.map(lambda x: x[None], tree)


@jax.jit
def first_run(tree: Any) -> Any:
    """The first run's leaves (the run axis taken off); jitted as with_run_axis."""
    return jax.tree.map(lambda x: x[0], tree)


def single_program(cfg: Config, chunk: int, seed: int, hp_py: dict, eval_seed: int = 0, evaluate: bool = True,
                   task: Any = None) -> tuple:
    """(Program of one run, its trainer). The run is a group of one: its state and metrics carry a leading run
    axis of 1 (what the group store saves), around the un-vmapped compiled run_chunk. The deterministic
    evaluation after iteration `it` starts its episodes from fold_in(PRNGKey(eval_seed), it): the same starts
    for every seed; it is compiled with the run unless `evaluate` is False (compile_single)."""
    trainer, init, run_chunk, evaluate = compile_single(cfg, chunk, evaluate, task)
    hp = make_hparams(**hp_py)
    eval_key = jax.random.PRNGKey(eval_seed)

    def run(states, hps):
        state, metrics = run_chunk(first_run(states), hps)
        return with_run_axis(state), with_run_axis(metrics)

    def evaluate_state(states, hps, it):
        state = first_run(states)
        return evaluate(state.params, state.obs_stats, hps, jax.random.fold_in(eval_key, it))

    state = with_run_axis(init(jax.random.PRNGKey(seed), hp))
    return Program(1, state, hp, run, evaluate_state, lambda tree: tree), trainer


def compile_group_evaluate(shape: GroupShape, states: Any, hps: Hparams, place: Callable, share: "tuple | None" = None,
                           log: Callable = print) -> Callable:
    """The compiled evaluation of a group's runs: (states, hps, key) -> ([R] mean deterministic returns,
    [R] failed episodes), every run from the same eval_envs start states (drawn from `key`)."""
    runs = jax.tree.leaves(hps)[0].shape[0]

    def build():
        keys = place(jnp.stack([jax.random.PRNGKey(0)] * runs))
        evaluate = make_group_evaluate(shape.cfg, shape.run_batch, shape.devices[0].platform)
        lowered = evaluate.lower(states.params, states.obs_stats, hps, keys)
        return xla_cache.compile_with(lowered, share, log)[0]

    compiled = cached("group_evaluate", (shape.cfg, shape.devices, shape.run_batch, runs), build)

    def evaluate(st, h, key):
        return compiled(st.params, st.obs_stats, h, place(jnp.stack([key] * runs)))

    return evaluate


def group_program(shape: GroupShape, group: GroupRuns, eval_seed: "int | None" = None, share: "tuple | None" = None,
                  log: Callable = print) -> Program:
    """compile_group as a driver Program of len(group.runs) (padded) runs; with an eval_seed, its deterministic
    evaluation after iteration `it` starts every run's episodes from fold_in(PRNGKey(eval_seed), it)."""
    states, run, hps, place, how = compile_group(shape, group, share, log)
    evaluate = None
    if eval_seed is not None:
        group_eval = compile_group_evaluate(shape, states, hps, place, share, log)
        base = jax.random.PRNGKey(eval_seed)
        evaluate = lambda st, h, it: group_eval(st, h, jax.random.fold_in(base, it))  # noqa: E731
    return Program(len(group.runs), states, hps, run, evaluate, place, how=how)
