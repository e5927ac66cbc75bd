"""PPO for the mixture-of-linear and flat-MLP policies, as pure functions.

    task = envs.resolve("hopper")                       # at the edge: a name to its record, once
    cfg = for_task(Config(env="hopper", ...), task)     # the task's own time limit and randomization
    trainer = make_train(cfg, *make_envs(cfg, task))    # as Brax's train, handed its environments
    state = trainer.init(key, hp)                       # everything a run carries
    state, metrics = trainer.run_chunk(state, hp, n)    # n PPO iterations in one lax.scan
    state, metrics = train(cfg, task, key, hp, n)       # a whole run

`Config` is static (it changes shapes or program structure). `hp` is a dict of array
scalars (`Hparams`, see `make_hparams`): everything a sweep varies (seed via the key, K, lr, clip,
the epsilon and sigma_min schedules, ...) so runs can be vmapped over it. Both live in
gsa_jax/algorithm/config.py.

One iteration: roll out num_envs x unroll_length steps with the current policy; GAE(lambda)
advantages from a separate value MLP, bootstrapping from the true last observation when
an episode is cut by the time limit; num_epochs of shuffled minibatches of the clipped
surrogate on the joint probability pi(c, a | s) plus the value loss; Adam with global-norm
clipping; then update the observation and return normalizers; epsilon and sigma_min decay
by their factors every iteration.
"""

import functools
from typing import Any, Callable

import jax
import jax.numpy as jnp

import envs
from envs.families.record import TaskRecord
from gsa_jax.algorithm.config import Config, Hparams
from gsa_jax.algorithm.episodes import step_episodes
from gsa_jax.algorithm.nn import init_mlp
from gsa_jax.algorithm.normalize import init_stats, update_stats
from gsa_jax.algorithm.optim import init_adam
from gsa_jax.algorithm.policies import draw_noise, make_policy, partition_entropy
from gsa_jax.algorithm.ppo_update import sgd_update
from gsa_jax.algorithm.retrace import buffer_targets, init_buffer, store
from gsa_jax.algorithm.run_parts import Parts, Trainer, TrainState, norm_obs, value


def schedule(hp: Hparams, iteration: jax.Array) -> dict:
    """Exploration at iteration `iteration` (int32 scalar): K, epsilon, sigma_min."""
    t = iteration.astype(jnp.float32)
    return {
        "K": hp.K,
        "epsilon": hp.eps_init * hp.eps_decay ** t,
        "sigma_min": hp.sigma_min_init * hp.sigma_min_decay ** t,
    }


def compute_gae(rewards: jax.Array, values: jax.Array, next_values: jax.Array, terminations: jax.Array,
                dones: jax.Array, gamma: jax.Array | float, lam: jax.Array | float) -> tuple:
    """GAE(lambda) over time-major arrays [T, ...].

    next_values[t] is V of the true observation after step t (before any auto-reset), so an
    episode cut by the time limit (done, not terminated) still bootstraps from it; a
    termination bootstraps from 0. The lambda-recursion stops at every episode end.
    Returns (advantages, value targets = advantages + values).
    """
    deltas = rewards + gamma * (1.0 - terminations) * next_values - values

    def back(acc, x):
        delta, done = x
        acc = delta + gamma * lam * (1.0 - done) * acc
        return acc, acc

    _, adv = jax.lax.scan(back, jnp.zeros_like(values[0]), (deltas, dones), reverse=True)
    return adv, adv + values


def make_env(cfg: Config, task: TaskRecord, auto_reset: bool = True, randomized: bool | None = None) -> Any:
    """The task (its record: resolved by the caller, never a name) as a Config describes it: time limit, physics
    options and (where randomized, default auto_reset: the training env) its domain randomization."""
    randomized = auto_reset if randomized is None else randomized
    return envs.make(task, cfg.episode_length, auto_reset, cfg.physics, cfg.reset_mode,
                     cfg.randomize if randomized else None)


def start_states(env: Any, key: jax.Array, n: int) -> Any:
    """[n] start states of `env` (its reset, vmapped) from jax.random.split(key, n)."""
    return jax.vmap(env.reset)(jax.random.split(key, n))


