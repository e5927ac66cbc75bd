"""Figures and tables of sweeps: `python -m gsa_jax.plot DIR [DIR ...] [--out OUT]` (a single run's learning
curve: gsa_jax.curve).

Merges every tidy metrics.csv under the directories (one per worker process, host, or separately run
sweep: a task's sweep may run on another day or machine; sweeps that hold the same group with other
steps, hyperparameters or settings are refused with the difference). Statistics with rliable
(gsa_jax/stats.py): a run's final score is the mean deterministic return of its last 3 scheduled
evaluations (the training return over the last 10% of iterations for sweeps without evaluations); a
failed evaluation episode (non-finite physics) counts up to its last finite step and is counted in
eval_failures. Writes to OUT
(default: the first DIR):
  figure.png               per task, IQM learning curves of the deterministic controllers (95% bootstrap bands)
  figure_training.png      the same for the training return (the stochastic policy)
  return_vs_k.png          final score IQM (95% CI) against K, flat PPO as a band
  performance_profile.png  fraction of runs above each normalized score, per configuration over tasks
  final_returns.csv        per cell: mean (t CI), IQM (bootstrap CI), P(better than flat PPO) (CI), training return,
                           learning speed (curve_*: IQM of each run's mean over all its evaluations), and in
                           sweeps that list value_targets P(Retrace better than GAE) (CI)
  aggregate.csv            per configuration over tasks: IQM of normalized scores (0 = random policy, 1 = flat
                           PPO's final IQM on that task) and P(better than flat PPO), with CIs
  sufficient_k.csv         per task (and sub-policy class / swept setting): the smallest K whose P(better than
                           flat PPO) interval reaches 0.5 ("on par or better"), or none; marked in return_vs_k.png
Runs that stopped at a NaN/inf (sweep.json 'failed_runs') are left out of every statistic and listed apart
(failed_runs), as are runs with no return at one of their last 3 scheduled evaluations (unscored_runs:
only in tables written before failed evaluation episodes were counted).
"""

import argparse
import csv
import glob
import gzip
import io
import json
import math
import os
import sys
from collections import defaultdict

import numpy as np

from gsa_jax import stats
from gsa_jax.metrics import TIDY_METRICS
from gsa_jax.runinfo import describe_changes

_ID_COLS = ("env", "policy", "K", "seed", "run")
_METRIC_COLS = set(TIDY_METRICS)
_SERIES = ("env_steps", "episode_return", "eval_return", "eval_failures")


class PlotError(ValueError):
    pass


def read_tidy(path, series):
    """Add one tidy metrics.csv to series {cell: {seed: {column: [(iteration, value)]}}}; False if not a sweep's."""
    with (gzip.open(path, "rt", newline="") if path.endswith(".gz") else open(path, newline="")) as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or not set(_ID_COLS) <= set(reader.fieldnames):
            return False  # a single run's metrics.csv (train.py) or a foreign file
        extra = [c for c in reader.fieldnames if c not in _ID_COLS and c not in _METRIC_COLS]
        for r in reader:
            cell = (r["env"], r["policy"], int(r["K"])) + tuple((c, r[c]) for c in extra)
            run = series[cell][int(r["seed"])]
            for c in _SERIES:
                v = r.get(c, "")
                run[c].append((int(r["iteration"]), float(v) if v != "" else math.nan))
    return True


def load_sweep(sweep_dir):
    """All tidy rows under sweep_dir (metrics*.csv, or gzipped as experiments/ keep them) ->
    {cell: {seed: {env_steps, episode_return, eval_return, eval_failures: [T]}}}, cell = (env, policy, K,
    (column, value)...). eval_failures is NaN throughout in tables written before it was recorded."""
    plain = glob.glob(os.path.join(sweep_dir, "**", "metrics*.csv"), recursive=True)
    zipped = glob.glob(os.path.join(sweep_dir, "**", "metrics*.csv.gz"), recursive=True)
    paths = sorted(plain + [p for p in zipped if p[:-3] not in plain])
    if not paths:
        raise FileNotFoundError(f"no metrics.csv under {sweep_dir!r} (is it a sweep directory?)")
    series = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    if not any([read_tidy(p, series) for p in paths]):
        raise FileNotFoundError(f"no sweep metrics.csv under {sweep_dir!r}")
    return {cell: {seed: {c: np.array([v for _, v in sorted(pts)]) for c, pts in cols.items()}
                   for seed, cols in seeds.items()} for cell, seeds in series.items()}


