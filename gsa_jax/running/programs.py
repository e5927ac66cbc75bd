"""The batched-program layer: one compiled program trains many runs at once.

A group of runs (same Config, any hyperparameters and seeds) becomes one program: `jax.vmap` over
the runs, optionally in sequential sub-batches (sub_batched), and with several devices the run axis
sharded over them (shard_map). Used by gsa sweep and gsa_jax.bench.

    shape = GroupShape(cfg, chunk, tuple(devices))
    group = compile_group(shape, GroupRuns(pad_runs(runs, len(devices)), names, iterations))
    states, metrics = group.run(group.states, group.hps)          # metrics [R, chunk]
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
from gsa_jax.algorithm.ppo import make_train
from gsa_jax.running import xla_cache
from gsa_jax.running.driver import Program


def stack_hparams(runs: list, names: Sequence[str], iterations: int) -> Hparams:
    """The runs' hyperparameters stacked along the run axis: Hparams of [R] arrays (make_hparams per run)."""

    per_run = [make_hparams(K=r["K"], total_iterations=iterations, **{n: r[n] for n in names}) for r in runs]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_run)


RUN_BATCH = 8  # runs per sub-batch (make_group_program); measured in experiments/bench_run_batch/


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


class RunInit(NamedTuple):
    """A run's or a group's init, jitted: init(key, hp) -> state of a run, init(keys [R], hps [R]) -> states of a
    group (make_group_init). rest alone is ppo.init_state (vmapped for a group); where the evaluation env is the
    training env without the auto-reset (ppo.resets_shared), reset is that env's reset over N = max(num_envs,
    eval_envs) keys ([R, N] for a group), shared with the evaluation (a run's RunEvaluation, a group's
    compile_group_evaluate), keys_of gives a run's training keys (ppo.start_keys), and rest is ppo.init_from_starts:
    (key, hp, starts) -> state."""

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


def over_runs(fn: Callable, devices: list) -> Callable:
    """fn (vmapped over a leading run axis of every argument and result), with several devices shard_mapped over
    them along that axis; else fn itself."""
    if len(devices) < 2:
        return fn
    # check_vma=False: MJX's solver has lax.cond branches whose outputs shard_map's varying-axis
    # type check rejects; every op here is per-run, so nothing needs that check.
    mesh = jax.sharding.Mesh(np.array(devices), ("runs",))
    return jax.shard_map(fn, mesh=mesh, in_specs=P("runs"), out_specs=P("runs"), check_vma=False)


def make_group_init(trainer: Any, devices: list) -> RunInit:
    """The group's init (RunInit), jitted with xla_cache.once_options and sharded over devices (over_runs)."""
    once = xla_cache.once_options(devices[0].platform)
    p = trainer.parts
    if not ppo.resets_shared(p):
        return RunInit(jax.jit(over_runs(jax.vmap(trainer.init), devices), compiler_options=once))
    reset = over_runs(jax.vmap(jax.vmap(p.eval_env.reset)), devices)
    keys_of = jax.vmap(lambda key: ppo.start_keys(p, ppo.env_key(key), p.cfg.num_envs))
    rest = over_runs(jax.vmap(functools.partial(ppo.init_from_starts, p)), devices)
    return RunInit(jax.jit(rest, compiler_options=once), jax.jit(reset, compiler_options=once), jax.jit(keys_of))


def make_group_program(cfg: Config, chunk: int, devices: list, run_batch: int = RUN_BATCH) -> tuple:
    """(trainer, init: RunInit (keys [R], hps [R]) -> states, run(states, hps) -> (states, metrics [R, chunk]),
    place), jit-compiled, vmapped over runs and, with several devices, sharded over them (R must be a multiple of
    len(devices)). run_batch: train each device's runs in sequential sub-batches of this many (sub_batched) instead
    of all at once (0 or None) -- the same per-run computation; MJX's batched solver loops then stop at each
    sub-batch's slowest env instead of the whole device's."""

    trainer = make_train(cfg)
    run = over_runs(sub_batched(jax.vmap(lambda s, h: trainer.run_chunk(s, h, chunk)), run_batch), devices)
    if len(devices) > 1:
        sharding = NamedSharding(jax.sharding.Mesh(np.array(devices), ("runs",)), P("runs"))
    else:
        sharding = jax.sharding.SingleDeviceSharding(devices[0])
    place = lambda tree: jax.device_put(tree, sharding)  # noqa: E731
    return trainer, make_group_init(trainer, devices), jax.jit(run, donate_argnums=0), place


def make_group_evaluate(trainer: Any, run_batch: int = RUN_BATCH, platform: "str | None" = None) -> Callable:
    """jit of evaluate(params, obs_stats, hps, keys) -> ([R] deterministic mean returns, [R] failed episodes) of
    trainer's runs, vmapped over runs in sequential sub-batches of run_batch (each sub-batch's episodes stop at its
    own slowest one); compiled for `platform` (default JAX's default backend) as programs run now and then are
    (xla_cache.once_options). Where the group's init shares its reset (RunInit.reset), the last argument is
    the start states [R, N] of that reset in place of keys (ppo.evaluate_from)."""
    once = xla_cache.once_options(platform)
    evaluate = functools.partial(ppo.evaluate_from, trainer.parts) if ppo.resets_shared(trainer.parts) else trainer.evaluate
    return jax.jit(sub_batched(jax.vmap(evaluate), run_batch), compiler_options=once)


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


