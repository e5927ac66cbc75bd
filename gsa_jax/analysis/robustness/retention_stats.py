"""Statistics of the tidy rows of controllers under shifts: aggregate.csv (IQM [CI] of the retained fraction
and shifted score, P(retains more than flat PPO)), correlation.csv (sensitivity against retention) and the
per-run scores of the performance profile."""

import math
from typing import Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.robustness.fairness import partial_spearman
from gsa_jax.analysis.robustness.shift_rows import RETAINED_CI, cells, controller_key
from gsa_jax.analysis.sweeps import stats

MULTIPLIERS = (0.5, 1, 2, 4)


def config_names(policy: str, k: int | str, action_dim: int) -> list:
    """['flat PPO'] or ['K = m d_a', ...] for every Figure-1 multiplier m whose ceil(m d_a) is K (on a
    one-action task K = 1 is both 0.5 and 1 d_a), else ['K = k']."""
    if policy == MLP:
        return ["flat PPO"]
    ms = [m for m in MULTIPLIERS if max(1, math.ceil(m * action_dim - 1e-9)) == int(k)]
    return [f"K = {m:g} d_a" for m in ms] or [f"K = {k}"]


def aggregate(rows: list, reps: int = stats.REPS) -> list:
    """aggregate.csv rows: per task x (policy, K) x shift, IQM [CI] of retained fraction and shifted score,
    P(retains more than flat PPO) [CI] for mixtures (runs paired by nothing: rliable's P over runs)."""
    by = cells(rows)
    retained = {c: np.array([float(r["retained_fraction"]) for r in v.values()]) for c, v in by.items()}
    score = {c: np.array([float(r["score"]) for r in v.values()]) for c, v in by.items()}
    iqm_r = stats.iqm_ci({str(c): x[np.isfinite(x)][:, None] for c, x in retained.items()}, reps=reps)
    iqm_s = stats.iqm_ci({str(c): x[:, None] for c, x in score.items()}, reps=reps)
    pairs = {str(c): (retained[c][:, None], retained[(c[0], MLP, "", c[3])][:, None]) for c in by
             if c[1] == MIXTURE and (c[0], MLP, "", c[3]) in by}
    better = stats.improvement_probability(pairs, reps=reps) if pairs else {}
    out = []
    for c in sorted(by, key=lambda c: (c[0], c[1] != MLP, int(c[2] or 0), c[3])):
        p = better.get(str(c), (math.nan,) * 3)
        r3 = lambda v: round(float(v), 3) if np.isfinite(v) else ""  # noqa: E731
        out.append({"env": c[0], "policy": c[1], "K": c[2], "shift": c[3], "runs": len(by[c]),
                    **{col: r3(v) for col, v in zip(RETAINED_CI, iqm_r[str(c)])}, "score_iqm": r3(iqm_s[str(c)][0]),
                    "score_ci_low": r3(iqm_s[str(c)][1]), "score_ci_high": r3(iqm_s[str(c)][2]),
                    "p_retains_more_than_flat_ppo": r3(p[0]), "p_ci_low": r3(p[1]), "p_ci_high": r3(p[2])})
    return out


def correlations(sens: list, rows: Sequence = ()) -> list:
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


def correlation_row(name: str, xyz: np.ndarray) -> dict:
    """One correlation.csv row of [n, 3] (sensitivity, mean retained fraction, nominal score)."""
    from scipy.stats import spearmanr

    rho, p = spearmanr(xyz[:, 0], xyz[:, 1])
    row = {"env": name, "controllers": len(xyz), "spearman_rho": round(float(rho), 3), "p_value": float(f"{p:.3g}"),
           "partial_rho_given_nominal": "", "partial_p_value": ""}
    if np.isfinite(xyz[:, 2]).all() and len(xyz) > 3:
        prho, pp = partial_spearman(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        row.update(partial_rho_given_nominal=round(prho, 3), partial_p_value=float(f"{pp:.3g}"))
    return row


def profile_scores(rows: list, action_dims: dict) -> dict:
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
