"""Where the compiled PPO program's own time goes: one PPO iteration of a sweep's sub-batch of runs split into
its parts, each compiled and timed alone, with the floating-point operations each needs and the rate it reaches
(`gsa profile`, make profile).

Parts (all vmapped over the runs, as a sweep worker runs them), in seconds per iteration of all the runs:
- mujoco_c, host_other, env_step_program: the rollout's env steps alone (its actions replayed): with backend
  'c' the time inside MuJoCo C, the rest of the host calls (copies in and out, derived values;
  envs.c_hosts.host_seconds) and the compiled program's side of the env step; with MJX all of it is
  env_step_program
- PPO's own program (the parts of the update carry the parameters from step to step, update_parts):
  rollout_policy (observation normalization and the policy's sampling at every rollout
  step), rollout_rest (the rest of the rollout: bookkeeping, trajectory writes), targets (the value network on
  the trajectory, GAE(lambda), flattening: make_batch), shuffle_gather (every epoch's permutation and minibatch
  gathers: epoch_minibatches), gradients (forward and backward of the loss on every minibatch:
  minibatch_gradients), optimizer (global-norm clipping and Adam on every minibatch: apply_gradients),
  update_loop (the whole update, sgd_update, less those three timed alone: negative where the parts alone cost
  more than inside the update, which they do on every task measured, so their shares are upper bounds) and rest
  (what the whole iteration takes beyond everything above: metrics, normalizer statistics, the failure guard)
The gradients part is also traced (jax.profiler) to split its time between XLA's matrix-product ops and its
other ops (op_seconds): what no reordering of the rest can remove.
FLOPs are XLA's cost analysis of each part's loop-free body times its trip count (the targets' GAE scan body
counted once: a few FLOPs per sample); the reference rate is a
1024 x 1024 float32 matmul in the same process, so "of matmul" says how close a part runs to what the
process's cores reach on dense work.
"""

import functools
import glob
import gzip
import json
import os
import statistics
import tempfile
import time
from typing import Callable

import jax
import jax.numpy as jnp

import envs
from envs.physics import C
from gsa_jax.algorithm import ppo, ppo_update
from gsa_jax.algorithm.config import Config, Hparams, make_hparams
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.algorithm.policies import draw_noise
from gsa_jax.algorithm.run_parts import Parts, TrainState, norm_obs
from gsa_jax.running.tasks import task_of

PHYSICS_PARTS = ("mujoco_c", "host_other", "env_step_program")
PPO_PARTS = ("rollout_policy", "rollout_rest", "targets", "shuffle_gather", "gradients", "optimizer", "update_loop", "rest")
PARTS = PHYSICS_PARTS + PPO_PARTS


def setup(cfg: Config, runs: int, K: int, seed: int = 0) -> tuple:
    """(Parts, TrainState [runs], Hparams [runs]) of `runs` runs of cfg, initialized as a sweep does."""
    p = ppo.make_run_parts(cfg, task_of(cfg))
    hps = jax.tree.map(lambda *x: jnp.stack(x), *[make_hparams(K=K, total_iterations=1000) for _ in range(runs)])
    states = jax.jit(jax.vmap(functools.partial(ppo.init_state, p)))(jax.random.split(jax.random.PRNGKey(seed), runs), hps)
    return p, states, hps


def whole_programs(p: Parts) -> dict:
    """The whole pieces, vmapped over runs: iteration (as run_chunk runs one), rollout, targets, update."""
    def iteration(s, h):
        return ppo.run_chunk(p, s, h, 1)

    def rollout(s, h):  # the whole result: the episode bookkeeping in the carry is part of the work
        return ppo.rollout(p, s, h, ppo.schedule(h, s.iteration), s.key)

    def targets(s, h, traj):
        return ppo.make_batch(p, s, traj, h, ppo.schedule(h, s.iteration), 1.0)[0]

    def update(s, h, batch):
        return ppo_update.sgd_update(p, s.params, s.opt, batch, h, ppo.schedule(h, s.iteration), h.lr, s.key)

    return {"iteration": iteration, "rollout": rollout, "targets": targets, "update": update}


