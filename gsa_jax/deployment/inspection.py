"""A trained mixture controller read from its rollouts: cluster usage and dwell times, the active cluster over
an episode, visited states by cluster, each piece's L and b and, for a linear partition, its cells' inequalities in
the task's units and their figure (the files `gsa inspect` writes)."""

import json
import os
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.config import Config, config_record, make_hparams
from gsa_jax.algorithm.episodes import step_episodes
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.policies import draw_noise
from gsa_jax.algorithm.ppo import make_env, make_train, schedule
from gsa_jax.deployment.cells import cell_inequalities, cells_text, plot_cells
from gsa_jax.deployment.exporting import controller_arrays, task_layout
from gsa_jax.deployment.numpy_policy import Controller
from gsa_jax.errors import UserError
from gsa_jax.running.trained import FormatError, RunNotFound, read_run


class InspectError(UserError):
    """A run that cannot be inspected (not found, not a mixture, unreadable)."""


def load_run(address: str, require_mixture: bool = True) -> tuple:
    """(trainer, params, obs_stats, hparams, meta) of a finished or interrupted (mixture) run: a run directory
    or SWEEP_DIR/<run label> (gsa_jax.running.trained)."""
    try:
        run = read_run(address)
    except (RunNotFound, FormatError) as e:
        raise InspectError(str(e)) from None
    meta = run.meta
    if require_mixture and meta["config"]["policy"] != MIXTURE:
        raise InspectError(f"{address!r} is a {meta['config']['policy']!r} run; inspect reads mixture-of-linear runs")
    c = config_record(meta["config"])
    c["hidden"] = tuple(c["hidden"])
    trainer = make_train(Config(**c))
    hp = make_hparams(**meta["hparams"])
    like = jax.eval_shape(trainer.init, jax.random.PRNGKey(0), hp)
    loaded = unflatten_like({"params": like.params, "obs_stats": like.obs_stats}, run.params, address)
    return trainer, loaded["params"], loaded["obs_stats"], hp, meta


def unflatten_like(like: Any, arrays: dict, source: str) -> Any:
    """The arrays {key path: array} (gsa_jax.running.checkpoint.save_pytree's names) in the structure of `like`."""
    leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
    out = []
    for path, ref in leaves:
        key = jax.tree_util.keystr(path)
        if key not in arrays or arrays[key].shape != ref.shape:
            raise InspectError(f"{source!r}: params.npz has no {key} of shape {ref.shape}")
        out.append(jnp.asarray(arrays[key], ref.dtype))
    return jax.tree_util.tree_unflatten(treedef, out)


def last_iteration(meta: dict) -> int:
    """The iteration a run's saved params belong to (its schedules of eps and sigma_min depend on it)."""
    return int(meta.get("result", {}).get("iterations_done") or meta.get("iterations", 0))


def rollout_program(trainer: Any, episodes: int) -> Callable:
    """One compiled program for full episodes (no auto-reset) of either controller, so a caller wanting both compiles
    once: f(params, obs_stats, sched, key, deterministic: bool array []) -> dict of arrays [T, episodes, ...] and the
    alive mask (both the mean action and a sampled one are computed per step; `deterministic` picks one)."""
    cfg, pol = trainer.cfg, trainer.policy
    env = make_env(cfg, auto_reset=False)

    def episodes_of(params, obs_stats, sched, key, deterministic):
        def step(carry, noise):
            s, alive = carry
            z = normalize(obs_stats, s.obs) if cfg.normalize_obs else s.obs
            a_mode, c_mode = jax.vmap(pol.mode, in_axes=(None, 0, None))(params["policy"], z, sched)
            a_draw, c_draw, _ = jax.vmap(pol.sample, in_axes=(None, 0, 0, None))(params["policy"], z, noise, sched)
            a, c = jnp.where(deterministic, a_mode, a_draw), jnp.where(deterministic, c_mode, c_draw)
            nxt, reward, still, _ = step_episodes(env, s, jnp.clip(a, -1.0, 1.0), alive)
            out = {"obs": s.obs, "qpos": s.pipeline_state.qpos, "z": z, "cluster": c, "action": a, "reward": reward,
                   "alive": alive}
            return (nxt, still), out

        k_reset, k_run = jax.random.split(key)
        s0 = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))
        noise = draw_noise(k_run, (cfg.episode_length, episodes), env.action_size)
        return jax.lax.scan(step, (s0, jnp.ones((episodes,))), noise)[1]

    return jax.jit(episodes_of)


