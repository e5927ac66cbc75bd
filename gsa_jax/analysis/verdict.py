"""Is K enough? A non-inferiority verdict per (task, K): `sufficient`, `insufficient` or `undecided`.

The gap of a cell is the difference of IQMs (interquartile mean over seeds, rliable's aggregate_iqm: the
mean of the middle half of the sorted scores) on the scale of flat PPO's gain over a random policy:

    gap = (IQM(mixture) - IQM(flat PPO)) / (IQM(flat PPO) - random return)

so gap = -0.1 means the mixtures keep 90% of what flat PPO learned. With `target` (a score the user's robot
needs) instead of flat PPO: gap = (IQM(mixture) - target) / (target - random return). The interval of the
gap is a stratified percentile bootstrap (seeds resampled within each cell; the denominator resampled with
flat PPO's seeds, so its uncertainty is in the interval). At margin delta:

    sufficient    the whole interval lies above -delta  (shown within delta of flat PPO, or better)
    insufficient  the whole interval lies below -delta  (shown worse than the margin allows)
    undecided     otherwise, with an estimate of the seeds per cell that would likely decide it

A cell is judged at looks fixed in advance (seeds per cell, e.g. 10, 20, 40). With L looks each uses a
two-sided interval of level 1 - ALPHA / L (Bonferroni over the looks), so adding seeds until decided keeps
the chance of calling a cell sufficient whose true gap is exactly -delta at most ALPHA / 2 (one side of the
interval); tests/test_verdict.py checks it by simulation. A task whose flat PPO does not beat the random
policy gets no verdict (the scale is undefined).
"""

import math
from typing import NamedTuple

import numpy as np

ALPHA = 0.05  # 1 - the stated level: 95% intervals
MARGINS = (0.05, 0.1, 0.2)  # the margins every answer reports
DEFAULT_MARGIN = 0.1  # the answer's margin: keep at least 90% of flat PPO's gain over a random policy
REPS = 4000  # bootstrap resamples of a verdict's interval
SUFFICIENT, INSUFFICIENT, UNDECIDED, NO_SCALE = "sufficient", "insufficient", "undecided", "no answer"


class Gap(NamedTuple):
    """A cell's gap (point, interval low, high), its verdict at `margin`, the seeds per cell, and the estimated
    seeds per cell that would likely decide it (n itself where decided; None where no finite number would)."""

    point: float
    low: float
    high: float
    verdict: str
    margin: float
    level: float
    n: int
    seeds_to_decide: int | None


def iqm(scores: np.ndarray) -> np.ndarray:
    """The interquartile mean along the last axis of scores [..., n] (scipy.stats.trim_mean(x, 0.25), which
    rliable's aggregate_iqm is for one task): the mean of the sorted values int(n/4) .. n - int(n/4) - 1."""
    x = np.sort(np.asarray(scores, np.float64), axis=-1)
    n = x.shape[-1]
    cut = int(0.25 * n)
    return x[..., cut: n - cut].mean(axis=-1)


def resampled_iqms(scores: np.ndarray, reps: int, rng: np.random.Generator) -> np.ndarray:
    """IQMs [reps] of `reps` bootstrap resamples (with replacement, same size) of one cell's scores [n]."""
    x = np.asarray(scores, np.float64)
    return iqm(x[rng.integers(0, len(x), size=(reps, len(x)))])


def gap_samples(mixture: np.ndarray, reference: np.ndarray, random_return: float, target: float | None = None,
                reps: int = REPS, seed: int = 0) -> tuple | None:
    """(point gap, bootstrap gaps [reps]) of a mixture cell against flat PPO's scores `reference` [n_f], or against
    the fixed score `target` (reference unused); None where the scale (reference IQM - random return) is <= 0."""
    rng = np.random.default_rng(seed)
    mix = np.asarray(mixture, np.float64)
    if target is not None:
        scale = float(target) - random_return
        if scale <= 0:
            return None
        return (float(iqm(mix)) - target) / scale, (resampled_iqms(mix, reps, rng) - target) / scale
    ref = np.asarray(reference, np.float64)
    scale = float(iqm(ref)) - random_return
    if scale <= 0:
        return None
    boot_mix, boot_ref = resampled_iqms(mix, reps, rng), resampled_iqms(ref, reps, rng)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = (boot_mix - boot_ref) / (boot_ref - random_return)
    boot = np.where(boot_ref - random_return > 0, boot, -1e9)  # a resample where flat PPO learned nothing
    return (float(iqm(mix)) - float(iqm(ref))) / scale, boot