def sweep_metas(sweep_dir):
    """The contents of every sweep.json under sweep_dir (one per sweep; merged results may hold several)."""
    out = []
    for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "sweep.json"), recursive=True)):
        with open(path) as f:
            out.append(json.load(f))
    return out


def group_settings(sweep_dir):
    """{(env, policy, critic): what makes its runs comparable (steps, hyperparameters, static config)} of a
    sweep; a sweep listing no value_targets trained with its [config] critic (default GAE)."""
    out = {}
    for meta in sweep_metas(sweep_dir):
        spec = meta.get("spec", {})
        config = spec.get("config") or {}
        for critic in spec.get("value_targets") or [config.get("value_target", "gae")]:
            # retrace_iterations does not change a GAE run
            kept = {k: v for k, v in config.items() if k != "value_target" and (critic != "gae" or k != "retrace_iterations")}
            for env_name in spec.get("envs", []):
                for policy in spec.get("policies", []):
                    out[(env_name, policy, critic)] = {"steps": spec.get("steps"), "hparams": spec.get("hparams"), "config": kept}
    return out


def lists_critics(cells):
    """Whether any of the cells carries a critic column (its sweep listed value_targets)."""
    return any(c == "value_target" for cell in cells for c, _ in cell[3:])


def with_critic(cell):
    """A cell with ("value_target", "gae") among its settings when it has no critic column (after the
    sub-policy class, where sweeps write it): sweeps that list no value_targets trained with GAE."""
    if any(c == "value_target" for c, _ in cell[3:]):
        return cell
    i = 4 if len(cell) > 3 and cell[3][0] == "subpolicy" else 3
    return cell[:i] + (("value_target", "gae"),) + cell[i:]


def load_sweeps(dirs):
    """load_sweep of every directory, merged; PlotError naming the difference when two hold the same
    group with other settings, or the same run twice. When one sweep lists critics (value_targets), the
    cells of those that do not get the GAE critic's column, so the two critics' cells meet."""
    seen = {}
    for d in dirs:
        for group, settings in group_settings(d).items():
            if group in seen and seen[group][1] != settings:
                diff = describe_changes(seen[group][1], settings)
                raise PlotError(f"{seen[group][0]} and {d} both hold {group[0]}/{group[1]} runs ({group[2]} critic), "
                                f"with different settings ({diff}); plot them apart")
            seen.setdefault(group, (d, settings))
    loaded = [(d, load_sweep(d)) for d in dirs]
    if lists_critics(cell for _, cells in loaded for cell in cells):
        loaded = [(d, {with_critic(cell): seeds for cell, seeds in cells.items()}) for d, cells in loaded]
    data = {}
    for d, cells in loaded:
        for cell, seeds in cells.items():
            twice = set(seeds) & set(data.get(cell, {}))
            if twice:
                raise PlotError(f"{d}: seed {min(twice)} of {cell[0]}/{cell[1]} K={cell[2]} is already in another directory")
            data.setdefault(cell, {}).update(seeds)
    return data


def load_failed(sweep_dir):
    """Runs that stopped at a NaN/inf: sweep.json's 'failed_runs', or the workers' failed_runs.json."""
    failed = [f for meta in sweep_metas(sweep_dir) for f in meta.get("failed_runs", [])]
    if not failed:  # a sweep still running or stopped: the workers' own lists
        for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "failed_runs.json"), recursive=True)):
            with open(path) as f:
                failed.extend(json.load(f))
    return failed


def failed_cell(f):
    """The cell (env, policy, K, (column, value)...) of a failed run, as load_sweep keys them."""
    extras = [c for c in f if c not in ("run", "env", "policy", "K", "seed", "failed_at")]
    return (f["env"], f["policy"], int(f["K"])) + tuple(
        (f"hparam_{c}" if c in _METRIC_COLS else c, str(f[c])) for c in extras)


def drop_failed(data, failed):
    """(data without the failed runs, {cell: [(seed, failed_at)]}): failed runs are reported apart,
    never averaged into a cell (their series end early; a run failing at once has none)."""
    dropped = defaultdict(list)
    critics = lists_critics(data)
    for f in failed:
        cell = with_critic(failed_cell(f)) if critics else failed_cell(f)
        if cell in data:
            data[cell].pop(int(f["seed"]), None)
        dropped[cell].append((int(f["seed"]), int(f["failed_at"])))
    return {c: s for c, s in data.items() if s}, dict(dropped)


