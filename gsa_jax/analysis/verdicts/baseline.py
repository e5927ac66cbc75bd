"""Is flat PPO an adequate baseline? Two checks before any verdict (docs/answer.md, "A baseline shown adequate"):

1. **Has it stopped learning at the budget?** Per seed, the gain of its training-time deterministic evaluations over
   the last fifth of training: the mean return of the evaluations in the last WINDOW of the steps minus that of the
   evaluations in the WINDOW ending at 80% of the steps. Their interquartile mean over seeds, on the scale of flat
   PPO's gain over the random policy, is shown below the margin (the one-sided 95% upper bound of Yuen's t under it)
   or flat PPO is reported as still learning, with the estimate and the bound: train longer (--steps).
2. **Does it reach the best reference known for the task at that budget?** A table of published PPO scores and the
   project's own tuned flat PPO (ppo_references.csv beside this module; `--references FILE` takes another): each
   entry with its source, task version, steps, seeds and metric. An entry applies when its steps are at most the
   budget. It is compared on its own metric: 'training_last_100' (CleanRL's tables: each seed's mean over its last
   100 training episodes, mean over seeds) against flat PPO's same statistic; 'deterministic' (a deterministic
   policy's evaluation return: Stable-Baselines3's zoo, Tianshou's best test return, our tuned runs' controllers)
   against flat PPO's controller scores (mean over seeds). Flat PPO is below an entry when its gain over the random
   policy on that metric is under (1 - margin) of the entry's. The entry flat PPO stands lowest against binds; where
   flat PPO is below it, the answer judges against that entry (a fixed score with its standard error over its
   seeds) on that entry's metric, never against the weaker run.
"""

import csv
import math
import os
from typing import NamedTuple, Sequence

import numpy as np

from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.verdicts import trimmed
from gsa_jax.errors import UserError

REFERENCES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ppo_references.csv")
COLUMNS = ("task", "published_task", "score", "std", "seeds", "steps", "metric", "algorithm", "source", "note")
METRICS = {"training_last_100": C.LAST_EPISODES_RETURN, "deterministic": C.CONTROLLER_SCORE}
WINDOW = 0.05  # the share of the steps each end of the last fifth averages its evaluations over
LEARNING_LEVEL = 0.05  # each side: 'stopped learning' when the last fifth's gain is shown inside (-margin, margin)
MIN_EVALS = 3  # an end of the last fifth averages at least this many evaluations (the window widens to take them)


class ReferencesError(UserError, ValueError):
    """A references table that cannot be read: the file, its line and the bad field in one line."""


def parse_reference(row: dict, where: str) -> dict:
    """One checked entry of a references table (ReferencesError naming the line and the field)."""
    missing = [c for c in ("task", "score", "steps", "metric", "source") if not (row.get(c) or "").strip()]
    if missing:
        raise ReferencesError(f"{where}: missing {', '.join(missing)}")
    if row["metric"] not in METRICS:
        raise ReferencesError(f"{where}: metric {row['metric']!r} is not one of {', '.join(METRICS)}")
    try:
        score, steps = float(row["score"]), int(float(row["steps"]))
        std = float(row["std"]) if (row.get("std") or "").strip() else 0.0
        seeds = int(row["seeds"]) if (row.get("seeds") or "").strip() else 0
    except ValueError as e:
        raise ReferencesError(f"{where}: {e}") from None
    if not (math.isfinite(score) and steps > 0 and std >= 0 and seeds >= 0):
        raise ReferencesError(f"{where}: score must be finite, steps > 0, std and seeds >= 0")
    return {**{c: (row.get(c) or "").strip() for c in COLUMNS}, "score": score, "std": std, "seeds": seeds, "steps": steps}


def load_references(path: str = REFERENCES) -> list:
    """The checked entries of a references table (CSV with COLUMNS); ReferencesError in one line if it is malformed."""
    if not os.path.exists(path):
        raise ReferencesError(f"references table {path!r} does not exist")
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        absent = [c for c in ("task", "score", "steps", "metric", "source") if c not in (reader.fieldnames or [])]
        if absent:
            raise ReferencesError(f"references table {path!r} lacks the column(s) {', '.join(absent)}")
        return [parse_reference(r, f"{path} line {i + 2}") for i, r in enumerate(reader)]


def applicable(references: Sequence[dict], task: str, steps: int) -> list:
    """The entries for `task` at no more than `steps` env steps."""
    return [r for r in references if r["task"] == task and r["steps"] <= steps]


def highest(references: Sequence[dict], task: str, steps: int) -> dict | None:
    """The applicable entry with the highest score (the constructive answer's bar where it is above flat PPO's best
    controller); None where there is none."""
    entries = applicable(references, task, steps)
    return max(entries, key=lambda r: r["score"]) if entries else None


class Standing(NamedTuple):
    """Flat PPO against one reference entry on the entry's metric: ours (mean over seeds), the entry's score, the
    ratio of the two gains over the random policy, whether flat PPO is *shown* below the entry (its gain below 1 -
    margin of the entry's: a one-sided test at LEARNING_LEVEL with the entry's error over its seeds and the random
    return's), and that test's p-value."""

    reference: dict
    ours: float
    ratio: float
    below: bool
    p_below: float = math.nan


