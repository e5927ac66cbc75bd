"""The statistics tables of a sweep's results (rliable via gsa_jax.analysis.sweeps.stats): final scores per cell,
normalized aggregates, smallest sufficient K, learning-curve bands."""

import math
from collections import defaultdict
from typing import Iterable, Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MIXTURE_COLUMNS, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import Cell, cell_schedule, eval_failures, evaluation_scores, final_scores, unscored_runs


def smooth(y: np.ndarray, window: int) -> np.ndarray:
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


def cell_label(cell: Cell, action_dims: dict) -> str:
    """A cell's name in figures: flat PPO or K (with K / d_a), and its settings."""
    extra = "".join(f", {v}" if c == "subpolicy" else f", {c}={v}" for c, v in cell.settings if v != "")
    if cell.policy == MLP:
        return "flat PPO (MLP 64x64)" + extra
    d_a = action_dims.get(cell.env)
    mult = f" ({cell.k / d_a:.3g} d_a)" if d_a else ""
    return f"K={cell.k}{mult}" + extra


def cell_order(cell: Cell) -> tuple:
    """Sort key of cells: by task, flat PPO first, then by K and settings."""
    return cell.env, cell.policy != MLP, cell.k, cell.settings


def other_settings(cell: Cell) -> tuple:
    """A cell's settings but a mixture's own classes (sub-policy, partition: MIXTURE_COLUMNS): what a mixture cell
    shares with the flat PPO cell it is compared with."""
    return tuple((c, v) for c, v in cell.settings if c not in MIXTURE_COLUMNS)


def flat_cell(cell: Cell, cells: Iterable[Cell]) -> Cell | None:
    """The flat PPO cell a mixture cell is compared with: same env and swept settings (a mixture's own classes
    aside)."""
    flats = [c for c in cells if c.env == cell.env and c.policy == MLP]
    same = [c for c in flats if other_settings(c) == other_settings(cell)]
    return (same or (flats if len(flats) == 1 else [None]))[0]


def rounded(columns: Sequence[str], values: Sequence[float | None]) -> dict:
    """{column: value to 3 decimals ('' where None or not finite)} of a group of columns (sweeps.columns)."""
    return {c: "" if v is None or not np.isfinite(v) else round(float(v), 3) for c, v in zip(columns, values)}


def cell_row(cell: Cell, scores: np.ndarray, kind: str, data: dict, action_dims: dict, versus: tuple | None,
             reps: int = stats.REPS) -> dict:
    """One row of final_returns.csv (statistics of a cell's final scores)."""
    env, policy, k = cell.env, cell.policy, cell.k
    n = len(scores)
    mean, half = stats.mean_ci(scores) if n else (math.nan, math.nan)
    iqm = stats.iqm_ci({"c": scores[:, None]}, reps=reps)["c"] if n else (math.nan,) * 3
    train = np.array([stats.final_score([], s["episode_return"])[0] for s in data[cell].values()])
    t_mean, t_half = stats.mean_ci(train[np.isfinite(train)]) if np.isfinite(train).any() else (math.nan, math.nan)
    area = np.array([stats.curve_score(s["eval_return"]) for s in data[cell].values()])
    area = area[np.isfinite(area)]
    auc = stats.iqm_ci({"c": area[:, None]}, reps=reps)["c"] if len(area) else (math.nan,) * 3
    p = versus or (math.nan,) * 3
    return {"env": env, "policy": policy, "K": k if policy == MIXTURE else "",
            C.K_OVER_ACTION_DIM: round(k / action_dims[env], 3) if policy == MIXTURE and env in action_dims else "",
            **dict(cell.settings), C.SEEDS: n, C.SCORE_KIND: kind, **rounded(C.MEAN_CI, (mean, half)),
            **rounded(C.IQM_CI, iqm), **rounded(C.P_FLAT_CI, p), **rounded(C.TRAINING_CI, (t_mean, t_half)),
            **rounded(C.CURVE_CI, auc), "env_steps": int(next(iter(data[cell].values()))["env_steps"][-1])}