def smooth(y, window):
    """Trailing mean over `window` iterations, ignoring NaN (iterations where no episode ended)."""
    if window <= 1:
        return y
    ok = np.isfinite(y)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, y, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(1, len(y) + 1)
    lo = np.maximum(0, idx - window)
    cnt = n[idx] - n[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, (c[idx] - c[lo]) / np.maximum(cnt, 1), np.nan)


def cell_label(cell, action_dims):
    env, policy, k = cell[:3]
    extra = "".join(f", {v}" if c == "subpolicy" else f", {c}={v}" for c, v in cell[3:] if v != "")
    if policy == "mlp":
        return "flat PPO (MLP 64x64)" + extra
    d_a = action_dims.get(env)
    mult = f" ({k / d_a:.3g} d_a)" if d_a else ""
    return f"K={k}{mult}" + extra


def cell_order(cell):
    return cell[0], cell[1] != "mlp", cell[2], cell[3:]


def cell_schedule(seeds):
    """[T] bool: the iterations a cell's runs were evaluated at. A group evaluates all its runs at once,
    so an evaluation that left one run without a return is still scheduled for that run."""
    mask = np.zeros(max(len(s["eval_return"]) for s in seeds.values()), bool)
    for s in seeds.values():
        for column in ("eval_return", "eval_failures"):
            mask[: len(s[column])] |= np.isfinite(s[column])
    return mask


def unscored_runs(data):
    """{cell: [(seed, [iterations])]}: runs whose final score is NaN because one of their last scheduled
    evaluations has no return (tables written before failed evaluation episodes were counted)."""
    out = {}
    for cell, seeds in data.items():
        sched = cell_schedule(seeds)
        got = [(seed, stats.unscored_evaluations(s["eval_return"], sched)) for seed, s in sorted(seeds.items())]
        if any(its for _, its in got):
            out[cell] = [(seed, its) for seed, its in got if its]
    return out


def eval_failures(seeds):
    """Failed evaluation episodes over a cell's runs and evaluations (gsa_jax.episodes); '' (unknown) for
    tables written before they were counted."""
    if not any(np.isfinite(s["eval_failures"]).any() for s in seeds.values()):
        return ""
    return int(sum(np.nansum(s["eval_failures"]) for s in seeds.values()))


def final_scores(data):
    """{cell: (scores [n], kind)}: each run's final score (stats.final_score over the cell's schedule),
    seeds in order, without the runs unscored_runs lists; kind is 'deterministic' when every run has
    evaluations, else 'training'."""
    out = {}
    for cell, seeds in data.items():
        sched = cell_schedule(seeds)
        got = [stats.final_score(s["eval_return"], s["episode_return"], sched) for _, s in sorted(seeds.items())]
        kind = "deterministic" if all(k == "deterministic" for _, k in got) else "training"
        if kind == "training":
            got = [stats.final_score([], s["episode_return"]) for _, s in sorted(seeds.items())]
        scores = np.array([v for v, _ in got])
        out[cell] = (scores[np.isfinite(scores)], kind)
    return out


def flat_cell(cell, cells):
    """The flat PPO cell a mixture cell is compared with: same env and swept settings (sub-policy aside)."""
    rest = tuple((c, v) for c, v in cell[3:] if c != "subpolicy")
    flats = [c for c in cells if c[0] == cell[0] and c[1] == "mlp"]
    same = [c for c in flats if tuple((k, v) for k, v in c[3:] if k != "subpolicy") == rest]
    return (same or (flats if len(flats) == 1 else [None]))[0]


def cell_row(cell, scores, kind, data, action_dims, versus, reps=stats.REPS):
    """One row of final_returns.csv (statistics of a cell's final scores)."""
    env, policy, k = cell[:3]
    n = len(scores)
    mean, half = stats.mean_ci(scores) if n else (math.nan, math.nan)
    iqm = stats.iqm_ci({"c": scores[:, None]}, reps=reps)["c"] if n else (math.nan,) * 3
    train = np.array([stats.final_score([], s["episode_return"])[0] for s in data[cell].values()])
    t_mean, t_half = stats.mean_ci(train[np.isfinite(train)]) if np.isfinite(train).any() else (math.nan, math.nan)
    area = np.array([stats.curve_score(s["eval_return"]) for s in data[cell].values()])
    area = area[np.isfinite(area)]
    auc = stats.iqm_ci({"c": area[:, None]}, reps=reps)["c"] if len(area) else (math.nan,) * 3
    p = versus or (math.nan,) * 3
    r = lambda x: "" if x is None or not np.isfinite(x) else round(float(x), 3)  # noqa: E731
    return {"env": env, "policy": policy, "K": k if policy == "mixture" else "",
            "K_over_action_dim": round(k / action_dims[env], 3) if policy == "mixture" and env in action_dims else "",
            **dict(cell[3:]), "seeds": n, "score": kind, "final_return_mean": r(mean), "ci95_halfwidth": r(half),
            "iqm": r(iqm[0]), "iqm_ci_low": r(iqm[1]), "iqm_ci_high": r(iqm[2]),
            "p_better_than_flat_ppo": r(p[0]), "p_ci_low": r(p[1]), "p_ci_high": r(p[2]),
            "training_return_mean": r(t_mean), "training_ci95_halfwidth": r(t_half),
            "curve_iqm": r(auc[0]), "curve_ci_low": r(auc[1]), "curve_ci_high": r(auc[2]),
            "env_steps": int(next(iter(data[cell].values()))["env_steps"][-1])}


