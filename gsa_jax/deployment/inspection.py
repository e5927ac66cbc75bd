"""A trained mixture controller read from its rollouts: cluster usage and dwell times, the active cluster over
an episode, visited states by cluster, each piece as u = u0 + K (x - x*) in the task's units and, for a linear
partition, its cells' inequalities in the task's units and their figure (the files `gsa inspect` writes); an
exported controller's pieces and cells without rollouts (inspect_file)."""

import json
import os
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.algorithm.config import Config, config_record, make_hparams
from gsa_jax.algorithm.episodes import step_episodes
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.policies import draw_noise
from gsa_jax.algorithm.ppo import make_env, schedule
from gsa_jax.deployment.cells import cell_inequalities, cells_text, plot_cells
from gsa_jax.deployment.exporting import controller_arrays, known_task, load_arrays, task_layout
from gsa_jax.deployment.numpy_policy import Controller, task_name
from gsa_jax.errors import UserError
from gsa_jax.running.formats import FormatError
from gsa_jax.running.tasks import task_of, trainer_for
from gsa_jax.running.trained import RunNotFound, read_run


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
    trainer = trainer_for(Config(**c))
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
    env = make_env(cfg, task_of(cfg), auto_reset=False)

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


class Frame(NamedTuple):
    """The units the pieces' laws are written in: x the raw observation, z = (x - mean) / std, around x*."""

    mean: np.ndarray  # [d_s] float64
    std: np.ndarray  # [d_s] float64
    x_star: np.ndarray  # [d_s] the point the laws are expanded around
    reference: str  # what x* is, in words


class PieceLaw(NamedTuple):
    """A piece's raw action in its frame: u = u0 + K (x - x*) + sum_{i <= j} Q[:, i, j] (x_i - x*_i) (x_j - x*_j)."""

    u0: np.ndarray  # [d_a] the raw action at x*
    K: np.ndarray  # [d_a, d_s] d u / d x at x*: action per unit of each observation
    Q: np.ndarray  # [d_a, d_s, d_s] upper triangle: a quadratic piece's second-order terms (else zeros)


def piece_laws(L: np.ndarray, b: np.ndarray, subpolicy: str, frame: Frame) -> list:
    """[PieceLaw] of pieces L [K, d_a, d_phi], b [K, d_a] acting L_c phi(z) + b_c, the normalization folded in: exact
    for constant, linear and quadratic pieces while the observation clip does not act (to first order otherwise)."""
    std = np.asarray(frame.std, np.float64)
    z = (np.asarray(frame.x_star, np.float64) - frame.mean) / std
    sub, d_s = subpolicies.get(subpolicy), len(z)
    phi, jac = sub.features(z, np), sub.jacobian(z)
    i, j = np.triu_indices(d_s)
    laws = []
    for l_c, b_c in zip(np.asarray(L, np.float64), np.asarray(b, np.float64)):
        q = np.zeros((len(b_c), d_s, d_s))
        if subpolicy == subpolicies.QUADRATIC.name:  # z_i z_j = ... + (dx_i / std_i) (dx_j / std_j)
            q[:, i, j] = l_c[:, d_s:] / (std[i] * std[j])
        laws.append(PieceLaw(l_c @ phi + b_c, l_c @ jac / std, q))
    return laws


def reference_point(arrays: dict) -> tuple:
    """(x* [d_s], what it is): the task's equilibrium observation where it declares one (Task.equilibrium_qpos at
    rest, observed in MuJoCo C as gsa verify forms it), else the normalization mean."""
    from envs.task import TaskC

    mean = np.asarray(arrays["obs_mean"], np.float64)
    record = known_task(arrays)
    try:
        task = record.new() if record is not None and record.verifiable else None
    except (ValueError, ImportError, NotImplementedError):
        task = None
    q = None if task is None or task.equilibrium_qpos is None else np.asarray(task.equilibrium_qpos, np.float64)
    try:  # mj_forward there (a task with a goal drawn at reset has no one observation of it)
        x = None if q is None else np.asarray(TaskC(task).set_start(q, np.zeros(task.model.nv)), np.float64)
    except ValueError:
        x = None
    if x is not None and x.shape == mean.shape:
        return x, f"the task's equilibrium observation ({record.name}'s equilibrium_qpos {np.round(q, 6).tolist()}, at rest)"
    return mean, "the normalization mean (no equilibrium observation of the task here)"


