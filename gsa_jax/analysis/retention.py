"""Exported controllers under shifted physics, observations and actions: their retained fraction of
nominal return, action sensitivity, aggregates with rliable's intervals and the figures; `python -m
gsa_jax.robustness` is its command."""

import csv
import glob
import json
import math
import os

import numpy as np

import envs
from envs import action_size, check_name
from gsa_jax.analysis import stats
from gsa_jax.analysis.figures import plot_profiles
from gsa_jax.analysis.results import read_csv, write_csv
from gsa_jax.deployment.evaluation import DeployError, load_controller
from gsa_jax.deployment.shifts import PUSH_RATE, Shift, applies, run_shifted
from gsa_jax.running.runinfo import run_metadata

START_SEED = 10_000
TIDY = ("env", "policy", "K", "seed", "shift", "level", "score", "nominal_score", "random_score", "retained_fraction")
MULTIPLIERS = (0.5, 1, 2, 4)
EARLY_PUSHES = 300  # env steps: paired_pushes_early.csv's pushes


class RobustnessError(ValueError):
    pass


def load_controllers(paths):
    """[(path, meta {env, policy, K, seed}, controller)] of exported controllers in files or directories."""
    files = []
    for p in paths:
        if os.path.isdir(p):
            files += sorted(glob.glob(os.path.join(p, "**", "*.npz"), recursive=True))
        elif os.path.isfile(p):
            files.append(p)
        else:
            raise RobustnessError(f"{p!r} is neither a controller file nor a directory")
    if not files:
        raise RobustnessError(f"no exported controller (.npz) in {', '.join(paths)}")
    out = []
    for f in files:
        try:
            ctrl, env_name, _ = load_controller(f)
            with np.load(f, allow_pickle=False) as z:
                meta = json.loads(str(z["config_json"]))
            check_name(env_name)  # a task defined outside the package: importable from here, in one line if not
        except (DeployError, ValueError) as e:
            raise RobustnessError(f"{f}: {e}") from None
        k = ctrl.num_clusters if ctrl.kind == "mixture" else ""
        out.append((f, {"env": env_name, "policy": ctrl.kind, "K": k, "seed": int(meta.get("seed", 0))}, ctrl))
    return out


class RandomController:
    """Uniform random actions in [-1, 1] (seeded): the 0 of the retained fraction."""

    def __init__(self, action_size, seed=0):
        self.rng, self.action_size = np.random.default_rng(seed), action_size
        self.obs_std = np.ones(1)  # unused: a random policy's shifts never read it (same law under noise)

    def act(self, obs):
        return self.rng.uniform(-1.0, 1.0, obs.shape[:-1] + (self.action_size,))


def random_score(env_name, shift, seeds):
    """Mean return of the random policy under the shift from the same starts."""
    ctrl = RandomController(action_size(env_name))
    same_law = shift.kind in ("obs_noise", "action_delay")  # a random policy ignores what it sees and when
    returns, _, _ = run_shifted(ctrl, env_name, Shift("nominal") if same_law else shift, seeds)
    return float(returns.mean())


def action_jacobian_norms(ctrl, obs):
    """[N] Frobenius norms of d action / d z at observations obs [N, d_s], z the normalized observation:
    a mixture's active piece L_c (linear sub-policies), an MLP's Jacobian through its tanh layers."""
    if ctrl.kind == "mixture":
        if ctrl.subpolicy != "linear":
            raise RobustnessError(f"sensitivity is defined for linear sub-policies, not {ctrl.subpolicy!r}")
        return np.linalg.norm(ctrl.L[ctrl.cluster(obs)], axis=(1, 2))
    x = ctrl.normalize(obs)
    jac = np.broadcast_to(np.eye(x.shape[-1], dtype=np.float32), (len(x),) + (x.shape[-1],) * 2)
    for i, (w, b) in enumerate(ctrl.layers):
        x = x @ w + b
        jac = jac @ w
        if i < len(ctrl.layers) - 1:
            x = np.tanh(x)
            jac = jac * (1.0 - x * x)[:, None, :]
    return np.linalg.norm(jac, axis=(1, 2))


def evaluate_controller(meta, ctrl, shifts, seeds, randoms):
    """Tidy rows of one controller under every applicable shift, and its sensitivity along its nominal episodes."""
    nominal, _, seen = run_shifted(ctrl, meta["env"], Shift("nominal"), seeds, record=True)
    rows = []
    for shift in shifts:
        if not applies(meta["env"], shift):
            continue
        score = nominal.mean() if shift.kind == "nominal" else run_shifted(ctrl, meta["env"], shift, seeds)[0].mean()
        rand = randoms[(meta["env"], shift)]
        scale = nominal.mean() - rand
        rows.append({**meta, "shift": shift.kind, "level": shift.level, "score": round(float(score), 3),
                     "nominal_score": round(float(nominal.mean()), 3), "random_score": round(rand, 3),
                     "retained_fraction": round(float((score - rand) / scale), 4) if abs(scale) > 1e-9 else math.nan})
    return rows, float(np.mean(action_jacobian_norms(ctrl, seen.astype(np.float32))))