def rollout_parts(p: Parts) -> dict:
    """The rollout's physics (its actions replayed from the rollout's start) and policy (sampling on its observations)."""
    def physics(s, actions):
        def step(env_state, a):
            nxt = jax.vmap(p.env.step)(env_state, jnp.clip(a, *envs.ACTION_RANGE))
            return nxt, nxt.reward
        return jax.lax.scan(step, s.env_state, actions)[1]

    def policy(s, h, raw_obs):
        sched = ppo.schedule(h, s.iteration)
        noise = draw_noise(s.key, (p.cfg.unroll_length, p.cfg.num_envs), p.env.action_size)
        return jax.lax.scan(lambda c, x: (c, policy_step(p, s, sched, *x)), None, (raw_obs, noise))[1]

    return {"physics": physics, "rollout_policy": policy}


def policy_step(p: Parts, s: TrainState, sched: dict, raw_obs: jax.Array, noise: dict) -> tuple:
    """One rollout step's policy work: normalize [N, d_s] observations, sample (action, cluster, logp)."""
    return p.v_sample(s.params["policy"], norm_obs(p.cfg, s.obs_stats, raw_obs), noise, sched)


NUDGE = 1e-30  # the size of the stand-in parameter step of the gradients part (update_parts)


def update_parts(p: Parts) -> dict:
    """The update's parts over all num_epochs x num_minibatches steps: shuffles and gathers; gradients, each at
    the parameters the step before left (moved by NUDGE x the gradients: as in the update, parameter-only work
    cannot be hoisted out of the loop, which made a fixed-parameter loop 2.4x faster than the update's on
    HalfCheetah-v5); the optimizer (on gradients that depend on the carried parameters, for the same reason).
    Also one step of each, loop-free, for FLOP counts."""
    def shuffle_gather(s, batch):
        keys = jax.random.split(s.key, p.cfg.num_epochs)
        return jax.lax.map(lambda k: ppo_update.epoch_minibatches(p, batch, k), keys)

    def grad_one(s, h, mb):
        return ppo_update.minibatch_gradients(p, s.params, mb, h, ppo.schedule(h, s.iteration))

    def gradients(s, h, mbs):
        def body(params, mb):
            grads, aux = grad_one(s._replace(params=params), h, mb)
            return jax.tree.map(lambda x, g: x - NUDGE * g, params, grads), aux
        return jax.lax.scan(body, s.params, jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), mbs))

    def opt_one(s, h, grads):
        return ppo_update.apply_gradients(s.params, s.opt, grads, h, ppo_update.group_learning_rates(s.params, h, h.lr))

    def optimizer(s, h, grads):
        def body(carry, _):
            moved = jax.tree.map(lambda g, x: g + NUDGE * x, grads, carry[0])
            params, opt, _ = opt_one(s._replace(params=carry[0], opt=carry[1]), h, moved)
            return (params, opt), None
        steps = p.cfg.num_epochs * p.cfg.num_minibatches
        return jax.lax.scan(body, (s.params, s.opt), None, length=steps)[0]

    return {"shuffle_gather": shuffle_gather, "gradients": gradients, "optimizer": optimizer,
            "grad_one": grad_one, "opt_one": opt_one}


def host_clock(cfg: Config) -> Callable:
    """The host clock of backend 'c' (envs.c_hosts.host_seconds), or one that reads zero."""
    if cfg.physics.backend == C:
        from envs.c_hosts import host_seconds
        return host_seconds
    return no_host_clock


def no_host_clock() -> dict:
    """The clock of a program without host calls: always zero."""
    return {"host_s": 0.0, "mujoco_c_s": 0.0}


def time_call(fn: Callable, args: tuple, repeats: int, clock: Callable) -> tuple:
    """(median wall seconds, median host seconds, median MuJoCo C seconds) of fn(*args) after one untimed call."""
    jax.block_until_ready(fn(*args))
    walls, hosts, cs = [], [], []
    for _ in range(repeats):
        c0, t0 = clock(), time.perf_counter()
        jax.block_until_ready(fn(*args))
        walls.append(time.perf_counter() - t0)
        c1 = clock()
        hosts.append(c1["host_s"] - c0["host_s"])
        cs.append(c1["mujoco_c_s"] - c0["mujoco_c_s"])
    return statistics.median(walls), statistics.median(hosts), statistics.median(cs)