def env_key(key: jax.Array) -> jax.Array:
    """The key a run's training envs start from: the third of init's four splits of the run's key."""
    return jax.random.split(key, 4)[2]


def init_state(p: Parts, key: jax.Array, hp: Hparams) -> TrainState:
    """The initial TrainState of one run."""
    return init_from(p, key, hp, start_states(p.env, env_key(key), p.cfg.num_envs))


def init_from(p: Parts, key: jax.Array, hp: Hparams, env_state: Any) -> TrainState:
    """The initial TrainState of one run whose num_envs training envs start at env_state (init_state's: drawn from
    env_key(key)); the other three splits of key draw the parameters and the run's own key."""
    k_pol, k_val, _, k_run = jax.random.split(key, 4)
    params = {
        "policy": p.policy.init(k_pol, hp),
        "value": init_mlp(k_val, (p.obs_size, *p.cfg.hidden, 1), out_scale=1.0),
    }
    return TrainState(
        params=params,
        opt=init_adam(params),
        obs_stats=init_stats(p.obs_size),
        ret_stats=init_stats(None),
        env_state=env_state,
        ep_return=jnp.zeros((p.cfg.num_envs,), jnp.float32),
        disc_return=jnp.zeros((p.cfg.num_envs,), jnp.float32),
        key=k_run,
        iteration=jnp.zeros((), jnp.int32),
        failed_at=jnp.full((), -1, jnp.int32),
        buffer=init_buffer(p.cfg.retrace_iterations, p.cfg.unroll_length, p.cfg.num_envs, p.obs_size,
                           p.env.action_size) if p.cfg.value_target == "retrace" else None,
    )


def rollout(p: Parts, state: TrainState, hp: Hparams, sched: dict, key: jax.Array) -> tuple:
    """cfg.unroll_length steps of cfg.num_envs envs -> (final carry, trajectory dict [T, N, ...]). The
    policy's random draws for all T x N steps come from one generator call before the loop."""
    params = state.params["policy"]

    def step(carry, noise):
        env_state, ep_ret, disc_ret, fin_sum, fin_cnt = carry
        obs = norm_obs(p.cfg, state.obs_stats, env_state.obs)
        action, cluster, logp = p.v_sample(params, obs, noise, sched)
        nxt = jax.vmap(p.env.step)(env_state, jnp.clip(action, *envs.ACTION_RANGE))
        r, done = nxt.reward, nxt.done
        ep_ret = ep_ret + r
        fin_sum = fin_sum + jnp.sum(done * ep_ret)
        fin_cnt = fin_cnt + jnp.sum(done)
        disc_ret = disc_ret * hp.gamma + r
        tr = {
            "raw_obs": env_state.obs,
            "obs": obs,
            "next_obs": norm_obs(p.cfg, state.obs_stats, nxt.info["final_obs"]),
            "action": action,
            "cluster": cluster,
            "logp": logp,
            "reward": r,
            "done": done,
            "term": done * (1.0 - nxt.info["truncation"]),
            "disc_return": disc_ret,
        }
        if p.cfg.value_target == "retrace":
            tr["raw_next_obs"] = nxt.info["final_obs"]
        carry = (nxt, ep_ret * (1.0 - done), disc_ret * (1.0 - done), fin_sum, fin_cnt)
        return carry, tr

    carry0 = (state.env_state, state.ep_return, state.disc_return, 0.0, 0.0)
    noise = draw_noise(key, (p.cfg.unroll_length, p.cfg.num_envs), p.env.action_size)
    carry, traj = jax.lax.scan(step, carry0, noise)
    return carry, traj