def controller_key(meta):
    return (meta["env"], meta["policy"], str(meta["K"]), str(meta["seed"]))


def evaluate_all(controllers, shifts, episodes, out, log=lambda m: print(m, flush=True)):
    """Evaluate every controller not yet in OUT/robustness.csv; returns (tidy rows, sensitivity rows)."""
    tidy_path, sens_path = os.path.join(out, "robustness.csv"), os.path.join(out, "sensitivity.csv")
    rows, sens = read_csv(tidy_path), read_csv(sens_path)
    done = {controller_key(r) for r in sens}
    seeds = np.arange(START_SEED, START_SEED + episodes)
    randoms = {}
    for i, (path, meta, ctrl) in enumerate(controllers):
        if controller_key(meta) in done:
            continue
        for shift in shifts:
            if applies(meta["env"], shift) and (meta["env"], shift) not in randoms:
                randoms[(meta["env"], shift)] = random_score(meta["env"], shift, seeds)
        new, sensitivity = evaluate_controller(meta, ctrl, shifts, seeds, randoms)
        kept = [float(r["retained_fraction"]) for r in new if r["shift"] != "nominal"]
        rows += new
        sens.append({**meta, "sensitivity": round(sensitivity, 5), "mean_retained_fraction": round(float(np.nanmean(kept)), 4),
                     "controller": os.path.basename(path)})
        write_csv(tidy_path, rows, TIDY)
        write_csv(sens_path, sens)
        log(f"[{i + 1}/{len(controllers)}] {os.path.basename(path)}: nominal {new[0]['score']:.1f}, "
            f"mean retained fraction {np.nanmean(kept):.3f}, sensitivity {sensitivity:.3g}")
    return rows, sens


def config_names(policy, k, action_dim):
    """['flat PPO'] or ['K = m d_a', ...] for every Figure-1 multiplier m whose ceil(m d_a) is K (on a
    one-action task K = 1 is both 0.5 and 1 d_a), else ['K = k']."""
    if policy == "mlp":
        return ["flat PPO"]
    ms = [m for m in MULTIPLIERS if max(1, math.ceil(m * action_dim - 1e-9)) == int(k)]
    return [f"K = {m:g} d_a" for m in ms] or [f"K = {k}"]


def cells(rows):
    """{(env, policy, K, shift name): {seed: row}} of tidy rows (strings or numbers)."""
    out = {}
    for r in rows:
        name = Shift(r["shift"], float(r["level"] or 0)).name
        out.setdefault((r["env"], r["policy"], str(r["K"]), name), {})[str(r["seed"])] = r
    return out


def aggregate(rows, reps=stats.REPS):
    """aggregate.csv rows: per task x (policy, K) x shift, IQM [CI] of retained fraction and shifted score,
    P(retains more than flat PPO) [CI] for mixtures (runs paired by nothing: rliable's P over runs)."""
    by = cells(rows)
    retained = {c: np.array([float(r["retained_fraction"]) for r in v.values()]) for c, v in by.items()}
    score = {c: np.array([float(r["score"]) for r in v.values()]) for c, v in by.items()}
    iqm_r = stats.iqm_ci({str(c): x[np.isfinite(x)][:, None] for c, x in retained.items()}, reps=reps)
    iqm_s = stats.iqm_ci({str(c): x[:, None] for c, x in score.items()}, reps=reps)
    pairs = {str(c): (retained[c][:, None], retained[(c[0], "mlp", "", c[3])][:, None]) for c in by
             if c[1] == "mixture" and (c[0], "mlp", "", c[3]) in by}
    better = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    out = []
    for c in sorted(by, key=lambda c: (c[0], c[1] != "mlp", int(c[2] or 0), c[3])):
        p = better.get(str(c), (math.nan,) * 3)
        r3 = lambda v: round(float(v), 3) if np.isfinite(v) else ""  # noqa: E731
        out.append({"env": c[0], "policy": c[1], "K": c[2], "shift": c[3], "runs": len(by[c]),
                    "retained_iqm": r3(iqm_r[str(c)][0]), "retained_ci_low": r3(iqm_r[str(c)][1]),
                    "retained_ci_high": r3(iqm_r[str(c)][2]), "score_iqm": r3(iqm_s[str(c)][0]),
                    "score_ci_low": r3(iqm_s[str(c)][1]), "score_ci_high": r3(iqm_s[str(c)][2]),
                    "p_retains_more_than_flat_ppo": r3(p[0]), "p_ci_low": r3(p[1]), "p_ci_high": r3(p[2])})
    return out