def stand(reference: dict, flat_values: dict, rand: trimmed.Summary, margin: float) -> Standing | None:
    """Flat PPO's standing against one entry; flat_values: {metric column: [per-seed values]}; None where flat PPO has
    no value of the entry's metric. A point estimate a little below the entry does not switch the baseline."""
    values = [v for v in flat_values.get(METRICS[reference["metric"]], []) if np.isfinite(v)]
    if not values:
        return None
    ours = float(np.mean(values))
    gain = reference["score"] - rand.mean
    ratio = (ours - rand.mean) / gain if gain > 0 else math.inf
    if len(values) < 2 or gain <= 0:
        return Standing(reference, ours, ratio, False, math.nan)
    c = trimmed.contrast([(1.0, trimmed.plain(values)), (-(1.0 - margin), reference_summary(reference)), (-margin, rand)])
    p = trimmed.p_below(c)
    return Standing(reference, ours, ratio, bool(p < LEARNING_LEVEL), p)


def binding(standings: Sequence[Standing]) -> Standing | None:
    """The entry flat PPO is shown below with the lowest ratio, else the one it stands lowest against (None where
    there is none)."""
    found = [s for s in standings if s is not None]
    below = [s for s in found if s.below]
    return min(below or found, key=lambda s: s.ratio) if found else None


def reference_name(reference: dict) -> str:
    """A reference entry in a few words: 'the reference <algorithm> on <task> (<score>, <metric>)'."""
    algorithm = reference["algorithm"].split(" (")[0].split(",")[0]
    return f"the reference {algorithm} on {reference['published_task'].split(' (')[0]} ({reference['score']:g}, {reference['metric']})"


def reference_summary(reference: dict) -> trimmed.Summary:
    """An entry as a fixed score with its standard error over its seeds (trimmed.fixed)."""
    return trimmed.fixed(reference["score"], reference["std"], reference["seeds"])


# ------------------------------------------------------------------------------------------- still learning?
def window_steps(steps: np.ndarray, at_step: float, end: str) -> np.ndarray:
    """The evaluation steps [m] that one end ('start' or 'end') of the last fifth of `at_step` averages: those in its
    5% window ((0.8 - 0.05, 0.8] or (0.95, 1] of at_step), or where that holds fewer than MIN_EVALS, the MIN_EVALS
    nearest its anchor within a tenth of the budget either side ((0.7, 0.9] or (0.9, 1]: the ends share none)."""
    steps = np.asarray(steps, np.float64)
    anchor, lo, hi = (0.8 * at_step, 0.7 * at_step, 0.9 * at_step) if end == "start" else (at_step, 0.9 * at_step, at_step)
    inside = steps[(steps > anchor - WINDOW * at_step) & (steps <= anchor)]
    if inside.size >= MIN_EVALS:
        return inside
    near = steps[(steps > lo) & (steps <= hi)]
    return np.sort(near[np.argsort(np.abs(near - anchor), kind="stable")[:MIN_EVALS]])


def window_mean(steps: np.ndarray, returns: np.ndarray, at_step: float, end: str) -> float:
    """The mean of a run's finite evaluations at its window_steps (NaN where there is none)."""
    ok = np.isfinite(returns)
    s, r = np.asarray(steps, np.float64)[ok], np.asarray(returns)[ok]
    chosen = np.isin(s, window_steps(s, at_step, end))
    return float(r[chosen].mean()) if chosen.any() else math.nan


def last_fifth_gains(curves: Sequence[tuple], at_step: float) -> np.ndarray:
    """Per run the gain of its evaluations over the last fifth of `at_step` steps, each end averaging several
    evaluations where it has them (window_steps); curves: [(env_steps [T], eval_return [T])] per seed."""
    out = [window_mean(s, r, at_step, "end") - window_mean(s, r, at_step, "start") for s, r in curves]
    return np.asarray([g for g in out if np.isfinite(g)], np.float64)


def steps_read(at_step: int, every: int) -> list:
    """The env steps, among the multiples of `every` up to `at_step` (a run evaluated every `every` steps), whose
    evaluations last_fifth_gains(at_step) reads (window_steps of both ends). A run evaluated only there gives the
    same gains as one evaluated at every multiple."""
    grid = np.arange(every, at_step + 1, every, dtype=np.int64)
    ends = [window_steps(grid, float(at_step), e) for e in ("start", "end")]
    return sorted({int(x) for chosen in ends for x in chosen})


class Learning(NamedTuple):
    """Flat PPO over the last fifth of `steps`: its IQM gain over seeds as a fraction of its gain over the random
    policy, that fraction's 90% interval (LEARNING_LEVEL each side), and whether it has stopped: the interval inside
    (-margin, margin) (a curve falling by the margin or more has not stopped, nor one not shown flat)."""

    steps: float
    gain: float
    upper: float
    stopped: bool
    seeds: int
    lower: float = math.nan