def action_names(arrays: dict, d_a: int) -> list:
    """The task's actuator names [d_a] (its MuJoCo model's; an unnamed one by the joint it drives), else act[i]."""
    import mujoco

    record = known_task(arrays)
    try:
        model = None if record is None else record.model()
    except (ValueError, ImportError, NotImplementedError):
        model = None
    if model is None or model.nu != d_a:
        return [f"act[{i}]" for i in range(d_a)]
    joint = lambda i: (model.joint(int(model.actuator_trnid[i, 0])).name  # noqa: E731
                       if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT else "")
    return [model.actuator(i).name or joint(i) or f"act[{i}]" for i in range(d_a)]


class Readout(NamedTuple):
    """An exported mixture controller with what its laws are written in."""

    ctrl: Controller
    obs_names: list
    act_names: list
    frame: Frame
    task: str


def readout(arrays: dict) -> Readout:
    """The Readout of exported mixture arrays: the task's observation layout and actuator names (obs[i] / act[i]
    where it has none), the task-unit frame around reference_point."""
    ctrl = Controller(arrays)
    d_s = ctrl.obs_mean.shape[0]
    x_star, reference = reference_point(arrays)
    frame = Frame(ctrl.obs_mean.astype(np.float64), ctrl.obs_std.astype(np.float64), x_star, reference)
    return Readout(ctrl, task_layout(arrays) or [f"obs[{j}]" for j in range(d_s)],
                   action_names(arrays, ctrl.action_size), frame, task_name(arrays) or "?")


def cell_words(ctrl: Controller) -> str:
    """Where a piece acts, in words."""
    if ctrl.single_piece:
        return "acts on every state (one piece, no partition)"
    if partitions.get(ctrl.partition).polyhedral:
        return "acts on its cell of the linear partition (inequalities A x >= d in the task's units: cells.txt)"
    return "acts where the partition network (a tanh MLP) picks it: a region, in general not a polyhedron"


def validity(ctrl: Controller) -> str:
    """Where the laws hold exactly and what act() does after them."""
    inside = (f"while every |x_i - mean_i| <= {ctrl.obs_clip:g} std_i (the controller's observation clip; beyond it "
              "x_i is clipped first)" if np.isfinite(ctrl.obs_clip) else "everywhere (no observation clip)")
    if ctrl.action_low is None:
        return f"exact {inside}"
    low, high = (np.round(v, 6).tolist() for v in ctrl.bounds())
    return f"exact {inside}; act() then clips u to its bounds, low {low}, high {high}"


def _terms(values, names, digits: int = 6) -> str:
    return "  ".join(f"{v:+.{digits}g} {n}" for v, n in zip(values, names))


