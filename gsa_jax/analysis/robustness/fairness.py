"""Comparisons under persistent shifts that do not favour weaker controllers.

The retained fraction (shifted - random) / (nominal - random) rewards having less to lose: a controller that
falls early anyway, or scores little, loses little. Two comparisons that do not:
  - above the line: per task and shift, the shifted score against the nominal score over the controllers
    of every *other* configuration (a least-squares line); a configuration's residuals say whether its
    controllers keep more than controllers of the same nominal score do (IQM [CI], and P(a mixture's
    residual exceeds flat PPO's)); `in_range` is the share of its controllers whose nominal score lies
    inside the others' (outside, the line is extrapolated);
  - full length only: the retained fraction compared only between controllers whose nominal episodes all
    reach the time limit (nominal.csv), so none has an early fall to hide a loss behind;
  - absolute: P(a mixture's shifted score exceeds flat PPO's). Where the mixture's nominal scores are lower
    (p_nominal_above_flat_ppo < 0.5) this comparison is biased *against* it, so 'more' there is conservative.
And the sensitivity-retention correlation controlling for nominal score (partial rank correlation).
"""

import math

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.robustness.shift_rows import cells
from gsa_jax.analysis.sweeps import stats

MIN_RUNS = 3  # controllers per side for an interval


def verdict(p: float, low: float, high: float) -> str:
    """'more' / 'less' / 'no difference' of P(mixture > flat PPO) and its CI ('' where none)."""
    if not all(isinstance(v, float) and np.isfinite(v) for v in (p, low, high)):
        return ""
    return "more" if low > 0.5 else "less" if high < 0.5 else "no difference"


def leave_out_residuals(by: dict, env_name: str, shift: str, config: tuple) -> tuple:
    """(residuals [n], share of the config's controllers inside the others' nominal range) of one
    configuration: shifted score minus the least-squares line of shifted on nominal score fit to every
    other configuration's controllers of the task under the shift."""
    own = list(by[(env_name, *config, shift)].values())
    others = [r for c, v in by.items() if c[0] == env_name and c[3] == shift and c[1:3] != config for r in v.values()]
    x = np.array([float(r["nominal_score"]) for r in others])
    y = np.array([float(r["score"]) for r in others])
    slope, intercept = np.polyfit(x, y, 1)
    nom = np.array([float(r["nominal_score"]) for r in own])
    # to the scores' own precision (3 decimals): a shift that changes nothing leaves residuals that tie
    res = np.round(np.array([float(r["score"]) for r in own]) - (slope * nom + intercept), 3)
    return res, float(np.mean((nom >= x.min()) & (nom <= x.max())))


def full_length_retained(by: dict, full: set, env_name: str, shift: str, config: tuple) -> np.ndarray:
    """[n] retained fractions under the shift of the configuration's controllers whose nominal episodes all
    reach the time limit (full: {controller key} of such controllers)."""
    cell = by[(env_name, *config, shift)]
    return np.array([float(r["retained_fraction"]) for seed, r in cell.items()
                     if (env_name, config[0], config[1], seed) in full and r["retained_fraction"] not in ("", None)], float)


def fair_rows(rows: list, nominal: list, reps: int = stats.REPS) -> list:
    """fair.csv rows: per task x configuration x shift (not nominal), the residual above the others' line
    (IQM [CI], P(mixture > flat PPO) [CI], in_range), the full-length-only retained fraction (controllers,
    IQM, P [CI]) and the verdict of each next to the retained fraction's (aggregate.csv's P)."""
    by = cells(rows)
    full = {(r["env"], r["policy"], str(r["K"]), str(r["seed"])) for r in nominal if float(r["full_length_fraction"]) >= 1.0}
    keys = sorted(c for c in by if c[3] != "nominal")
    resid = {c: leave_out_residuals(by, c[0], c[3], c[1:3]) for c in keys if len({k[1:3] for k in by if k[0] == c[0]}) > 1}
    fl = {c: full_length_retained(by, full, c[0], c[3], c[1:3]) for c in keys}
    retained = {c: np.array([float(r["retained_fraction"]) for r in by[c].values()], float) for c in keys}
    fin = lambda x: x[np.isfinite(x)][:, None]  # noqa: E731
    iqm_res = stats.iqm_ci({str(c): resid[c][0][:, None] for c in resid}, reps=reps) if resid else {}
    iqm_fl = stats.iqm_ci({str(c): fin(fl[c]) for c in keys if len(fin(fl[c])) >= MIN_RUNS}, reps=reps)
    flat = lambda c: (c[0], MLP, "", c[3])  # noqa: E731
    mix = [c for c in keys if c[1] == MIXTURE and flat(c) in by]
    p_res = probabilities({str(c): (resid[c][0][:, None], resid[flat(c)][0][:, None]) for c in mix if c in resid}, reps=reps)
    p_fl = probabilities({str(c): (fin(fl[c]), fin(fl[flat(c)])) for c in mix
                                          if min(len(fin(fl[c])), len(fin(fl[flat(c)]))) >= MIN_RUNS}, reps=reps)
    p_ret = probabilities({str(c): (fin(retained[c]), fin(retained[flat(c)])) for c in mix}, reps=reps)
    score = lambda c, col: np.array([float(r[col]) for r in by[c].values()])[:, None]  # noqa: E731
    p_abs = probabilities({str(c): (score(c, "score"), score(flat(c), "score")) for c in mix}, reps=reps)
    p_nom = {str(c): stats.improvement_probability({0: (score(c, "nominal_score"), score(flat(c), "nominal_score"))}, reps=1)[0][0]
             for c in mix}
    return [{**fair_row(c, resid.get(c), len(fl[c]), iqm_res, iqm_fl, p_res, p_fl, p_ret), **absolute_columns(c, p_abs, p_nom)}
            for c in sorted(keys, key=lambda c: (c[0], c[3], c[1] != MLP, int(c[2] or 0)))]