def critic_comparisons(scores: dict, reps: int = stats.REPS) -> dict:
    """{retrace cell: P(better than the same cell with GAE's critic) with its CI} for sweeps that list
    value_targets; {} otherwise."""
    pairs = {}
    for cell, (sc, _) in scores.items():
        if ("value_target", "retrace") in cell.settings:
            gae = cell._replace(settings=tuple((c, "gae" if c == "value_target" else v) for c, v in cell.settings))
            if gae in scores and len(sc) and len(scores[gae][0]):
                pairs[cell] = (sc[:, None], scores[gae][0][:, None])
    return stats.improvement_probability(pairs, reps=reps) if pairs else {}


def final_table(data: dict, action_dims: dict, failed: dict | None = None, reps: int = stats.REPS) -> list:
    """final_returns.csv rows: per cell, statistics of its final scores and P(better than flat PPO)."""
    failed = failed or {}
    scores = final_scores(data)
    pairs = {c: (scores[c][0][:, None], scores[f][0][:, None]) for c in data if c.policy == MIXTURE
             for f in [flat_cell(c, data)] if f is not None and len(scores[c][0]) and len(scores[f][0])}
    versus = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    critics = critic_comparisons(scores, reps)
    unscored = unscored_runs(data)
    rows = []
    for cell in sorted(set(failed) - set(data), key=cell_order):  # every seed failed
        rows.append({"env": cell.env, "policy": cell.policy, "K": cell.k if cell.policy == MIXTURE else "",
                     **dict(cell.settings), C.SEEDS: 0,
                     "failed_runs": " ".join(f"{s}@{it}" for s, it in sorted(failed[cell]))})
    for cell in sorted(data, key=cell_order):
        row = cell_row(cell, scores[cell][0], scores[cell][1], data, action_dims, versus.get(cell), reps)
        if critics:
            row.update(rounded(C.P_GAE_CI, critics.get(cell, (math.nan,) * 3)))
        rows.append(dict(row, failed_runs=" ".join(f"{s}@{it}" for s, it in sorted(failed.get(cell, []))),
                         eval_failures=eval_failures(data[cell]),
                         unscored_runs=" ".join(f"{s}@{'+'.join(map(str, its))}" for s, its in unscored.get(cell, []))))
    return rows


def run_table(data: dict) -> list:
    """per_run_scores.csv rows: per run (cells in table order, seeds in order) its committed controller's score
    (controller_score: the final controller re-run in MuJoCo C from fixed start states, what every verdict uses;
    '' where not scored), score_kind (which score the tables use: controller, deterministic or training), its
    final_score from training-time evaluations (the mean of its last scheduled evaluations, a learning-curve
    statistic; '' for a run unscored_runs lists), its last scheduled evaluation, failed evaluation episodes, its
    training return over the last 10% of iterations and over its last LAST_EPISODES (100) episodes
    (stats.last_episodes_return: how CleanRL's tables score a run)."""
    r = lambda x: "" if not np.isfinite(x) else round(float(x), 3)  # noqa: E731
    rows = []
    for cell in sorted(data, key=cell_order):
        sched = cell_schedule(data[cell])
        kind = final_scores({cell: data[cell]})[cell][1]
        evaluated = evaluation_scores({cell: data[cell]})[cell][1] == "deterministic"
        for seed, s in sorted(data[cell].items()):
            score = stats.final_score(s["eval_return"] if evaluated else [], s["episode_return"], sched)[0]
            last = s["eval_return"][sched[: len(s["eval_return"])]][-1:]
            last_100 = stats.last_episodes_return(s["episode_return"], s["episodes"])
            rows.append({"env": cell.env, "policy": cell.policy, "K": cell.k if cell.policy == MIXTURE else "",
                         **dict(cell.settings), "seed": seed, C.CONTROLLER_SCORE: r(s.get(C.CONTROLLER_SCORE, math.nan)),
                         "score_kind": kind, C.FINAL_SCORE: r(score), "last_eval_return": r(last[0]) if len(last) else "",
                         "eval_failures": eval_failures({seed: s}),
                         "training_return": r(stats.final_score([], s["episode_return"])[0]),
                         C.LAST_EPISODES_RETURN: r(last_100)})
    return rows