def make_batch(p: Parts, state: TrainState, traj: dict, hp: Hparams, sched: dict,
               ret_scale: jax.Array | float) -> tuple:
    """The update's samples, flattened to [B, ...]: the iteration's own (obs, action, cluster, logp) with
    GAE(lambda) advantages, and the value function's targets: GAE's on the same samples, or Retrace's on
    every slot of the buffer (which first takes this iteration's samples). -> (batch, new buffer)."""
    values = value(state.params["value"], traj["obs"])
    next_values = value(state.params["value"], traj["next_obs"])
    adv, target = compute_gae(
        traj["reward"] / ret_scale, values, next_values, traj["term"], traj["done"], hp.gamma, hp.gae_lambda
    )
    batch = {
        "obs": traj["obs"],
        "action": traj["action"],
        "cluster": traj["cluster"],
        "logp": traj["logp"],
        "adv": adv,
    }
    buffer = state.buffer
    if p.cfg.value_target == "gae":
        batch["target"] = target
    else:
        buffer = store(state.buffer, traj, state.iteration)
        batch.update(retrace_batch(p, state, buffer, hp, sched, ret_scale))
    return jax.tree.map(lambda x: x.reshape((p.cfg.batch_size,) + x.shape[2:]), batch), buffer


def retrace_batch(p: Parts, state: TrainState, buffer: dict, hp: Hparams, sched: dict,
                  ret_scale: jax.Array | float) -> dict:
    """Retrace targets of the buffer under the current policy: v_obs [T, E, N, d_s], v_target and v_weight
    [T, E, N] (slot axis after the sample axes, so minibatches take every slot of the samples they draw)."""
    obs, targets, _ = buffer_targets(
        buffer, lambda x: norm_obs(p.cfg, state.obs_stats, x), lambda x: value(state.params["value"], x),
        lambda o, a, c: p.v_log_prob(state.params["policy"], o, a, c, sched), ret_scale, hp.gamma, hp.gae_lambda)
    weight = jnp.broadcast_to(buffer["filled"][:, None, None], targets.shape)
    to_samples_first = lambda x: jnp.moveaxis(x, 0, 2)  # noqa: E731
    return {"v_obs": to_samples_first(obs), "v_target": to_samples_first(targets), "v_weight": to_samples_first(weight)}


def ppo_iteration(p: Parts, state: TrainState, hp: Hparams) -> tuple:
    """One PPO iteration. Returns (new state, dict of scalar metrics)."""
    it = state.iteration
    sched = schedule(hp, it)
    key, k_roll, k_upd = jax.random.split(state.key, 3)
    (env_state, ep_ret, disc_ret, fin_sum, fin_cnt), traj = rollout(p, state, hp, sched, k_roll)

    params = state.params
    ret_stats = update_stats(state.ret_stats, traj["disc_return"])
    ret_scale = jnp.sqrt(ret_stats["var"] + 1e-8) if p.cfg.normalize_reward else 1.0
    batch, buffer = make_batch(p, state, traj, hp, sched, ret_scale)
    frac = it.astype(jnp.float32) / jnp.maximum(hp.total_iterations, 1).astype(jnp.float32)
    lr = hp.lr * (1.0 - hp.anneal_lr * jnp.clip(frac, 0.0, 1.0))
    new_params, opt, stats = sgd_update(p, params, state.opt, batch, hp, sched, lr, k_upd)

    probs = p.v_probs(params["policy"], traj["obs"].reshape(-1, p.obs_size), sched)
    usage = jnp.mean(jax.nn.one_hot(traj["cluster"].reshape(-1), probs.shape[-1]), axis=0)
    new_state = TrainState(
        params=new_params,
        opt=opt,
        obs_stats=update_stats(state.obs_stats, traj["raw_obs"]) if p.cfg.normalize_obs else state.obs_stats,
        ret_stats=ret_stats,
        env_state=env_state,
        ep_return=ep_ret,
        disc_return=disc_ret,
        key=key,
        iteration=it + 1,
        failed_at=state.failed_at,
        buffer=buffer,
    )
    metrics = {
        "iteration": it + 1,
        "env_steps": (it + 1) * p.cfg.batch_size,
        "episode_return": jnp.where(fin_cnt > 0, fin_sum / jnp.maximum(fin_cnt, 1.0), jnp.nan),
        "episodes": fin_cnt,
        "epsilon": sched["epsilon"],
        "sigma_min": sched["sigma_min"],
        "lr": lr,
        "partition_entropy": jnp.mean(partition_entropy(probs)),
        "clusters_used": jnp.sum(usage >= 0.01).astype(jnp.int32),
        **stats,
    }
    return new_state, metrics