def play(program: Callable, params: dict, obs_stats: dict, hp: Any, key: jax.Array, deterministic: bool,
         iteration: int) -> dict:
    """Full episodes of a rollout_program at training iteration `iteration` (its schedules) -> NumPy arrays
    [T, episodes, ...] and the alive mask."""
    sched = schedule(hp, jnp.asarray(iteration, jnp.int32))
    return jax.device_get(program(params, obs_stats, sched, key, jnp.asarray(deterministic)))


def rollout(trainer: Any, params: dict, obs_stats: dict, hp: Any, key: jax.Array, episodes: int, deterministic: bool,
            iteration: int) -> dict:
    """Full episodes (no auto-reset) of the deterministic or the stochastic controller at training iteration
    `iteration` -> dict of arrays [T, episodes, ...] and alive mask."""
    return play(rollout_program(trainer, episodes), params, obs_stats, hp, key, deterministic, iteration)


def cluster_stats(cluster: np.ndarray, alive: np.ndarray, k: int) -> dict:
    """Usage fraction per cluster over alive steps, clusters used, mean dwell time (steps) and switches per episode."""
    mask = alive > 0.5
    used = cluster[mask]
    usage = np.bincount(used, minlength=k)[:k] / max(1, used.size)
    dwell, switches = [], []
    for e in range(cluster.shape[1]):
        seq = cluster[mask[:, e], e]
        if seq.size == 0:
            continue
        change = np.flatnonzero(np.diff(seq) != 0)
        switches.append(len(change))
        bounds = np.concatenate([[0], change + 1, [seq.size]])
        dwell.extend(np.diff(bounds))
    return {
        "usage": usage.tolist(),
        "clusters_used": int(np.sum(usage > 0)),
        "mean_dwell_steps": float(np.mean(dwell)) if dwell else 0.0,
        "switches_per_episode": float(np.mean(switches)) if switches else 0.0,
    }


def feature_names(subpolicy: str, obs_names: list) -> list:
    """Names of the sub-policy features phi(z) (the class's entry in gsa_jax.algorithm.subpolicies)."""
    return subpolicies.get(subpolicy).names(obs_names)