def flops_of(fn: Callable, args: tuple) -> float:
    """XLA's count of floating-point operations of the compiled fn(*args) (loop bodies counted once)."""
    cost = jax.jit(fn).lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", 0.0))


def matmul_rate(repeats: int = 10, n: int = 1024) -> float:
    """FLOP/s of an n x n float32 matmul in this process (the reference for how well a part uses the cores)."""
    a = jnp.ones((n, n), jnp.float32)
    t, _, _ = time_call(jax.jit(lambda x: x @ x), (a,), repeats, no_host_clock)
    return 2 * n**3 / t


def inputs(p: Parts, states: TrainState, hps: Hparams, programs: dict) -> dict:
    """Every part's arguments, made by running the pieces before it once: the rollout's trajectory, the batch,
    the minibatches and one minibatch's gradients."""
    traj = programs["rollout"](states, hps)[1]
    batch = programs["targets"](states, hps, traj)
    mbs = programs["shuffle_gather"](states, batch)
    first = jax.tree.map(lambda x: x[:, 0, 0], mbs)
    grads = programs["grad_one"](states, hps, first)[0]
    return {"iteration": (states, hps), "rollout": (states, hps), "targets": (states, hps, traj),
            "update": (states, hps, batch), "physics": (states, traj["action"]),
            "rollout_policy": (states, hps, traj["raw_obs"]), "shuffle_gather": (states, batch),
            "gradients": (states, hps, mbs), "optimizer": (states, hps, grads),
            "grad_one": (states, hps, first), "opt_one": (states, hps, grads),
            "policy_one": (states, hps, traj["raw_obs"][:, 0])}


def programs_of(p: Parts) -> dict:
    """Every timed or counted piece, jit(vmap(...)) over runs."""
    def policy_one(s, h, raw_obs):
        noise = draw_noise(s.key, (p.cfg.num_envs,), p.env.action_size)
        return policy_step(p, s, ppo.schedule(h, s.iteration), raw_obs, noise)

    fns = {**whole_programs(p), **rollout_parts(p), **update_parts(p), "policy_one": policy_one}
    return {name: jax.jit(jax.vmap(f)) for name, f in fns.items()}


TIMED = ("iteration", "rollout", "targets", "update", "physics", "rollout_policy", "shuffle_gather", "gradients", "optimizer")


def split_seconds(t: dict) -> dict:
    """Seconds per iteration of every part from the timed pieces t[name] = (wall, host, mujoco_c). MuJoCo C and
    the host calls are the iteration's own (its clock); the program's side of a piece with host calls is its wall
    less its host time, so the residual parts (rollout_rest, update_loop, rest: differences of measured wholes,
    which noise can make slightly negative) do not carry MuJoCo C's run-to-run variation. The parts add up to the
    iteration's wall time."""
    wall = {name: v[0] for name, v in t.items()}
    program = {name: v[0] - v[1] for name, v in t.items()}
    return {
        "mujoco_c": t["iteration"][2], "host_other": t["iteration"][1] - t["iteration"][2],
        "env_step_program": program["physics"],
        "rollout_policy": wall["rollout_policy"],
        "rollout_rest": program["rollout"] - program["physics"] - wall["rollout_policy"],
        "targets": wall["targets"], "shuffle_gather": wall["shuffle_gather"], "gradients": wall["gradients"],
        "optimizer": wall["optimizer"],
        "update_loop": wall["update"] - wall["shuffle_gather"] - wall["gradients"] - wall["optimizer"],
        "rest": program["iteration"] - program["rollout"] - wall["targets"] - wall["update"],
    }


def count_flops(p: Parts, programs: dict, args: dict) -> dict:
    """Floating-point operations per iteration of all the runs, per part that does arithmetic."""
    steps = p.cfg.num_epochs * p.cfg.num_minibatches
    one = lambda name: flops_of(programs[name], args[name])  # noqa: E731
    return {"rollout_policy": one("policy_one") * p.cfg.unroll_length, "targets": one("targets"),
            "gradients": one("grad_one") * steps, "optimizer": one("opt_one") * steps}