class CompiledGroup(NamedTuple):
    """compile_group's result: the runs' initial states, the compiled run(states, hps) -> (states, metrics [R, chunk]),
    the stacked hyperparameters, place (onto the group's devices), how the training program was had (compiled,
    loaded, reused), and the compiled init and its trainer (compile_group_evaluate shares the init's reset)."""

    states: Any
    run: Callable
    hps: Hparams
    place: Callable
    how: str
    init: RunInit
    trainer: Any


def compile_group(shape: GroupShape, group: GroupRuns, share: "tuple | None" = None, log: Callable = print) -> CompiledGroup:
    """The group program for `group`, compiled, and its initial state.
    share: None, or (mark_dir, leader) to compile once for all worker processes (xla_cache.compile_with;
    inside xla_cache.enabled(...) or after xla_cache.enable(...), with the same cache for every process)."""
    how = ["reused (compiled earlier in this process)"]

    def build():
        trainer, init, run, place = make_group_program(shape.cfg, shape.chunk, list(shape.devices), shape.run_batch)
        keys, hps = stacked_inputs(group, place)
        init = compile_group_init(init, keys, hps, share, log)
        run, how[0] = xla_cache.compile_with(run.lower(init(keys, hps), hps), share, log)
        return trainer, init, run, place

    trainer, init, run, place = cached("group", (shape, len(group.runs)), build)
    keys, hps = stacked_inputs(group, place)
    return CompiledGroup(init(keys, hps), run, hps, place, how[0], init, trainer)


def compile_group_init(init: RunInit, keys: jax.Array, hps: Hparams, share: "tuple | None", log: Callable) -> RunInit:
    """init with its programs compiled (xla_cache.compile_with) for these keys and hyperparameters."""
    if init.reset is None:
        return RunInit(xla_cache.compile_with(init.rest.lower(keys, hps), share, log)[0])
    starts = init.keys_of(keys)
    reset = xla_cache.compile_with(init.reset.lower(starts), share, log)[0]
    rest = xla_cache.compile_with(init.rest.lower(keys, hps, reset(starts)), share, log)[0]
    return RunInit(rest, reset, init.keys_of)


def compile_single(cfg: Config, chunk: int, evaluate: bool = True) -> tuple:
    """(trainer, init, compiled run_chunk of `chunk` iterations, evaluate) of one run of a Config (not
    vmapped: train.py's program), compiled once per process for these shapes; evaluate is compiled with them
    (so a run's compile time includes it) unless `evaluate` is False (a run without evaluations: jitted only).
    Where the training env auto-resets the evaluation env itself (ppo.resets_shared), init and the evaluation
    reset their envs with one compiled program (single_run_parts)."""

    def build():
        trainer = make_train(cfg)
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


def single_program(cfg: Config, chunk: int, seed: int, hp_py: dict, eval_seed: int = 0, evaluate: bool = True) -> tuple:
    """(Program of one run, its trainer). The run is a group of one: its state and metrics carry a leading run
    axis of 1 (what the group store saves), around the un-vmapped compiled run_chunk. The deterministic
    evaluation after iteration `it` starts its episodes from fold_in(PRNGKey(eval_seed), it): the same starts
    for every seed; it is compiled with the run unless `evaluate` is False (compile_single)."""
    trainer, init, run_chunk, evaluate = compile_single(cfg, chunk, evaluate)
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


def compile_group_evaluate(shape: GroupShape, compiled: CompiledGroup, share: "tuple | None" = None,
                           log: Callable = print) -> Callable:
    """The compiled evaluation of a group's runs: (states, hps, key) -> ([R] mean deterministic returns,
    [R] failed episodes), every run from the same eval_envs start states (drawn from `key`); where the group's
    init shares its reset (RunInit.reset), from that reset's states (ppo.start_keys pads the keys)."""
    states, hps, place, init, p = compiled.states, compiled.hps, compiled.place, compiled.init, compiled.trainer.parts
    runs = jax.tree.leaves(hps)[0].shape[0]

    def starts_of(key, keys_of):
        keys = place(jnp.stack([key] * runs))
        return keys if init.reset is None else init.reset(keys_of(keys))

    def build():
        keys_of = jax.jit(jax.vmap(lambda key: ppo.start_keys(p, key, p.cfg.eval_envs)))
        evaluate = make_group_evaluate(compiled.trainer, shape.run_batch, shape.devices[0].platform)
        lowered = evaluate.lower(states.params, states.obs_stats, hps, starts_of(jax.random.PRNGKey(0), keys_of))
        return xla_cache.compile_with(lowered, share, log)[0], keys_of

    program, keys_of = cached("group_evaluate", (shape.cfg, shape.devices, shape.run_batch, runs), build)

    def evaluate(st, h, key):
        return program(st.params, st.obs_stats, h, starts_of(key, keys_of))

    return evaluate


def group_program(shape: GroupShape, group: GroupRuns, eval_seed: "int | None" = None, share: "tuple | None" = None,
                  log: Callable = print) -> Program:
    """compile_group as a driver Program of len(group.runs) (padded) runs; with an eval_seed, its deterministic
    evaluation after iteration `it` starts every run's episodes from fold_in(PRNGKey(eval_seed), it)."""
    compiled = compile_group(shape, group, share, log)
    evaluate = None
    if eval_seed is not None:
        group_eval = compile_group_evaluate(shape, compiled, share, log)
        base = jax.random.PRNGKey(eval_seed)
        evaluate = lambda st, h, it: group_eval(st, h, jax.random.fold_in(base, it))  # noqa: E731
    return Program(len(group.runs), compiled.states, compiled.hps, compiled.run, evaluate, compiled.place,
                   how=compiled.how)
