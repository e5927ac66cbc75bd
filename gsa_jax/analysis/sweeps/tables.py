"""The statistics tables of a sweep's results (rliable via gsa_jax.analysis.sweeps.stats): final scores per cell,
normalized aggregates, smallest sufficient K, learning-curve bands."""

import math
from collections import defaultdict
from typing import Iterable, Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import cell_schedule, eval_failures, evaluation_scores, final_scores, unscored_runs
from gsa_jax.analysis.verdicts import verdict


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


def cell_label(cell: tuple, action_dims: dict) -> str:
    env, policy, k = cell[:3]
    extra = "".join(f", {v}" if c == "subpolicy" else f", {c}={v}" for c, v in cell[3:] if v != "")
    if policy == MLP:
        return "flat PPO (MLP 64x64)" + extra
    d_a = action_dims.get(env)
    mult = f" ({k / d_a:.3g} d_a)" if d_a else ""
    return f"K={k}{mult}" + extra


def cell_order(cell: tuple) -> tuple:
    return cell[0], cell[1] != MLP, cell[2], cell[3:]


def flat_cell(cell: tuple, cells: Iterable[tuple]) -> tuple | None:
    """The flat PPO cell a mixture cell is compared with: same env and swept settings (sub-policy aside)."""
    rest = tuple((c, v) for c, v in cell[3:] if c != "subpolicy")
    flats = [c for c in cells if c[0] == cell[0] and c[1] == MLP]
    same = [c for c in flats if tuple((k, v) for k, v in c[3:] if k != "subpolicy") == rest]
    return (same or (flats if len(flats) == 1 else [None]))[0]


def cell_row(cell: tuple, scores: np.ndarray, kind: str, data: dict, action_dims: dict, versus: tuple | None,
             reps: int = stats.REPS) -> dict:
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
    return {"env": env, "policy": policy, "K": k if policy == MIXTURE else "",
            "K_over_action_dim": round(k / action_dims[env], 3) if policy == MIXTURE and env in action_dims else "",
            **dict(cell[3:]), "seeds": n, "score": kind, "final_return_mean": r(mean), "ci95_halfwidth": r(half),
            "iqm": r(iqm[0]), "iqm_ci_low": r(iqm[1]), "iqm_ci_high": r(iqm[2]),
            "p_better_than_flat_ppo": r(p[0]), "p_ci_low": r(p[1]), "p_ci_high": r(p[2]),
            "training_return_mean": r(t_mean), "training_ci95_halfwidth": r(t_half),
            "curve_iqm": r(auc[0]), "curve_ci_low": r(auc[1]), "curve_ci_high": r(auc[2]),
            "env_steps": int(next(iter(data[cell].values()))["env_steps"][-1])}


def critic_comparisons(scores: dict, reps: int = stats.REPS) -> dict:
    """{retrace cell: P(better than the same cell with GAE's critic) with its CI} for sweeps that list
    value_targets; {} otherwise."""
    pairs = {}
    for cell, (sc, _) in scores.items():
        if ("value_target", "retrace") in cell[3:]:
            gae = cell[:3] + tuple((c, "gae" if c == "value_target" else v) for c, v in cell[3:])
            if gae in scores and len(sc) and len(scores[gae][0]):
                pairs[cell] = (sc[:, None], scores[gae][0][:, None])
    return stats.improvement_probability(pairs, reps=reps) if pairs else {}