def critic_comparisons(scores, reps=stats.REPS):
    """{retrace cell: P(better than the same cell with GAE's critic) with its CI} for sweeps that list
    value_targets; {} otherwise."""
    pairs = {}
    for cell, (sc, _) in scores.items():
        if ("value_target", "retrace") in cell[3:]:
            gae = cell[:3] + tuple((c, "gae" if c == "value_target" else v) for c, v in cell[3:])
            if gae in scores and len(sc) and len(scores[gae][0]):
                pairs[cell] = (sc[:, None], scores[gae][0][:, None])
    return stats.improvement_probability(pairs, reps=reps) if pairs else {}


def final_table(data, action_dims, failed=None, reps=stats.REPS):
    """final_returns.csv rows: per cell, statistics of its final scores and P(better than flat PPO)."""
    failed = failed or {}
    scores = final_scores(data)
    pairs = {c: (scores[c][0][:, None], scores[f][0][:, None]) for c in data if c[1] == "mixture"
             for f in [flat_cell(c, data)] if f is not None and len(scores[c][0]) and len(scores[f][0])}
    versus = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    critics = critic_comparisons(scores, reps)
    unscored = unscored_runs(data)
    rows = []
    for cell in sorted(set(failed) - set(data), key=cell_order):  # every seed failed
        rows.append({"env": cell[0], "policy": cell[1], "K": cell[2] if cell[1] == "mixture" else "", **dict(cell[3:]),
                     "seeds": 0, "failed_runs": " ".join(f"{s}@{it}" for s, it in sorted(failed[cell]))})
    for cell in sorted(data, key=cell_order):
        row = cell_row(cell, scores[cell][0], scores[cell][1], data, action_dims, versus.get(cell), reps)
        if critics:
            p = critics.get(cell, (math.nan,) * 3)
            row.update({k: "" if not np.isfinite(v) else round(float(v), 3)
                        for k, v in zip(("p_better_than_gae", "p_gae_ci_low", "p_gae_ci_high"), p)})
        rows.append(dict(row, failed_runs=" ".join(f"{s}@{it}" for s, it in sorted(failed.get(cell, []))),
                         eval_failures=eval_failures(data[cell]),
                         unscored_runs=" ".join(f"{s}@{'+'.join(map(str, its))}" for s, its in unscored.get(cell, []))))
    return rows


def spec_multipliers(dirs):
    """{env: sorted cluster multipliers} of the sweeps that set K as multiples of the action dimension
    (cluster_multipliers), read from their sweep.json."""
    out = defaultdict(set)
    for spec in (meta.get("spec", {}) for d in dirs for meta in sweep_metas(d)):
        for env_name in spec.get("envs", []) if spec.get("cluster_multipliers") else []:
            out[env_name].update(spec["cluster_multipliers"])
    return {e: sorted(ms) for e, ms in out.items()}


def config_keys(cell, action_dims, multipliers):
    """The configurations across tasks a cell belongs to: flat PPO, or "K = m d_a" for every multiplier m
    of its sweep that gives its K (K = ceil(m d_a), as Figure 1 sets K: on a task with one action, K = 1
    is both 0.5 d_a and 1 d_a), or K / d_a when K was set directly; with the swept settings."""
    from gsa_jax.spec import cluster_count  # here, not at the top: reading results does not import jax

    env, policy, k = cell[:3]
    if policy == "mlp":
        return [("flat PPO",) + tuple(cell[3:])]
    if env not in action_dims:
        return [(f"K = {k}",) + tuple(cell[3:])]
    ms = [m for m in multipliers.get(env, []) if cluster_count(m, action_dims[env]) == k]
    labels = [f"K = {m:g} d_a" for m in ms] or [f"K = {k / action_dims[env]:.3g} d_a"]
    return [(label,) + tuple(cell[3:]) for label in labels]