def laws_text(r: Readout) -> str:
    """Every piece as u = u0 + K (x - x*) in the task's units, named, with where it acts (gsa inspect prints it)."""
    ctrl, f = r.ctrl, r.frame
    laws = piece_laws(ctrl.L, ctrl.b, ctrl.subpolicy, f)
    law = {subpolicies.CONSTANT.name: "u = u0", subpolicies.LINEAR.name: "u = u0 + K (x - x*)",
           subpolicies.QUADRATIC.name: "u = u0 + K (x - x*) + sum_{i<=j} Q_ij (x_i - x*_i) (x_j - x*_j)"}
    k = ctrl.num_clusters
    other = f"u = u0 + K (x - x*) + the {ctrl.subpolicy} features' terms beyond first order (K: the gradient at x*)"
    lines = [f"{r.task}: {k} {ctrl.subpolicy} piece{'s' * (k > 1)}, each piece's raw action",
             f"  {law.get(ctrl.subpolicy, other)}",
             "x: the task's raw observation in its own units (the normalization z = (x - mean) / std folded in: "
             f"K = L / std); {validity(ctrl)}.", f"x* = {f.reference}:"]
    lines += [f"  [{i}] {n} = {v:+.6g}" for i, (n, v) in enumerate(zip(r.obs_names, f.x_star))]
    still = [n for n, v in zip(r.obs_names, ctrl.obs_std) if v < 1.01e-4]  # var 0: std is the normalizer's 1e-8 floor
    if still:
        lines.append(f"note: {len(still)} observation(s) never varied in training ({', '.join(still[:3])}"
                     f"{', ...' if len(still) > 3 else ''}): std 1e-4, so their gains L / 1e-4 were never exercised.")
    if np.any(np.abs(f.x_star - f.mean) > ctrl.obs_clip * f.std):
        lines.append("note: x* lies outside the observation clip: u0 is the law's value there, not act(x*).")
    pairs = np.triu_indices(len(r.obs_names))
    for c, law in enumerate(laws):
        lines += [f"piece {c}: {cell_words(ctrl)}", f"  u0 (the raw action at x*):  {_terms(law.u0, r.act_names)}"]
        if ctrl.L.shape[-1]:
            lines.append("  K (action per unit of each observation):")
            lines += [f"    {a}:  {_terms(row, r.obs_names)}" for a, row in zip(r.act_names, law.K)]
        if law.Q.any():
            quad = [f"{r.obs_names[i]}*{r.obs_names[j]}" for i, j in zip(*pairs)]
            lines.append("  Q (per unit of each observation product):")
            lines += [f"    {a}:  {_terms(q[pairs], quad)}" for a, q in zip(r.act_names, law.Q)]
    return "\n".join(lines) + "\n"


def controller_table(params: dict, k: int, obs_names: list, act_names: list, subpolicy: str = subpolicies.DEFAULT,
                     top: int = 3, frame: Frame | None = None, where: str = "acts where the partition picks it") -> str:
    """controllers.md: per cluster, u0 and the gains K of u = u0 + K (x - x*) in `frame`'s units (None: the
    normalized observation z itself, x* = 0), with the inputs that move each action most per observation std."""
    L, b = np.asarray(params["policy"]["L"])[:k], np.asarray(params["policy"]["b"])[:k]
    d_s = len(obs_names)
    frame = frame or Frame(np.zeros(d_s), np.ones(d_s), np.zeros(d_s), "0 (the normalized observation z itself)")
    quadratic = "; its quadratic terms Q_ij (x_i - x*_i) (x_j - x*_j) under each table" * (
        subpolicy == subpolicies.QUADRATIC.name)
    lines = [f"# {subpolicy.capitalize()} controllers", "",
             f"{subpolicies.get(subpolicy).rule} on the normalized observation z = (x - mean) / std (clipped to +-10 "
             "std), written as u = u0 + K (x - x*): u0 the raw action at x*, K = L / std the action per unit of each "
             f"observation{quadratic}; x* = {frame.reference}.", "",
             "| | " + " | ".join(obs_names) + " |", "|---|" + "---|" * d_s,
             "| x* | " + " | ".join(f"{v:+.4g}" for v in frame.x_star) + " |",
             "| std | " + " | ".join(f"{v:.4g}" for v in frame.std) + " |", ""]
    for c, law in enumerate(piece_laws(L, b, subpolicy, frame)):
        lines += [f"## cluster {c}", "", f"{where[0].upper()}{where[1:]}.", ""]
        lines += _piece_table(law, L[c], obs_names, act_names, feature_names(subpolicy, obs_names), top) + [""]
    return "\n".join(lines)


def _piece_table(law: PieceLaw, L: np.ndarray, obs_names: list, act_names: list, names: list, top: int) -> list:
    """One cluster's markdown rows: action, u0, K per observation, its strongest features (L, per std); then Q."""
    gains = obs_names if names else []  # constant pieces: u0 alone
    head = ["action", "u0", *gains] + (["strongest inputs (per std)"] if names else [])
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for a, action in enumerate(act_names):
        order = np.argsort(-np.abs(L[a]))[:top]  # L: the action's change per feature, in std units
        strongest = [", ".join(f"{names[j]} ({L[a, j]:+.2f})" for j in order)] if names else []
        rows.append("| " + " | ".join([action, f"{law.u0[a]:+.4g}", *(f"{x:+.4g}" for x in law.K[a][: len(gains)]),
                                       *strongest]) + " |")
    if law.Q.any():
        i, j = np.triu_indices(len(obs_names))
        pairs = [f"{obs_names[p]}*{obs_names[q]}" for p, q in zip(i, j)]
        rows += [""] + [f"- Q of {action}: {_terms(law.Q[a][i, j], pairs, 4)}" for a, action in enumerate(act_names)]
    return rows