def run_chunk(p: Parts, state: TrainState, hp: Hparams, num_iterations: int) -> tuple:
    """num_iterations (static) PPO iterations in one lax.scan; metrics stacked [num_iterations]."""
    iteration = functools.partial(ppo_iteration, p)
    return jax.lax.scan(lambda s, _: guarded_iteration(iteration, s, hp), state, None, length=num_iterations)


def evaluate(p: Parts, params: dict, obs_stats: dict, hp: Hparams, key: jax.Array) -> tuple:
    """(mean return, failed episodes) of the deterministic controller (most probable cluster, mean action)
    over p.cfg.eval_envs full episodes from random starts (start_states of the evaluation env from key). A failed
    episode (non-finite reward or observation while alive: gsa_jax.algorithm.episodes) ends at its last finite
    step; the count says how many."""
    return evaluate_from(p, params, obs_stats, hp, start_states(p.eval_env, key, p.cfg.eval_envs))


def evaluate_from(p: Parts, params: dict, obs_stats: dict, hp: Hparams, starts: Any) -> tuple:
    """evaluate's episodes from the evaluation env's start states `starts` (the first p.cfg.eval_envs of them)."""
    sched = schedule(hp, jnp.zeros((), jnp.int32))
    s0 = jax.tree.map(lambda x: x[: p.cfg.eval_envs], starts)

    def cond(carry):
        _, _, alive, _, t = carry
        return (t < p.cfg.episode_length) & jnp.any(alive > 0)

    def body(carry):
        s, ret, alive, failed, t = carry
        action, _ = p.v_mode(params["policy"], norm_obs(p.cfg, obs_stats, s.obs), sched)
        s, reward, alive, failed_now = step_episodes(p.eval_env, s, jnp.clip(action, *envs.ACTION_RANGE), alive)
        return s, ret + reward, alive, failed | failed_now, t + 1

    # stop once every episode has ended: stepping finished envs is wasted work (and fallen
    # bodies pressed against limits make MJX's solver loop run long)
    zeros = jnp.zeros((p.cfg.eval_envs,), jnp.float32)
    init = (s0, zeros, zeros + 1.0, jnp.zeros((p.cfg.eval_envs,), bool), jnp.zeros((), jnp.int32))
    _, ret, _, failed, _ = jax.lax.while_loop(cond, body, init)
    return jnp.mean(ret), jnp.sum(failed).astype(jnp.int32)


def make_parts(cfg: Config, env: Any, eval_env: Any) -> Parts:
    """Parts of a run on the tasks env / eval_env (anything with reset, step, observation_size, action_size)."""
    policy = make_policy(cfg.policy, env.observation_size, env.action_size, cfg.k_max, cfg.hidden, cfg.b_init_scale,
                         cfg.subpolicy, cfg.partition)
    return Parts(cfg, env, eval_env, policy, env.observation_size,
                 jax.vmap(policy.sample, in_axes=(None, 0, 0, None)), jax.vmap(policy.log_prob, in_axes=(None, 0, 0, 0, None)),
                 jax.vmap(policy.mode, in_axes=(None, 0, None)), jax.vmap(policy.partition_probs, in_axes=(None, 0, None)))


def make_envs(cfg: Config, task: TaskRecord) -> tuple:
    """(training env, evaluation env) of a run of cfg on `task`, its record (envs.resolve at the edge; a task
    definition's too: envs.resolve(MyTask)), cfg validated against it (cfg.env its name; episode_length and
    randomize filled in: config.for_task). Where the run shares its start states (shares_starts), the evaluation
    env is the training env's inner env."""
    if isinstance(task, str):
        raise TypeError(f"make_envs takes a task's record, not its name: envs.resolve({task!r})")
    cfg.validate(task)
    env = make_env(cfg, task)
    if shares_starts(cfg):
        return env, env.env
    return env, make_env(cfg, task, auto_reset=False, randomized=cfg.eval_randomized)