def learning(curves: Sequence[tuple], at_step: float, scale: float, margin: float) -> Learning:
    """Has flat PPO stopped learning at `at_step`? Two one-sided tests of its last fifth's gain (an equivalence
    test: shown below +margin and above -margin of its gain over the random policy, scale in score units). Runs
    without an evaluation at an end (a budget of a few evaluations) give no gain; fewer than two: not stopped."""
    gains = last_fifth_gains(curves, at_step)
    if len(gains) < 2 or not scale > 0:
        return Learning(at_step, math.nan, math.nan, False, len(gains))
    s = trimmed.trimmed(gains)
    c = trimmed.contrast([(1.0, s)])
    half = trimmed.t_quantile(LEARNING_LEVEL, c.df) * c.se if c.se > 0 else 0.0
    upper, lower = (s.mean + half) / scale, (s.mean - half) / scale
    return Learning(at_step, s.mean / scale, upper, bool(-margin < lower and upper < margin), len(gains), lower)


def plateau_step(curves: Sequence[tuple], candidates: Sequence[float], scale: float, margin: float) -> float | None:
    """The first of the candidate budgets (increasing env steps) at which flat PPO is shown to have stopped
    learning (None if at none)."""
    for at in candidates:
        if learning(curves, at, scale, margin).stopped:
            return float(at)
    return None


# ------------------------------------------------------------------------------------------- the choice
LEARNED = 0.1  # where a task declares its maximum return: flat PPO must reach this share of the way from random to it


def learned(flat_scores: Sequence[float], rand: trimmed.Summary, max_return: float | None) -> tuple:
    """(whether the task counts as learned by flat PPO at this budget, why not): where the task declares its maximum
    return, 'not learned' needs flat PPO's IQM over its scores [n] *shown* below LEARNED of the way from the random
    policy's return to it (Yuen's test with the random return's error, one-sided at LEARNING_LEVEL); an IQM a coin
    flip away from that bar is not taken as 'not learned'. Matching a policy that has not learned the task says
    nothing of the task."""
    values = [float(v) for v in flat_scores if np.isfinite(v)]
    if max_return is None or len(values) < 2:
        return True, ""
    flat = trimmed.trimmed(values)
    bar = rand.mean + LEARNED * (max_return - rand.mean)
    c = trimmed.contrast([(1.0, flat), (-(1.0 - LEARNED), rand)])
    p = trimmed.p_below(trimmed.Contrast(c.estimate - LEARNED * max_return, c.se, c.df))
    if not p < LEARNING_LEVEL:
        return True, ""
    return False, (f"flat PPO does not learn the task at this budget (IQM {flat.mean:.1f} shown below {bar:.1f}, p = "
                   f"{p:.2g}; {LEARNED:.0%} of the way from the random policy's {rand.mean:.1f} to the maximum "
                   f"{max_return:g})")


def standing_record(s: Standing) -> dict:
    """A Standing as answer.json and the reports keep it."""
    r = s.reference
    return {"source": r["source"], "algorithm": r["algorithm"], "published_task": r["published_task"],
            "metric": r["metric"], "steps": r["steps"], "seeds": r["seeds"], "score": r["score"], "std": r["std"],
            "ours": round(s.ours, 3), "ratio": round(s.ratio, 4), "below": s.below,
            "p_below": None if math.isnan(s.p_below) else round(s.p_below, 6)}


class FlatRuns(NamedTuple):
    """Flat PPO's runs as the baseline checks read them: per seed its controller score and its mean return over the
    last 100 training episodes, and its learning curves [(env_steps [T], eval_return [T])]."""

    controller: Sequence[float]
    last100: Sequence[float]
    curves: Sequence[tuple]


def choose(task: str, steps: int, margin: float, flat: FlatRuns, rand: trimmed.Summary, references: Sequence[dict],
           max_return: float | None = None) -> dict:
    """The baseline record of an answer: flat PPO's standing against every entry that applies, whether it still
    learns at the budget and learns the task at all, and what the verdicts judge against (flat PPO on controller
    scores; the binding entry on its own metric where flat PPO is below it)."""

    values = {C.CONTROLLER_SCORE: list(flat.controller), C.LAST_EPISODES_RETURN: list(flat.last100)}
    standings = [s for s in (stand(r, values, rand, margin) for r in applicable(references, task, steps)) if s]
    bind = binding(standings)
    flat_iqm = stats.iqm(flat.controller) if len(flat.controller) else float("nan")
    learn = learning(flat.curves, steps, flat_iqm - rand.mean, margin)
    ok, why = learned(flat.controller, rand, max_return)
    entry = bind.reference if bind is not None and bind.below else None
    versus = "flat PPO" if entry is None else reference_name(entry)
    return {"versus": versus, "metric": METRICS[entry["metric"]] if entry else C.CONTROLLER_SCORE, "entry": entry,
            "standings": [standing_record(s) for s in standings],
            "binding": standing_record(bind) if bind is not None else None,
            "learning": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in learn._asdict().items()},
            "learned": ok, "why": why, "max_return": max_return}