def controller_table(params: dict, k: int, obs_names: list, act_names: list, subpolicy: str = subpolicies.DEFAULT,
                     top: int = 3) -> str:
    L = np.asarray(params["policy"]["L"])[:k]
    b = np.asarray(params["policy"]["b"])[:k]
    names = feature_names(subpolicy, obs_names)
    shown = names[: len(obs_names)]  # quadratic: the table shows the linear terms; "strongest" ranks all
    rule = subpolicies.get(subpolicy).rule
    lines = [f"# {subpolicy.capitalize()} controllers", "",
             f"{rule} on the normalized observation z = (obs - mean) / std (clipped to +-10), "
             "for the cluster c the partition network picks.", ""]
    for c in range(k):
        head = ["actuator", "b", *shown] + (["strongest inputs"] if names else [])
        lines += [f"## cluster {c}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for i, a in enumerate(act_names):
            cells = [a, f"{b[c, i]:+.3f}", *(f"{x:+.2f}" for x in L[c, i, : len(shown)])]
            if names:
                order = np.argsort(-np.abs(L[c, i]))[:top]
                cells.append(", ".join(f"{names[j]} ({L[c, i, j]:+.2f})" for j in order))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def plot_time(data: dict, k: int, path: str, episode: int = 0, n_state: int = 6) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alive = data["alive"][:, episode] > 0.5
    t = np.flatnonzero(alive)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, gridspec_kw={"height_ratios": [1, 2]})
    ax1.step(t, data["cluster"][t, episode], where="post", color="k", lw=1)
    ax1.scatter(t, data["cluster"][t, episode], c=data["cluster"][t, episode], cmap="tab10", vmin=0, vmax=9, s=6)
    ax1.set_ylabel("active cluster")
    ax1.set_yticks(range(k))
    ax1.set_title(f"deterministic controller, episode {episode}: return {data['reward'][:, episode].sum():.1f}")
    obs = data["obs"][t, episode]
    var = np.argsort(-obs.std(axis=0))[:n_state]
    for j in var:
        ax2.plot(t, obs[:, j], lw=1, label=f"obs[{j}]")
    ax2.set_xlabel("step")
    ax2.set_ylabel("state (raw)")
    ax2.legend(fontsize=7, ncol=3, loc="upper right")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_pca(data: dict, k: int, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mask = data["alive"] > 0.5
    z = data["z"][mask]
    c = data["cluster"][mask]
    zc = z - z.mean(axis=0)
    _, s, vt = np.linalg.svd(zc, full_matrices=False)
    p = zc @ vt[:2].T
    explained = (s[:2] ** 2) / max(np.sum(s**2), 1e-12)
    fig, ax = plt.subplots(figsize=(6.4, 5))
    for ci in range(k):
        sel = c == ci
        if np.any(sel):
            ax.scatter(p[sel, 0], p[sel, 1], s=3, alpha=0.5, color=plt.cm.tab10(ci % 10), label=f"cluster {ci} ({sel.mean():.0%})")
    ax.set_xlabel(f"PC1 ({explained[0]:.0%} of variance)")
    ax.set_ylabel(f"PC2 ({explained[1]:.0%} of variance)" if len(explained) > 1 else "PC2")
    ax.set_title("visited states (normalized), coloured by active cluster")
    ax.legend(fontsize=8, markerscale=4)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_cells(address: str, out: str, visited: np.ndarray) -> list:
    """A linear partition's cells (gsa_jax.deployment.cells) from the run's exported controller: out/cells.txt (named
    by the task's observation layout where it has one) and out/cells.png with the visited states [n, d_s] ->
    [{cluster, versus, A, d}] for summary.json."""
    arrays = controller_arrays(address)
    ctrl = Controller(arrays)
    names = task_layout(arrays) or [f"obs[{j}]" for j in range(ctrl.obs_mean.shape[0])]
    with open(os.path.join(out, "cells.txt"), "w") as f:
        f.write(cells_text(ctrl, names))
    if len(names) >= 2:
        plot_cells(ctrl, names, os.path.join(out, "cells.png"), visited)
    return [{"cluster": c.cluster, "versus": c.others, "A": c.A.tolist(), "d": c.d.tolist()} for c in cell_inequalities(ctrl)]


def default_out(address: str) -> str:
    """<run dir>/inspect/, or SWEEP_DIR/inspect/<run label>/ for a sweep's run."""
    if os.path.exists(os.path.join(address, "config.json")):
        return os.path.join(address, "inspect")
    return os.path.join(os.path.dirname(os.path.normpath(address)), "inspect", os.path.basename(os.path.normpath(address)))


def inspect_run(run_dir: str, out: str | None = None, episodes: int = 8, seed: int = 0) -> tuple:
    trainer, params, obs_stats, hp, meta = load_run(run_dir)
    k = int(meta["hparams"]["K"])
    out = out or default_out(run_dir)
    os.makedirs(out, exist_ok=True)
    last_it = last_iteration(meta)
    key = jax.random.PRNGKey(seed)
    program = rollout_program(trainer, episodes)  # compiled once for both controllers
    det = play(program, params, obs_stats, hp, key, True, last_it)
    sto = play(program, params, obs_stats, hp, key, False, last_it)
    ret_det, ret_sto = det["reward"].sum(0), sto["reward"].sum(0)
    summary = {
        "run_dir": run_dir, "env": trainer.cfg.env, "K": k, "episodes": episodes,
        "return_deterministic_mean": float(ret_det.mean()), "return_deterministic": ret_det.tolist(),
        "return_stochastic_mean": float(ret_sto.mean()), "return_stochastic": ret_sto.tolist(),
        "episode_length_deterministic": (det["alive"].sum(0)).tolist(),
        "deterministic": cluster_stats(det["cluster"], det["alive"], k),
        "stochastic": cluster_stats(sto["cluster"], sto["alive"], k),
    }
    if partitions.get(trainer.cfg.partition).polyhedral:
        summary["cells"] = write_cells(run_dir, out, det["obs"][det["alive"] > 0.5])
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    d_s, d_a = det["obs"].shape[-1], det["action"].shape[-1]
    with open(os.path.join(out, "controllers.md"), "w") as f:
        f.write(controller_table(params, k, [f"obs[{j}]" for j in range(d_s)], [f"act[{i}]" for i in range(d_a)],
                                  trainer.cfg.subpolicy))
    plot_time(det, k, os.path.join(out, "clusters_time.png"))
    plot_pca(det, k, os.path.join(out, "clusters_pca.png"))
    return summary, out