def config_keys(cell: Cell, action_dims: dict, multipliers: dict) -> list:
    """The configurations across tasks a cell belongs to: flat PPO, or "K = m d_a" for every multiplier m
    of its sweep that gives its K (K = ceil(m d_a), as Figure 1 sets K: on a task with one action, K = 1
    is both 0.5 d_a and 1 d_a), or K / d_a when K was set directly; with the swept settings."""
    from gsa_jax.running.spec import cluster_count

    env, k = cell.env, cell.k
    if cell.policy == MLP:
        return [("flat PPO",) + cell.settings]
    if env not in action_dims:
        return [(f"K = {k}",) + cell.settings]
    ms = [m for m in multipliers.get(env, []) if cluster_count(m, action_dims[env]) == k]
    labels = [f"K = {m:g} d_a" for m in ms] or [f"K = {k / action_dims[env]:.3g} d_a"]
    return [(label,) + cell.settings for label in labels]


def config_order(key: tuple) -> tuple:
    """Sort key of a configuration: flat PPO first, then by K (or K / d_a), then the settings."""
    words = key[0].split()
    return (key[0] != "flat PPO", float(words[2]) if len(words) > 2 else 0.0, str(key[1:]))


def normalized_scores(data: dict, action_dims: dict, random_returns: dict, multipliers: dict | None = None) -> dict:
    """{config: [runs, tasks] normalized final scores} (0 = random policy, 1 = flat PPO's final IQM on the
    task); tasks without a flat PPO cell or a random-policy return are left out; runs cut to the fewest.
    multipliers: spec_multipliers of the sweeps (configs named by them, see config_keys)."""
    scores = final_scores(data)
    by_config = defaultdict(dict)
    for cell in data:
        flat = flat_cell(cell, data) if cell.policy == MIXTURE else cell
        if flat is None or cell.env not in random_returns or not len(scores[cell][0]) or not len(scores[flat][0]):
            continue
        ref = stats.iqm(scores[flat][0][:, None])  # the point only: no bootstrap per mixture cell
        for key in config_keys(cell, action_dims, multipliers or {}):
            by_config[key][cell.env] = stats.normalize(scores[cell][0], random_returns[cell.env], ref)
    out = {}
    for config, tasks in sorted(by_config.items(), key=lambda kv: config_order(kv[0])):
        n = min(len(v) for v in tasks.values())
        out[config] = (sorted(tasks), np.stack([tasks[t][:n] for t in sorted(tasks)], axis=1))
    return out


def aggregate_table(normalized: dict, reps: int = stats.REPS) -> list:
    """aggregate.csv rows: per configuration, IQM of normalized scores over tasks and P(better than flat PPO)."""
    if not normalized:
        return []
    iqm = stats.iqm_ci({str(k): m for k, (_, m) in normalized.items()}, reps=reps)
    flats = {tuple(c for c in k[1:] if c[0] not in MIXTURE_COLUMNS): k for k in normalized if k[0] == "flat PPO"}
    pairs = {}
    for k, (tasks, m) in normalized.items():
        f = flats.get(tuple(c for c in k[1:] if c[0] not in MIXTURE_COLUMNS))
        if k[0] != "flat PPO" and f is not None and normalized[f][0] == tasks:
            n = min(len(m), len(normalized[f][1]))
            pairs[str(k)] = (m[:n], normalized[f][1][:n])
    better = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    rows = []
    for k, (tasks, m) in normalized.items():
        p = better.get(str(k), (None,) * 3)
        rows.append({"config": k[0], **dict(k[1:]), "tasks": " ".join(tasks), "runs_per_task": m.shape[0],
                     **rounded(C.NORMALIZED_IQM_CI, iqm[str(k)]), **rounded(C.P_FLAT_CI, p)})
    return rows


def cell_curves(data: dict, column: str, window: int, reps: int = stats.CURVE_REPS) -> dict:
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


def k_curves(rows: list, env_name: str, settings: Sequence[str]) -> dict:
    """{((column, value) of `settings`...): the task's mixture rows of final_returns.csv sorted by K}: one
    return-vs-K curve per sub-policy class, critic and other swept setting."""
    curves = defaultdict(list)
    for r in rows:
        if r["env"] == env_name and r["policy"] == MIXTURE and r[C.SEEDS]:
            curves[tuple((c, r.get(c, "")) for c in settings)].append(r)
    return {k: sorted(pts, key=lambda r: r["K"]) for k, pts in curves.items()}