def config_order(key):
    """Sort key of a configuration: flat PPO first, then by K (or K / d_a), then the settings."""
    words = key[0].split()
    return (key[0] != "flat PPO", float(words[2]) if len(words) > 2 else 0.0, str(key[1:]))


def normalized_scores(data, action_dims, random_returns, multipliers=None):
    """{config: [runs, tasks] normalized final scores} (0 = random policy, 1 = flat PPO's final IQM on the
    task); tasks without a flat PPO cell or a random-policy return are left out; runs cut to the fewest.
    multipliers: spec_multipliers of the sweeps (configs named by them, see config_keys)."""
    scores = final_scores(data)
    by_config = defaultdict(dict)
    for cell in data:
        flat = flat_cell(cell, data) if cell[1] == "mixture" else cell
        if flat is None or cell[0] not in random_returns or not len(scores[cell][0]) or not len(scores[flat][0]):
            continue
        ref = stats.iqm(scores[flat][0][:, None])  # the point only: no bootstrap per mixture cell
        for key in config_keys(cell, action_dims, multipliers or {}):
            by_config[key][cell[0]] = stats.normalize(scores[cell][0], random_returns[cell[0]], ref)
    out = {}
    for config, tasks in sorted(by_config.items(), key=lambda kv: config_order(kv[0])):
        n = min(len(v) for v in tasks.values())
        out[config] = (sorted(tasks), np.stack([tasks[t][:n] for t in sorted(tasks)], axis=1))
    return out


def aggregate_table(normalized, reps=stats.REPS):
    """aggregate.csv rows: per configuration, IQM of normalized scores over tasks and P(better than flat PPO)."""
    if not normalized:
        return []
    iqm = stats.iqm_ci({str(k): m for k, (_, m) in normalized.items()}, reps=reps)
    flats = {tuple(c for c in k[1:] if c[0] != "subpolicy"): k for k in normalized if k[0] == "flat PPO"}
    pairs = {}
    for k, (tasks, m) in normalized.items():
        f = flats.get(tuple(c for c in k[1:] if c[0] != "subpolicy"))
        if k[0] != "flat PPO" and f is not None and normalized[f][0] == tasks:
            n = min(len(m), len(normalized[f][1]))
            pairs[str(k)] = (m[:n], normalized[f][1][:n])
    better = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    rows = []
    for k, (tasks, m) in normalized.items():
        p = better.get(str(k), ("",) * 3)
        rows.append({"config": k[0], **dict(k[1:]), "tasks": " ".join(tasks), "runs_per_task": m.shape[0],
                     "normalized_iqm": round(iqm[str(k)][0], 3), "iqm_ci_low": round(iqm[str(k)][1], 3),
                     "iqm_ci_high": round(iqm[str(k)][2], 3), "p_better_than_flat_ppo": p[0] if p[0] == "" else round(p[0], 3),
                     "p_ci_low": p[1] if p[1] == "" else round(p[1], 3), "p_ci_high": p[2] if p[2] == "" else round(p[2], 3)})
    return rows


def cell_curves(data, column, window, reps=stats.CURVE_REPS):
    """{cell: (env_steps [P], IQM [P], low [P], high [P])}: IQM over seeds with bootstrap bands of the
    training return (smoothed over `window` iterations) or of the evaluations (where evaluated)."""
    curves, steps = {}, {}
    for cell, seeds in data.items():
        n = min(len(s[column]) for s in seeds.values())
        m = np.stack([s[column][:n] for s in seeds.values()])
        if column == "episode_return":
            m = np.stack([smooth(y, window) for y in m])
        if column == "eval_return":
            keep = np.where(np.all(np.isfinite(m), axis=0))[0]
            m = m[:, keep]
        else:
            keep = np.arange(n)
        curves[cell], steps[cell] = m, next(iter(seeds.values()))["env_steps"][:n][keep]
    est = stats.iqm_curves({c: m for c, m in curves.items() if m.size}, reps=reps)
    return {c: (steps[c][idx], iqm, lo, hi) for c, (idx, iqm, lo, hi) in est.items()}