def absolute_columns(c: tuple, p_abs: dict, p_nom: dict) -> dict:
    """P(the mixture's shifted score > flat PPO's) [CI], its verdict, and P(its nominal score > flat PPO's)."""
    r3 = lambda v: round(float(v), 3) if np.isfinite(v) else ""  # noqa: E731
    p = p_abs.get(str(c), (math.nan,) * 3)
    return {"p_score_above_flat_ppo": r3(p[0]), "p_score_ci_low": r3(p[1]), "p_score_ci_high": r3(p[2]),
            "absolute_says": verdict(*p), "p_nominal_above_flat_ppo": r3(p_nom.get(str(c), math.nan))}


def probabilities(pairs: dict, reps: int) -> dict:
    """stats.improvement_probability of the pairs, {} where there are none."""
    return stats.improvement_probability(pairs, reps=reps) if pairs else {}


def fair_row(c: tuple, resid: tuple | None, n_full: int, iqm_res: dict, iqm_fl: dict, p_res: dict, p_fl: dict,
             p_ret: dict) -> dict:
    """One fair.csv row from the computed statistics (blank where a statistic does not exist)."""
    nan3 = (math.nan,) * 3
    r3 = lambda v: round(float(v), 3) if np.isfinite(v) else ""  # noqa: E731
    res, pr, fl, pf, pt = (iqm_res.get(str(c), nan3), p_res.get(str(c), nan3), iqm_fl.get(str(c), nan3),
                           p_fl.get(str(c), nan3), p_ret.get(str(c), nan3))
    return {"env": c[0], "policy": c[1], "K": c[2], "shift": c[3], "runs": len(resid[0]) if resid else "",
            "residual_iqm": r3(res[0]), "residual_ci_low": r3(res[1]), "residual_ci_high": r3(res[2]),
            "in_range": r3(resid[1]) if resid else "", "p_residual_above_flat_ppo": r3(pr[0]),
            "p_residual_ci_low": r3(pr[1]), "p_residual_ci_high": r3(pr[2]),
            "full_length_runs": n_full, "full_length_retained_iqm": r3(fl[0]), "full_length_retained_ci_low": r3(fl[1]),
            "full_length_retained_ci_high": r3(fl[2]), "p_full_length_retains_more": r3(pf[0]),
            "p_full_length_ci_low": r3(pf[1]), "p_full_length_ci_high": r3(pf[2]),
            "retained_fraction_says": verdict(*pt), "line_says": verdict(*pr), "full_length_says": verdict(*pf)}


def partial_spearman(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple:
    """(rho, p) of Spearman's rank correlation between x and y controlling for z: the Pearson correlation of
    the ranks' residuals after a least-squares fit on z's ranks, its p-value from Student's t with n - 3
    degrees of freedom."""
    from scipy.stats import rankdata, t

    rx, ry, rz = (rankdata(v) for v in (x, y, z))
    design = np.stack([np.ones_like(rz), rz], axis=1)
    ex = rx - design @ np.linalg.lstsq(design, rx, rcond=None)[0]
    ey = ry - design @ np.linalg.lstsq(design, ry, rcond=None)[0]
    rho = float(ex @ ey / math.sqrt((ex @ ex) * (ey @ ey)))
    n = len(x)
    stat = rho * math.sqrt((n - 3) / max(1e-300, 1 - rho * rho))
    return rho, float(2 * t.sf(abs(stat), n - 3))