def pieces_json(r: Readout) -> dict:
    """summary.json's pieces: x* (and what it is), names, each piece's u0, K (and Q) in the task's units."""
    laws = piece_laws(r.ctrl.L, r.ctrl.b, r.ctrl.subpolicy, r.frame)
    return {"x_star": r.frame.x_star.tolist(), "x_star_is": r.frame.reference, "observations": r.obs_names,
            "actions": r.act_names, "cell": cell_words(r.ctrl),
            "pieces": [{"u0": law.u0.tolist(), "K": law.K.tolist(), **({"Q": law.Q.tolist()} if law.Q.any() else {})}
                       for law in laws]}


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


def polyhedral(ctrl: Controller) -> bool:
    """Whether the controller's cells are a linear partition's polyhedra (cells.txt); a single piece has none."""
    return not ctrl.single_piece and partitions.get(ctrl.partition).polyhedral


def write_readout(r: Readout, out: str, visited: np.ndarray | None = None) -> tuple:
    """Write out/pieces.txt (laws_text, what gsa inspect prints), out/controllers.md (controller_table in the task's
    units) and, for a linear partition, out/cells.txt and out/cells.png (with the visited states [n, d_s] where
    given) -> (summary.json's entries: pieces (pieces_json) and cells [{cluster, versus, A, d}], the names written)."""
    ctrl = r.ctrl
    files = {"pieces.txt": laws_text(r), "controllers.md": controller_table(
        {"policy": {"L": ctrl.L, "b": ctrl.b}}, ctrl.num_clusters, r.obs_names, r.act_names, ctrl.subpolicy,
        frame=r.frame, where=cell_words(ctrl))}
    entries = {"pieces": pieces_json(r)}
    if polyhedral(ctrl):
        files["cells.txt"] = cells_text(ctrl, r.obs_names)
        entries["cells"] = [{"cluster": c.cluster, "versus": c.others, "A": c.A.tolist(), "d": c.d.tolist()}
                            for c in cell_inequalities(ctrl)]
    for name, text in files.items():
        with open(os.path.join(out, name), "w") as f:
            f.write(text)
    if polyhedral(ctrl) and len(r.obs_names) >= 2:
        plot_cells(ctrl, r.obs_names, os.path.join(out, "cells.png"), visited)
        files["cells.png"] = ""
    return entries, list(files)


def inspect_file(path: str, out: str | None = None) -> tuple:
    """(text, the files written) of an exported controller .npz, no rollouts: every piece's law in the task's units
    and its cell (laws_text, then a linear partition's inequalities); with out, written there too (write_readout and
    summary.json; else none)."""
    arrays = load_arrays(path)
    if str(arrays["kind"]) != MIXTURE:
        raise InspectError(f"{path!r} is a flat {str(arrays['kind'])!r} controller; inspect reads mixtures of "
                           "linear pieces")
    r = readout(arrays)
    text = laws_text(r) + (cells_text(r.ctrl, r.obs_names) if polyhedral(r.ctrl) else "")
    if out is None:
        return text, []
    os.makedirs(out, exist_ok=True)
    entries, written = write_readout(r, out)
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump({"controller": path, "env": r.task, "K": r.ctrl.num_clusters, **entries}, f, indent=1)
    return text, ["summary.json", *written]


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
    summary.update(write_readout(readout(controller_arrays(run_dir)), out, det["obs"][det["alive"] > 0.5])[0])
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    plot_time(det, k, os.path.join(out, "clusters_time.png"))
    plot_pca(det, k, os.path.join(out, "clusters_pca.png"))
    return summary, out