def plot_curves(data, action_dims, failed, column, path, title, reps=stats.CURVE_REPS):
    """Per task, the IQM learning curve of every cell with its 95% bootstrap band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    window = max(1, min(len(s["episode_return"]) for seeds in data.values() for s in seeds.values()) // 50)
    curves = cell_curves(data, column, window, reps)
    env_names = list(dict.fromkeys(c[0] for c in sorted(data)))
    ncols = min(3, len(env_names))
    fig, axes = plt.subplots(math.ceil(len(env_names) / ncols), ncols, figsize=(max(7.0, 5.2 * ncols), 3.9 * math.ceil(len(env_names) / ncols) + 0.3), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        cells = sorted((c for c in data if c[0] == env_name), key=cell_order)
        for i, cell in enumerate(c for c in cells if c in curves):
            xs, iqm, lo, hi = curves[cell]
            style = dict(color="black", lw=2.0) if cell[1] == "mlp" else dict(color=plt.cm.viridis(i / max(1, len(cells) - 1) * 0.9), lw=1.6)
            n_failed = f", {len(failed[cell])} failed (NaN/inf), not shown" if cell in failed else ""
            ax.plot(xs, iqm, marker="o" if column == "eval_return" else None, ms=3,
                    label=f"{cell_label(cell, action_dims)} (n={len(data[cell])}{n_failed})", **style)
            ax.fill_between(xs, lo, hi, alpha=0.18, color=style["color"], lw=0)
        ax.set(title=env_name, xlabel="environment steps", ylabel="episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(env_names):]:
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def setting_columns(data):
    """The columns that set cells apart beyond (env, policy, K): sub-policy class, critic, swept hyperparameters."""
    return list(dict.fromkeys(c for cell in data for c, _ in cell[3:]))


def k_curves(rows, env_name, settings):
    """{((column, value) of `settings`...): the task's mixture rows of final_returns.csv sorted by K}: one
    return-vs-K curve per sub-policy class, critic and other swept setting."""
    curves = defaultdict(list)
    for r in rows:
        if r["env"] == env_name and r["policy"] == "mixture" and r["seeds"]:
            curves[tuple((c, r.get(c, "")) for c in settings)].append(r)
    return {k: sorted(pts, key=lambda r: r["K"]) for k, pts in curves.items()}


def sufficient_k_table(rows, settings=()):
    """sufficient_k.csv rows: per task and setting, the smallest K whose P(better than flat PPO) 95% interval
    reaches 0.5 (its upper end >= 0.5: not shown worse than flat PPO), with that cell's IQM and P; K ''
    where no K does. The product's answer to "how many linear controllers does this task need?"."""
    out = []
    for env_name in dict.fromkeys(r["env"] for r in rows):
        for extra, pts in k_curves(rows, env_name, settings).items():
            ok = [r for r in pts if r.get("p_ci_high") != "" and r["p_ci_high"] >= 0.5]
            r = ok[0] if ok else {}
            out.append({"env": env_name, **dict(extra), "smallest_sufficient_K": r.get("K", ""),
                        "K_over_action_dim": r.get("K_over_action_dim", ""), "iqm": r.get("iqm", ""),
                        "p_better_than_flat_ppo": r.get("p_better_than_flat_ppo", ""),
                        "p_ci_low": r.get("p_ci_low", ""), "p_ci_high": r.get("p_ci_high", ""),
                        "ks_tried": " ".join(str(q["K"]) for q in pts)})
    return out


def sufficient_k_lines(table):
    """One printed line per row of sufficient_k_table."""
    lines = []
    for r in table:
        extra = "".join(f" {c}={v}" for c, v in r.items() if c not in SUFFICIENT_COLS and v != "")
        if r["smallest_sufficient_K"] == "":
            lines.append(f"  {r['env']}{extra}: no K of {r['ks_tried']} reaches P(> flat PPO) 0.5 within its 95% CI")
        else:
            lines.append(f"  {r['env']}{extra}: smallest sufficient K = {r['smallest_sufficient_K']} "
                         f"(IQM {r['iqm']}, P(> flat PPO) {r['p_better_than_flat_ppo']} [{r['p_ci_low']}, {r['p_ci_high']}])")
    return lines


SUFFICIENT_COLS = ("env", "smallest_sufficient_K", "K_over_action_dim", "iqm", "p_better_than_flat_ppo", "p_ci_low",
                   "p_ci_high", "ks_tried")


def mark_sufficient_k(ax, table, env_name):
    """A dotted vertical line at each of the task's smallest sufficient K (sufficient_k_table)."""
    for r in table:
        if r["env"] == env_name and r["smallest_sufficient_K"] != "":
            ax.axvline(r["smallest_sufficient_K"], color="tab:green", ls=":", lw=1.5,
                       label=f"smallest K on par with flat PPO: {r['smallest_sufficient_K']}")


def plot_return_vs_k(rows, path, settings=()):
    """Final score IQM (95% bootstrap CI over seeds) against K per task; flat PPO as a horizontal band. One
    curve per value of the `settings` columns (the cells' sub-policy class, critic, swept hyperparameters)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in rows))
    table = sufficient_k_table(rows, settings)
    fig, axes = plt.subplots(1, len(env_names), figsize=(max(6.5, 4.6 * len(env_names)), 4.0), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        mark_sufficient_k(ax, table, env_name)
        curves = k_curves(rows, env_name, settings)
        all_ks = sorted({r["K"] for pts in curves.values() for r in pts})
        for extra, pts in curves.items():
            iqm = np.array([r["iqm"] for r in pts], float)
            err = np.array([[r["iqm"] - r["iqm_ci_low"], r["iqm_ci_high"] - r["iqm"]] for r in pts], float).T
            sub = dict(extra).get("subpolicy") or "linear"
            rest = "".join(f", {c}={v}" for c, v in extra if c != "subpolicy")
            ax.errorbar([r["K"] for r in pts], iqm, yerr=err, fmt="o-", capsize=3, label=f"mixture of K {sub} controllers{rest}")
        if all_ks:
            ax.set_xscale("log", base=2)
            ax.set_xticks(all_ks, [f"{int(k)}" for k in all_ks])
        for r in rows:
            if r["env"] == env_name and r["policy"] == "mlp" and r["seeds"]:
                ax.axhspan(r["iqm_ci_low"], r["iqm_ci_high"], color="k", alpha=0.15, lw=0)
                ax.axhline(r["iqm"], color="k", lw=1.5, label="flat PPO (MLP 64x64)")
        ax.set(title=env_name, xlabel="K (number of clusters / sub-policies)", ylabel=f"final score ({rows[0].get('score', '')})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("How many (and how complex) controllers does the task need?\n(final score: IQM, 95% bootstrap CI)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


PROFILE_XLABEL = "normalized score tau (0 = random policy, 1 = flat PPO's final IQM)"


def plot_profiles(normalized, path, reps=stats.REPS, xlabel=PROFILE_XLABEL):
    """Performance profiles: the fraction of runs (averaged over tasks) whose normalized score exceeds tau.
    normalized: {(configuration, (column, value)...): (tasks, scores [runs, tasks])}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = max(1.5, max(float(np.max(m)) for _, m in normalized.values()))
    taus = np.linspace(0.0, top, 60)
    prof = stats.performance_profiles({str(k): m for k, (_, m) in normalized.items()}, taus, reps)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, (k, (tasks, _)) in enumerate(normalized.items()):
        frac, lo, hi = prof[str(k)]
        color = "black" if k[0] == "flat PPO" else plt.cm.viridis(i / max(1, len(normalized) - 1) * 0.9)
        ax.plot(taus, frac, color=color, label=" ".join([k[0]] + [f"{c}={v}" for c, v in k[1:] if v != ""]) + f" ({len(tasks)} tasks)")
        ax.fill_between(taus, lo, hi, color=color, alpha=0.15, lw=0)
    ax.set(xlabel=xlabel, ylabel="fraction of runs with score > tau")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def random_returns_of(dirs, env_names, out_dir, log=print):
    """{env: random-policy return}: from the sweeps' random_returns.json, measured (and saved in out_dir) where missing."""
    found = {}
    for d in dirs:
        for path in glob.glob(os.path.join(d, "**", "random_returns.json"), recursive=True):
            with open(path) as f:
                found.update(json.load(f))
    missing = [e for e in env_names if e not in found]
    if missing:
        from gsa_jax.scoring import random_policy_return

        for env_name in missing:
            log(f"measuring the random-policy return of {env_name} (for normalized scores)")
            found[env_name] = random_policy_return(env_name)
        with open(os.path.join(out_dir, "random_returns.json"), "w") as f:
            json.dump({e: found[e] for e in env_names}, f, indent=1)
    return {e: found[e] for e in env_names}


def write_csv(path, rows, columns=None):
    """rows (dicts) as a CSV file, written atomically; columns: their order (default: as first seen)."""
    from gsa_jax.checkpoint import write_atomic

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns or list(dict.fromkeys(k for r in rows for k in r)))
    w.writeheader()
    w.writerows(rows)
    write_atomic(path, buf.getvalue())