def profile_parts(cfg: Config, runs: int, K: int, repeats: int = 5) -> dict:
    """The profile of one PPO iteration of `runs` runs of cfg (mixture with K clusters): a dict with each part's
    seconds per iteration, us per env step, share, FLOPs per env step and rate, and the wholes as timed."""
    p, states, hps = setup(cfg, runs, K)
    programs = programs_of(p)
    args = inputs(p, states, hps, programs)
    clock = host_clock(p.cfg)
    timed = {name: time_call(programs[name], args[name], repeats, clock) for name in TIMED}
    flops = count_flops(p, programs, args)
    ops = op_seconds(programs["gradients"], args["gradients"])
    prof = {"env": cfg.env, "policy": cfg.policy, "K": K if cfg.policy == MIXTURE else None, "runs": runs,
            "backend": cfg.physics.backend, "repeats": repeats, "env_steps_per_iteration": runs * p.cfg.batch_size,
            "matmul_gflop_per_s": matmul_rate() / 1e9, "flops_per_iteration": flops,
            "timed": {k: dict(zip(("wall_s", "host_s", "mujoco_c_s"), v)) for k, v in timed.items()},
            "gradients_ops_s": ops}
    return {**prof, **summarize(prof)}


def summarize(prof: dict) -> dict:
    """A profile's derived figures from what it measured (timed pieces {name: {wall_s, host_s, mujoco_c_s}},
    flops_per_iteration, env_steps_per_iteration, matmul_gflop_per_s): the iteration's, PPO's own program's and the
    program's (the iteration less its host calls) seconds; the gradients' matrix products in seconds (their share of
    the traced op time, gradients_ops_s, times the gradients' untraced wall: a trace slows every op roughly alike);
    and one row per part."""
    t = {k: (v["wall_s"], v["host_s"], v["mujoco_c_s"]) for k, v in prof["timed"].items()}
    flops, env_steps = prof["flops_per_iteration"], prof["env_steps_per_iteration"]
    seconds = split_seconds(t)
    ppo_s = sum(seconds[k] for k in PPO_PARTS)
    rate = prof["matmul_gflop_per_s"] * 1e9
    rows = [{"part": k, "s_per_iteration": v, "us_per_env_step": 1e6 * v / env_steps,
             "share_of_iteration": v / t["iteration"][0], "share_of_ppo": v / ppo_s if k in PPO_PARTS else None,
             "kflop_per_env_step": flops[k] / env_steps / 1e3 if k in flops else None,
             "gflop_per_s": flops[k] / v / 1e9 if k in flops and v > 0 else None,
             "of_matmul_rate": flops[k] / v / rate if k in flops and v > 0 else None} for k, v in seconds.items()]
    ops = prof["gradients_ops_s"]
    matrix_products_s = seconds["gradients"] * ops["matrix_products"] / (ops["matrix_products"] + ops["other_ops"])
    return {"iteration_s": t["iteration"][0], "ppo_program_s": ppo_s, "program_s": t["iteration"][0] - t["iteration"][1],
            "matrix_products_s": matrix_products_s, "parts": rows}


def op_seconds(fn: Callable, args: tuple, repeats: int = 3) -> dict:
    """{'matrix_products', 'other_ops'}: seconds per call of fn(*args) inside XLA:CPU's matrix-product ops (dots,
    YNNPACK fusions) and inside its other ops, from a jax.profiler trace of `repeats` calls (each executed op is
    one complete event; loops and runtime bookkeeping are not ops)."""
    jax.block_until_ready(fn(*args))
    with tempfile.TemporaryDirectory() as d:
        jax.profiler.start_trace(d)
        try:
            for _ in range(repeats):
                jax.block_until_ready(fn(*args))
        finally:
            jax.profiler.stop_trace()
        found = glob.glob(os.path.join(d, "**", "*.trace.json.gz"), recursive=True)
        if not found:
            raise RuntimeError(f"jax.profiler wrote no trace under {d}: cannot split the gradients' op time")
        with gzip.open(found[0]) as f:
            events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    out = {"matrix_products": 0.0, "other_ops": 0.0}
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X" or name.startswith(NOT_OPS) or name.split(".")[0] in ("while", "conditional", "call"):
            continue
        kind = "matrix_products" if name.startswith(("dot", "ynn", "xnn", "onednn")) else "other_ops"
        out[kind] += e.get("dur", 0) * 1e-6 / repeats
    return out


NOT_OPS = ("ThunkExecutor", "$", "PjitFunction", "CommonPjRt", "Thunk")  # trace events that are not XLA ops