def look_level(looks: int) -> float:
    """The two-sided level of each look's interval when a cell may be judged at `looks` looks (Bonferroni)."""
    return 1.0 - ALPHA / max(int(looks), 1)


def decide(low: float, high: float, margin: float) -> str:
    """sufficient / insufficient / undecided of an interval [low, high] of the gap at margin delta."""
    if low > -margin:
        return SUFFICIENT
    if high < -margin:
        return INSUFFICIENT
    return UNDECIDED


def seeds_to_decide(point: float, low: float, high: float, margin: float, n: int) -> int | None:
    """Seeds per cell that would likely decide an undecided cell: its interval's half-width shrinking as
    1/sqrt(n) until it no longer reaches -margin from the point estimate (None if the point sits on -margin)."""
    distance, half = abs(point + margin), 0.5 * (high - low)
    if not np.isfinite(half) or distance < 1e-12:
        return None
    return max(n + 1, int(math.ceil(n * (half / distance) ** 2)))


def judge(mixture: np.ndarray, reference: np.ndarray, random_return: float, margin: float = DEFAULT_MARGIN, looks: int = 1,
          target: float | None = None, reps: int = REPS, seed: int = 0) -> Gap:
    """The verdict of one mixture cell (scores [n]) against flat PPO's scores [n_f] (or `target`) at `margin`,
    with the interval of a design of `looks` looks (look_level)."""
    if not 0.0 < margin < 1.0:
        raise ValueError(f"the margin must be in (0, 1), got {margin}")
    n = len(mixture) if target is not None else min(len(mixture), len(reference))
    level = look_level(looks)
    sampled = gap_samples(mixture, reference, random_return, target, reps, seed)
    if sampled is None:
        return Gap(math.nan, math.nan, math.nan, NO_SCALE, margin, level, n, None)
    point, boot = sampled
    low, high = (float(v) for v in np.quantile(boot, [0.5 * (1 - level), 1 - 0.5 * (1 - level)]))
    verdict = decide(low, high, margin)
    more = n if verdict != UNDECIDED else seeds_to_decide(point, low, high, margin, n)
    return Gap(point, low, high, verdict, margin, level, n, more)


def smallest_sufficient(verdicts: dict) -> tuple:
    """(smallest sufficient K or None, [undecided K below it]) of {K: verdict}."""
    ks = sorted(verdicts)
    chosen = next((k for k in ks if verdicts[k] == SUFFICIENT), None)
    below = [k for k in ks if (chosen is None or k < chosen) and verdicts[k] == UNDECIDED]
    return chosen, below


def sentence(task: str, verdicts: dict, margin: float, versus: str) -> str:
    """The answer in one sentence from {K: verdict} at `margin` (versus: 'flat PPO' or 'the target score S')."""
    chosen, below = smallest_sufficient(verdicts)
    pct = f"{margin:.0%}"
    if all(v == NO_SCALE for v in verdicts.values()):
        return f"{task}: no answer: {versus} does not score above a random policy, so no margin can be set."
    if chosen is None:
        undecided = [k for k, v in sorted(verdicts.items()) if v == UNDECIDED]
        if undecided:
            return (f"{task}: not decided: no K of {sorted(verdicts)} is shown within {pct} of {versus}; "
                    f"K = {', '.join(map(str, undecided))} still undecided.")
        return f"{task}: no K of {sorted(verdicts)} is within {pct} of {versus} (all shown insufficient)."
    tail = (f"; smaller K = {', '.join(map(str, below))} undecided" if below
            else ("; every smaller K shown insufficient" if chosen != min(verdicts) else ""))
    verb = "controller suffices" if chosen == 1 else "controllers suffice"
    return f"{task}: K = {chosen} linear {verb} (shown within {pct} of {versus}){tail}."