def final_table(data: dict, action_dims: dict, failed: dict | None = None, reps: int = stats.REPS) -> list:
    """final_returns.csv rows: per cell, statistics of its final scores and P(better than flat PPO)."""
    failed = failed or {}
    scores = final_scores(data)
    pairs = {c: (scores[c][0][:, None], scores[f][0][:, None]) for c in data if c[1] == MIXTURE
             for f in [flat_cell(c, data)] if f is not None and len(scores[c][0]) and len(scores[f][0])}
    versus = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    critics = critic_comparisons(scores, reps)
    unscored = unscored_runs(data)
    rows = []
    for cell in sorted(set(failed) - set(data), key=cell_order):  # every seed failed
        rows.append({"env": cell[0], "policy": cell[1], "K": cell[2] if cell[1] == MIXTURE else "", **dict(cell[3:]),
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
            rows.append({"env": cell[0], "policy": cell[1], "K": cell[2] if cell[1] == MIXTURE else "", **dict(cell[3:]),
                         "seed": seed, "controller_score": r(s.get("controller_score", math.nan)), "score_kind": kind,
                         "final_score": r(score), "last_eval_return": r(last[0]) if len(last) else "",
                         "eval_failures": eval_failures({seed: s}),
                         "training_return": r(stats.final_score([], s["episode_return"])[0]),
                         f"training_return_last_{stats.LAST_EPISODES}_episodes": r(last_100)})
    return rows


def config_keys(cell: tuple, action_dims: dict, multipliers: dict) -> list:
    """The configurations across tasks a cell belongs to: flat PPO, or "K = m d_a" for every multiplier m
    of its sweep that gives its K (K = ceil(m d_a), as Figure 1 sets K: on a task with one action, K = 1
    is both 0.5 d_a and 1 d_a), or K / d_a when K was set directly; with the swept settings."""
    from gsa_jax.running.spec import cluster_count

    env, policy, k = cell[:3]
    if policy == MLP:
        return [("flat PPO",) + tuple(cell[3:])]
    if env not in action_dims:
        return [(f"K = {k}",) + tuple(cell[3:])]
    ms = [m for m in multipliers.get(env, []) if cluster_count(m, action_dims[env]) == k]
    labels = [f"K = {m:g} d_a" for m in ms] or [f"K = {k / action_dims[env]:.3g} d_a"]
    return [(label,) + tuple(cell[3:]) for label in labels]


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
        flat = flat_cell(cell, data) if cell[1] == MIXTURE else cell
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


def aggregate_table(normalized: dict, reps: int = stats.REPS) -> list:
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
        if r["env"] == env_name and r["policy"] == MIXTURE and r["seeds"]:
            curves[tuple((c, r.get(c, "")) for c in settings)].append(r)
    return {k: sorted(pts, key=lambda r: r["K"]) for k, pts in curves.items()}


def cell_setting(cell: tuple, settings: Sequence[str]) -> tuple:
    """((column, value) of `settings`...) of a cell: which return-vs-K curve it belongs to."""
    extra = dict(cell[3:])
    return tuple((c, extra.get(c, "")) for c in settings)


def grid_evidence(data: dict, scores: dict, cells: list) -> tuple:
    """answering.Evidence of one task's fixed grid: flat PPO's and each K's scores (final_scores: the committed
    controllers' where scored), last-100-episode training returns and flat PPO's learning curves."""
    from gsa_jax.analysis.verdicts.answering import FLAT, Evidence

    values, last100, curves = {}, {}, {}
    for cell in cells:
        key = FLAT if cell[1] == MLP else cell[2]
        seeds = sorted(data[cell])
        values[key] = dict(zip(seeds, (float(v) for v in scores[cell][0])))
        last100[key] = {s: stats.last_episodes_return(data[cell][s]["episode_return"], data[cell][s]["episodes"]) for s in seeds}
        if cell[1] == MLP:
            curves = {s: (data[cell][s]["env_steps"], data[cell][s]["eval_return"]) for s in seeds}
    return Evidence(values, last100, curves)


def grid_verdicts(env_name: str, cells: list, data: dict, scores: dict, random_policy: dict, steps: int,
                  target: float | None = None) -> tuple:
    """(answer rows, sensitivity rows, baseline record) of one task's fixed grid, judged exactly as gsa_jax.answer
    judges its first look (answering.decide with the default design): a table of n seeds is the look n reaches."""
    from gsa_jax.analysis.verdicts.answer_report import answer_rows, sensitivity_rows
    from gsa_jax.analysis.verdicts.answering import DEFAULT_LOOKS, Setup, decide

    ladder = tuple(sorted(c[2] for c in cells if c[1] == MIXTURE))
    spec = {"steps": int(steps), "hparams": {}, "config": {}}
    setup = Setup(env_name, ladder, verdict.DEFAULT_MARGIN, DEFAULT_LOOKS, {"mlp": spec, "mixture": spec}, target)
    evidence = grid_evidence(data, scores, cells)
    state = {"records": {}, "random": random_policy, "rounds": []}
    records, _, _ = decide(setup, evidence, state)
    few = min(len(v) for v in evidence.scores.values())
    if few < setup.looks[0]:
        why = f"too few seeds for a verdict ({few} per cell; the first look needs {setup.looks[0]})"
        records = {str(k): {"verdict": verdict.UNDECIDED, "why": why} for k in ladder}
    state["judged"] = records
    return answer_rows(setup, state), sensitivity_rows(setup, evidence, state), state.get("baseline")


def baseline_columns(base: dict | None) -> dict:
    """The baseline record as verdicts.csv columns: what was judged against, flat PPO's standing against the binding
    reference, and the still-learning test."""
    if not base:
        return {"versus": "flat PPO", "baseline_metric": "", "learned": ""}
    bind, learn = base.get("binding") or {}, base.get("learning") or {}
    return {"versus": base["versus"], "baseline_metric": base["metric"], "learned": int(base["learned"]),
            "binding_reference": f"{bind['algorithm']} ({bind['source']})" if bind else "",
            "binding_reference_score": bind.get("score", ""), "flat_on_its_metric": bind.get("ours", ""),
            "flat_gain_ratio_to_reference": bind.get("ratio", ""), "flat_below_reference": int(bind["below"]) if bind else "",
            "last_fifth_gain": learn.get("gain", ""), "last_fifth_gain_upper": learn.get("upper", ""),
            "stopped_learning": int(learn["stopped"]) if learn else ""}


def reference_value(cells: list, scores: dict, base: dict | None, target: float | None) -> float | None:
    """The score the margin line of a return-vs-K plot hangs from: flat PPO's IQM or the target (None where the
    verdicts judge against a reference on another metric, or there is no baseline)."""
    if target is not None:
        return float(target)
    if not base or base["metric"] != "controller_score":
        return None
    if base["entry"] is not None:
        return float(base["entry"]["score"])
    return stats.iqm(scores[cells[0]][0])


def verdict_table(data: dict, random_policies: dict, steps: dict, settings: Sequence[str] = (),
                  target: float | None = None) -> list:
    """verdicts.csv rows: per task and setting, each K's verdict at the default margin as gsa_jax.answer's first look
    gives it (role 'answer'), the other margins as sensitivity, and the baseline's columns. random_policies: {env:
    controller_scores.random_policy record}; steps: {env: env steps of its runs} (default: the runs' last env_steps);
    tasks without a random policy are left out."""
    scores, groups = final_scores(data), defaultdict(list)
    for cell in data:
        if cell[1] == MIXTURE and len(scores[cell][0]) == len(data[cell]):
            groups[(cell[0], cell_setting(cell, settings))].append(cell)
    rows = []
    for (env_name, setting), cells in sorted(groups.items()):
        flat = flat_cell(cells[0], data)
        if flat is not None and len(scores[flat][0]) == len(data[flat]):
            cells = [flat] + cells
        elif target is None:
            continue
        if env_name not in random_policies:
            continue
        budget = steps.get(env_name) or max(float(np.nanmax(r["env_steps"])) for c in cells for r in data[c].values())
        answer, sensitivity, base = grid_verdicts(env_name, cells, data, scores, random_policies[env_name], budget, target)
        ref = reference_value(cells, scores, base, target)
        common = {"env": env_name, **dict(setting), **baseline_columns(base), "score": scores[cells[0]][1],
                  "reference_iqm": "" if ref is None else round(ref, 4),
                  "random_return": round(float(np.mean(random_policies[env_name]["returns"])), 4)}
        for r in answer + sensitivity:
            rows.append({**common, "default_margin": int(r["margin"] == verdict.DEFAULT_MARGIN), **r})
    return rows


def sufficient_k_table(verdict_rows: list, settings: Sequence[str] = ()) -> list:
    """sufficient_k.csv rows: per task, setting and margin the smallest K judged sufficient (verdict_table: the
    answer's first look at the default margin, sensitivity at the others), '' where none is, with the smaller K still
    undecided and the answer in one sentence. The product's answer to "how many linear controllers does this task
    need?"."""
    groups = defaultdict(dict)
    for r in verdict_rows:
        key = (r["env"], tuple((c, r.get(c, "")) for c in settings), r["margin"], r["versus"])
        groups[key][int(r["K"])] = r
    out = []
    for (env_name, extra, margin, versus), by_k in groups.items():
        verdicts = {k: r["verdict"] for k, r in by_k.items()}
        chosen, below = verdict.smallest_sufficient(verdicts)
        first = next(iter(by_k.values()))
        label = env_name + "".join(f" {c}={v}" for c, v in extra if v != "")
        answer = verdict.sentence(label, verdicts, margin, versus or "flat PPO")
        if first.get("why"):
            answer = f"{label}: {'no answer: ' if first['verdict'] == verdict.NO_SCALE else ''}{first['why']}."
        out.append({"env": env_name, **dict(extra), "margin": margin, "default_margin": first["default_margin"],
                    "role": first["role"], "versus": versus, "smallest_sufficient_K": "" if chosen is None else chosen,
                    "undecided_below": " ".join(map(str, below)), "ks_tried": " ".join(map(str, sorted(by_k))),
                    "verdicts": " ".join(f"{k}:{verdicts[k]}" for k in sorted(by_k)),
                    "seeds": " ".join(f"{k}:{by_k[k].get('seeds', '')}" for k in sorted(by_k)), "answer": answer})
    return out


def sufficient_k_lines(table: list) -> list:
    """One printed line per row of sufficient_k_table at the default margin."""
    return ["  " + r["answer"] for r in table if r["default_margin"]]