def make_run_parts(cfg: Config, task: TaskRecord) -> Parts:
    """The Parts of a run of cfg on `task` (its record, as make_envs takes it); gsa_jax.benchmark.parts times them."""
    return make_parts(cfg, *make_envs(cfg, task))


def shares_starts(cfg: Config) -> bool:
    """Whether a run's evaluation env is its training env without the auto-reset (no randomization, reset mode
    'first') and at most twice as many envs as it evaluates with train: make_run_parts then makes it once, as the
    training env's inner env, and the training envs' start states are the evaluation env's (AutoReset.started):
    one reset program over max(num_envs, eval_envs) keys serves both (resets_shared), and each evaluation resets at
    most twice the envs it runs."""
    return not cfg.randomize and cfg.reset_mode == "first" and cfg.num_envs <= 2 * cfg.eval_envs


def resets_shared(p: Parts) -> bool:
    """Whether p's training env auto-resets (mode 'first') its very evaluation env (make_run_parts, shares_starts):
    then init_from_starts and evaluate_from start both from that env's reset."""
    return p.eval_env is getattr(p.env, "env", None) and getattr(p.env, "mode", None) == "first"


def init_from_starts(p: Parts, key: jax.Array, hp: Hparams, starts: Any) -> TrainState:
    """init_state where the training envs' start states are the first num_envs of `starts`, start states of the
    evaluation env that p.env auto-resets (shares_starts). From start_states(p.eval_env, env_key(key), num_envs)
    and more, it is init_state(p, key, hp)."""
    first = jax.tree.map(lambda x: x[: p.cfg.num_envs], starts)
    return init_from(p, key, hp, jax.vmap(p.env.started)(first))


def start_keys(p: Parts, key: jax.Array, n: int) -> jax.Array:
    """jax.random.split(key, n) padded with copies of its last key to max(num_envs, eval_envs): the one batch
    of the shared reset program (compile_single), so that init's and the evaluation's resets are one program."""
    keys = jax.random.split(key, n)
    size = max(p.cfg.num_envs, p.cfg.eval_envs)
    return jnp.concatenate([keys, jnp.repeat(keys[-1:], size - n, axis=0)])


def make_train(cfg: Config, env: Any, eval_env: Any) -> Trainer:
    """Bind the pieces of one training run to a static Config and its environments, as Brax's train takes an
    environment: Trainer(init, iteration, run_chunk, evaluate, ...). env: the training env (it auto-resets),
    eval_env: the evaluation env (episodes end); make_envs(cfg, task) builds both from a task's record."""
    p = make_parts(cfg, env, eval_env)
    bind = functools.partial
    return Trainer(p.cfg, p.env, p.policy, bind(init_state, p), bind(ppo_iteration, p), bind(run_chunk, p), bind(evaluate, p),
                   p)


def all_finite(tree: Any) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


def guarded_iteration(iteration: Callable, state: TrainState, hp: Hparams) -> tuple:
    """iteration(state, hp), masked: a run whose loss or new parameters are non-finite keeps its last
    state (last finite parameters), records the failing iteration in state.failed_at and stays
    frozen from then on; metrics['failed_at'] says so per iteration (-1 while healthy). Inside the
    compiled program, per run: a vmapped sweep keeps training its other runs, bit for bit."""
    new_state, metrics = iteration(state, hp)
    ok = (state.failed_at < 0) & jnp.isfinite(metrics["policy_loss"]) & jnp.isfinite(metrics["value_loss"])
    ok = ok & all_finite(new_state.params)
    kept = jax.tree.map(lambda n, o: jnp.where(ok, n, o), new_state, state)
    failed_at = jnp.where(ok | (state.failed_at >= 0), state.failed_at, state.iteration + 1)
    return kept._replace(failed_at=failed_at), dict(metrics, failed_at=failed_at)


def train(cfg: Config, task: TaskRecord, key: jax.Array, hp: Hparams, num_iterations: int) -> tuple:
    """A whole run of cfg on `task` (its record) as one pure function: (final state, metrics stacked over
    iterations)."""
    trainer = make_train(cfg, *make_envs(cfg, task))
    return trainer.run_chunk(trainer.init(key, hp), hp, num_iterations)