def plot_sweep(sweep_dirs, out_dir=None, action_dims=None, random_returns=None, log=print, reps=stats.REPS,
               curve_reps=stats.CURVE_REPS):
    """Every figure and table of the merged sweeps into out_dir (default: the first directory); reps /
    curve_reps: bootstrap resamples of the tables' intervals / of each learning-curve point's band.
    Returns (figure.png path, final_returns.csv path, final_returns rows)."""
    dirs = [sweep_dirs] if isinstance(sweep_dirs, str) else list(sweep_dirs)
    out_dir = out_dir or dirs[0]
    os.makedirs(out_dir, exist_ok=True)
    failed_runs = [f for d in dirs for f in load_failed(d)]
    data, failed = drop_failed(load_sweeps(dirs), failed_runs)
    if action_dims is None:
        import envs

        action_dims = {e: envs.action_size(e) for e in {c[0] for c in data}}
    evaluated = any(np.isfinite(s["eval_return"]).any() for seeds in data.values() for s in seeds.values())
    png = os.path.join(out_dir, "figure.png")
    plot_curves(data, action_dims, failed, "eval_return" if evaluated else "episode_return", png,
                "Flat PPO vs mixtures of K linear controllers: " + ("deterministic controllers" if evaluated else "training return")
                + "\n(IQM over seeds, 95% bootstrap band)", curve_reps)
    plot_curves(data, action_dims, failed, "episode_return", os.path.join(out_dir, "figure_training.png"),
                "Training return (stochastic policy)\n(IQM over seeds, 95% bootstrap band)", curve_reps)
    rows = final_table(data, action_dims, failed, reps)
    for line in unscored_lines(rows):
        log(line)
    table = os.path.join(out_dir, "final_returns.csv")
    write_csv(table, rows)
    scored = [r for r in rows if r["seeds"]]
    plot_return_vs_k(scored, os.path.join(out_dir, "return_vs_k.png"), setting_columns(data))
    sufficient = sufficient_k_table(scored, setting_columns(data))
    if sufficient:
        write_csv(os.path.join(out_dir, "sufficient_k.csv"), sufficient)
        log("How many linear controllers does each task need (smallest K on par with flat PPO or better)?")
        for line in sufficient_k_lines(sufficient):
            log(line)
    if random_returns is None:
        random_returns = random_returns_of(dirs, sorted({c[0] for c in data}), out_dir, log)
    normalized = normalized_scores(data, action_dims, random_returns, spec_multipliers(dirs))
    if normalized:
        write_csv(os.path.join(out_dir, "aggregate.csv"), aggregate_table(normalized, reps))
        plot_profiles(normalized, os.path.join(out_dir, "performance_profile.png"), reps)
    return png, table, rows