def correlations(sens, rows=()):
    """correlation.csv rows: Spearman's rho (and its p-value) between sensitivity and mean retained
    fraction across controllers, per task and pooled (ranks within each task); with the tidy rows, also
    the partial rank correlation controlling for the controller's nominal score (fairness.partial_spearman)."""
    from scipy.stats import rankdata

    nominal = {controller_key(r): float(r["nominal_score"]) for r in rows if r["shift"] == "nominal"}
    out, pooled = [], []
    for env_name in sorted({r["env"] for r in sens}):
        mine = [r for r in sens if r["env"] == env_name]
        xyz = np.array([[float(r["sensitivity"]), float(r["mean_retained_fraction"]), nominal.get(controller_key(r), math.nan)]
                        for r in mine]).reshape(-1, 3)
        xyz = xyz[np.isfinite(xyz[:, :2]).all(1)]
        if len(xyz) < 3:
            continue
        out.append(correlation_row(env_name, xyz))
        pooled.append(np.stack([(rankdata(c) - 1) / (len(c) - 1) for c in xyz.T], axis=1))
    if len(out) > 1:
        out.append(correlation_row("all (ranks within task)", np.concatenate(pooled)))
    return out


def correlation_row(name, xyz):
    """One correlation.csv row of [n, 3] (sensitivity, mean retained fraction, nominal score)."""
    from scipy.stats import spearmanr

    from gsa_jax.analysis.fairness import partial_spearman

    rho, p = spearmanr(xyz[:, 0], xyz[:, 1])
    row = {"env": name, "controllers": len(xyz), "spearman_rho": round(float(rho), 3), "p_value": float(f"{p:.3g}"),
           "partial_rho_given_nominal": "", "partial_p_value": ""}
    if np.isfinite(xyz[:, 2]).all() and len(xyz) > 3:
        prho, pp = partial_spearman(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        row.update(partial_rho_given_nominal=round(prho, 3), partial_p_value=float(f"{pp:.3g}"))
    return row


def plot_robustness(agg, path):
    """Per task: retained fraction (IQM, 95% CI) under each shift, flat PPO and each K side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in agg))
    fig, axes = plt.subplots(len(env_names), 1, figsize=(11, 3.4 * len(env_names)), squeeze=False)
    for ax, env_name in zip(axes[:, 0], env_names):
        rows = [r for r in agg if r["env"] == env_name and r["shift"] != "nominal" and r["retained_iqm"] != ""]
        shifts = list(dict.fromkeys(r["shift"] for r in rows))
        configs = list(dict.fromkeys((r["policy"], r["K"]) for r in rows))
        width = 0.8 / max(1, len(configs))
        for j, (policy, k) in enumerate(configs):
            pts = {r["shift"]: r for r in rows if (r["policy"], r["K"]) == (policy, k)}
            x = np.array([i for i, sh in enumerate(shifts) if sh in pts]) + (j - (len(configs) - 1) / 2) * width
            y = np.array([pts[sh]["retained_iqm"] for sh in shifts if sh in pts], float)
            err = np.array([[pts[sh]["retained_iqm"] - pts[sh]["retained_ci_low"], pts[sh]["retained_ci_high"] - pts[sh]["retained_iqm"]]
                            for sh in shifts if sh in pts], float).T
            ax.bar(x, y, width, yerr=err, capsize=2, color="k" if policy == "mlp" else None, alpha=0.8,
                   label="flat PPO (MLP 64x64)" if policy == "mlp" else f"K = {k}")
        ax.axhline(1.0, color="gray", lw=0.8, ls="--")
        ax.set_xticks(range(len(shifts)), shifts, fontsize=8)
        ax.set(title=env_name, ylabel="retained fraction (IQM)")
        ax.legend(fontsize=7, ncol=len(configs))
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Deterministic controllers under shifts: (score - random) / (nominal - random), 95% bootstrap CI", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def profile_scores(rows, action_dims):
    """{(configuration name,): (tasks, [runs, tasks] retained fractions)}: each run's mean over its shifts
    (tasks with every configuration only; runs beyond the fewest of a task dropped to align the matrix)."""
    per = {}
    for r in rows:
        if r["shift"] == "nominal" or r["retained_fraction"] in ("", None) or not np.isfinite(float(r["retained_fraction"])):
            continue
        for name in config_names(r["policy"], r["K"], action_dims[r["env"]]):
            per.setdefault(name, {}).setdefault(r["env"], {}).setdefault(str(r["seed"]), []).append(float(r["retained_fraction"]))
    tasks = sorted(set.intersection(*(set(v) for v in per.values()))) if per else []
    if not tasks:
        return {}
    n = min(len(per[c][t]) for c in per for t in tasks)
    return {(c,): (tasks, np.array([[np.mean(v) for v in list(per[c][t].values())[:n]] for t in tasks]).T) for c in per}


def write_settings(out, shifts, episodes, pushes=None):
    """robustness.json: the shifts, episodes, start seeds, push rate and paired pushes ({sizes, windows,
    per_episode}), versions and commit; a re-run into the same OUT with other settings is refused (its rows
    would not be comparable). A setting the file lacks (an evaluation made before it existed) is added, with
    the versions and commit that add it under 'added'."""
    from gsa_jax.running.checkpoint import write_atomic

    settings = {"shifts": [list(s) for s in shifts], "episodes": episodes, "start_seeds": [START_SEED, START_SEED + episodes],
                "push_rate": PUSH_RATE}
    if pushes:
        settings["paired_pushes"] = {k: list(v) if isinstance(v, tuple) else v for k, v in pushes.items()}
    path = os.path.join(out, "robustness.json")
    if not os.path.exists(path):
        return write_atomic(path, json.dumps({**settings, **run_metadata()}, indent=1))
    with open(path) as f:
        old = json.load(f)
    held = {k: old[k] for k in settings if k in old}
    if any(held[k] != settings[k] for k in held):
        raise RobustnessError(f"{out} holds an evaluation with other settings ({held}); use another --out")
    new = [k for k in settings if k not in old]
    if new:
        added = {**old.get("added", {}), **{k: run_metadata() for k in new}}
        write_atomic(path, json.dumps({**old, **{k: settings[k] for k in new}, "added": added}, indent=1))


def analyse(rows, sens, out, reps=stats.REPS, log=print, events=(), nominal=(), windows=()):
    """aggregate.csv, correlation.csv, robustness.png, profile.png from the tidy rows; with the paired
    pushes' events and nominal rows also paired_pushes.csv, pushes.png and fair.csv."""
    agg = aggregate(rows, reps)
    write_csv(os.path.join(out, "aggregate.csv"), agg)
    corr = correlations(sens, rows)
    if corr:
        write_csv(os.path.join(out, "correlation.csv"), corr)
    plot_robustness(agg, os.path.join(out, "robustness.png"))
    scores = profile_scores(rows, {e: envs.action_size(e) for e in {r["env"] for r in rows}})
    if scores:
        plot_profiles(scores, os.path.join(out, "profile.png"), reps,
                      xlabel="tau: a run's mean retained fraction over the shifts (1 = its nominal score, 0 = random)")
    for c in corr:
        log(f"sensitivity vs retained fraction, {c['env']}: Spearman rho {c['spearman_rho']} (p {c['p_value']}; "
            f"given nominal score {c['partial_rho_given_nominal']}, p {c['partial_p_value']}; {c['controllers']} controllers)")
    if events:
        analyse_pairs(rows, out, reps, events, nominal, windows, log)
    return agg, corr


def analyse_pairs(rows, out, reps, events, nominal, windows, log):
    """paired_pushes.csv (and paired_pushes_early.csv: pushes before step EARLY_PUSHES only, where the counted
    pushes of controllers that fall early and of those that do not come from the same part of the episode),
    pushes.png, fair.csv (gsa_jax.analysis.paired, .fairness), and how far the paired pushes' control
    episodes' scores are from the nominal scores of the shifts' evaluation."""
    from gsa_jax.analysis.fairness import fair_rows
    from gsa_jax.analysis.paired import aggregate_pushes, plot_pushes

    pushes = aggregate_pushes(events, windows, reps)
    write_csv(os.path.join(out, "paired_pushes.csv"), pushes)
    early = [r for r in events if int(r["time"]) < EARLY_PUSHES]  # the same pushes where every controller still stands
    write_csv(os.path.join(out, "paired_pushes_early.csv"), aggregate_pushes(early, windows, reps))
    plot_pushes(pushes, os.path.join(out, "pushes.png"))
    write_csv(os.path.join(out, "fair.csv"), fair_rows(rows, nominal, reps))
    held = {controller_key(r): float(r["nominal_score"]) for r in rows if r["shift"] == "nominal"}
    diffs = [abs(float(r["nominal_score"]) - held[controller_key(r)]) for r in nominal if controller_key(r) in held]
    if diffs:
        log(f"paired pushes' control episodes vs the shifts' nominal scores: largest difference {max(diffs):.3g} "
            f"over {len(diffs)} controllers")