def unscored_lines(rows):
    """Lines naming the cells with unscored runs (final_returns.csv 'unscored_runs'); [] if none."""
    cells = [r for r in rows if r.get("unscored_runs")]
    if not cells:
        return []
    return [f"{sum(len(r['unscored_runs'].split()) for r in cells)} run(s) have no return at one of their last "
            f"{stats.FINAL_EVALUATIONS} scheduled evaluations (metrics written before failed evaluation episodes were "
            "counted): left out of the statistics, listed as seed@iterations:"] + [
        f"  {r['env']} {r['policy']}{' K=' + str(r['K']) if r['K'] != '' else ''}: {r['unscored_runs']}" for r in cells]


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.plot", description=__doc__.split("\n")[0])
    p.add_argument("sweep_dirs", nargs="+", metavar="DIR", help="sweep directories (merged)")
    p.add_argument("--out", default=None, help="directory for the figures and tables (default: the first DIR)")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples of the tables' intervals (default %(default)s)")
    p.add_argument("--curve-reps", type=int, default=stats.CURVE_REPS,
                   help="bootstrap resamples of each learning-curve point's band (default %(default)s)")
    args = p.parse_args(argv)
    try:
        if min(args.reps, args.curve_reps) < 1:
            raise PlotError(f"--reps and --curve-reps must be >= 1, got {args.reps} and {args.curve_reps}")
        png, table, rows = plot_sweep(args.sweep_dirs, args.out, reps=args.reps, curve_reps=args.curve_reps)
    except (FileNotFoundError, PlotError) as e:
        print(f"gsa_jax.plot: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {png} and {table}")
    for r in rows:
        print("  " + "  ".join(f"{k}={v}" for k, v in r.items() if v != ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
