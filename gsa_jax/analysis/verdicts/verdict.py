"""Is K enough? A non-inferiority verdict per (task, K): `sufficient`, `insufficient`, `undecided` or `no answer`.

The gap of a cell is the difference of interquartile means (IQM: the 25% trimmed mean over seeds, rliable's
aggregate_iqm for one task) on the scale of the reference's gain over a uniformly random policy:

    gap = (IQM(mixture) - IQM(reference)) / (IQM(reference) - mean(random-policy episodes))

so gap = -0.1 means the mixtures keep 90% of what the reference learned. The reference is flat PPO's seeds, or a
fixed score (a target a robot needs, or a published PPO score with its standard error: gsa_jax.analysis.verdicts.baseline).
"K is within delta" is the linear statement IQM(mix) - (1 - delta) IQM(ref) - delta R > 0, tested with Yuen's
trimmed-mean t for a contrast (gsa_jax.analysis.verdicts.trimmed): the random return's own uncertainty (its episodes) and a
published reference's are in the test, and no resampling is involved, so a verdict does not depend on a seed. At
margin delta and the look's one-sided level a (gsa_jax.analysis.verdicts.sequential: the design's share for this K and look):

    sufficient    p(gap <= -delta) < a   (shown within delta of the reference, or better), and against flat PPO's seeds
                  also p_share < a: the mixture's seeds are shown to fail no more often than flat PPO's, within
                  SHARE_MARGIN (a seed fails when it keeps less than FAIL_GAIN of flat PPO's IQM gain over the
                  random policy; gsa_jax.analysis.verdicts.shares.share_p, exact). Both at the same level: the
                  claim is their conjunction, so the pair errs no more than either (an intersection-union test).
                  The IQM alone does not see failing seeds: a mixture failing on 29% of its seeds, its others far
                  above flat PPO, has an IQM above flat PPO's; and ties at the ceiling collapse Yuen's error
    insufficient  p(gap >= -delta) < a   (shown worse than the margin allows)
    undecided     otherwise, with the seeds per cell for 80% power at parity and at the observed gap, and the
                  chance that the seed cap decides it if the gap is what it looks (chance_by_cap: the answer stops
                  adding seeds below FUTILITY)
    no answer     the reference's gain over the random policy is not shown positive (one-sided p < GAIN_LEVEL)

The gap's interval [low, high] is the set of gaps no one-sided test at level a rejects (the test inverted, as
Fieller's interval for a ratio): unbounded where the scale itself is uncertain.
"""

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np

from gsa_jax.analysis.verdicts import shares, trimmed

ALPHA = 0.025  # the one-sided chance of wrongly calling some K sufficient, over the whole answer
GAIN_LEVEL = 0.025  # the reference's gain over the random policy must be shown positive at this one-sided level
POWER = 0.8  # the power the seed estimates aim at
FUTILITY = 0.05  # the answer stops adding seeds to a K whose chance to be decided by the seed cap is below this
MARGINS = (0.05, 0.1, 0.2)  # the margins every answer reports (the others as sensitivity, not as the answer)
DEFAULT_MARGIN = 0.1  # the answer's margin: keep at least 90% of the reference's gain over a random policy
FAIL_GAIN = 0.5  # a seed fails when its score keeps less than this share of flat PPO's IQM gain over the random policy
SHARE_MARGIN = 0.2  # 'sufficient' against flat PPO also needs the mixture's failures shown at most this much more frequent
SUFFICIENT, INSUFFICIENT, UNDECIDED, NO_SCALE = "sufficient", "insufficient", "undecided", "no answer"


class Gap(NamedTuple):
    """A cell's gap (point, interval low/high at the look's level), its verdict at `margin`, the look's nominal
    one-sided level, the seeds (mixture, reference: 0 for a fixed score), the two one-sided p-values, and the seeds
    per cell for 80% power at parity (gap 0) and at the observed gap (None where no finite number would do), and the
    chance that the design's last look decides the cell if its contrast is what it is now (None: not asked), and the
    failure-share test's p-value against flat PPO's seeds (failure_share_p; NaN against a fixed score)."""

    point: float
    low: float
    high: float
    verdict: str
    margin: float
    level: float
    n: int
    n_ref: int
    p_sufficient: float
    p_insufficient: float
    seeds_parity: int | None
    seeds_observed: int | None
    chance_by_cap: float | None = None
    p_share: float = math.nan  # the failure-share test's p-value (NaN: not asked, against a fixed score)


def summarize_reference(reference: "Sequence[float] | trimmed.Summary") -> trimmed.Summary:
    """A reference as a contrast group: flat PPO's scores [n] (their IQM), or a Summary (a fixed score)."""
    return reference if isinstance(reference, trimmed.Summary) else trimmed.trimmed(reference)


def summarize_random(random_returns: "Sequence[float] | float") -> trimmed.Summary:
    """The random policy as a contrast group: its episodes' returns [n] (their mean), or one number taken as exact."""
    if np.ndim(random_returns) == 0:
        return trimmed.fixed(float(random_returns))
    return trimmed.plain(random_returns)


def margin_contrast(mix: trimmed.Summary, ref: trimmed.Summary, rand: trimmed.Summary, gap: float) -> trimmed.Contrast:
    """IQM(mix) - (1 + gap) IQM(ref) + gap R: positive exactly when the cell's gap is above `gap`."""
    return trimmed.contrast([(1.0, mix), (-(1.0 + gap), ref), (gap, rand)])


def gain_shown(ref: trimmed.Summary, rand: trimmed.Summary) -> bool:
    """Whether the reference's gain over the random policy is shown positive (one-sided p < GAIN_LEVEL)."""
    return trimmed.p_above(trimmed.contrast([(1.0, ref), (-1.0, rand)])) < GAIN_LEVEL


def bound(mix: trimmed.Summary, ref: trimmed.Summary, rand: trimmed.Summary, point: float, level: float,
          upper: bool) -> float:
    """The gap at which the one-sided test at `level` stops rejecting: the interval's low (upper=False) or high end;
    +-inf where no finite gap does (the scale is not shown positive at that level)."""
    return invert(lambda g: margin_contrast(mix, ref, rand, g), point, level, upper)


def invert(contrast_at: Callable[[float], trimmed.Contrast], point: float, level: float, upper: bool) -> float:
    """The gap g at which the one-sided test of contrast_at(g) at `level` stops rejecting, searched outwards from the
    point estimate: the interval's low (upper=False) or high end (the test inverted, as Fieller's interval);
    +-inf where no finite gap does."""

    def rejects(g: float) -> bool:
        c = contrast_at(g)
        return (trimmed.p_below(c) if upper else trimmed.p_above(c)) < level

    inside, step = point, max(abs(point), 1.0) * 0.5
    outside = inside + (step if upper else -step)
    while not rejects(outside):  # walk outwards until the test rejects
        inside, outside, step = outside, outside + (step if upper else -step), step * 2.0
        if abs(outside) > 1e6:
            return math.inf if upper else -math.inf
    for _ in range(40):  # then bisect between the last accepted and the first rejected gap
        mid = 0.5 * (inside + outside)
        inside, outside = (inside, mid) if rejects(mid) else (mid, outside)
    return float(0.5 * (inside + outside))


def shrinking_variance(c: trimmed.Contrast, n: int, fixed_var: float) -> float:
    """One seed's variance of the part of the contrast's squared standard error at n seeds that more seeds shrink
    (all of it less fixed_var: fixed_variance)."""
    return max(c.se * c.se - fixed_var, 0.0) * n


def seeds_for_power(c: trimmed.Contrast, n: int, distance: float, level: float, fixed_var: float = 0.0) -> int | None:
    """Seeds per cell for POWER at a true distance (in score units) of the contrast from 0 (a normal approximation at
    the one-sided `level`): the contrast's squared standard error at n seeds less fixed_var (the part more seeds do
    not shrink: fixed_variance) shrinks as 1/seeds. None where no finite number would do: a distance of 0, no finite
    error, or a fixed part alone too large for that power."""
    from scipy import stats

    if distance <= 0 or not math.isfinite(c.se):
        return None
    z = stats.norm.isf(level) + stats.norm.isf(1.0 - POWER)
    per_seed = shrinking_variance(c, n, fixed_var)
    room = (distance / z) ** 2 - fixed_var  # what the shrinking part's variance may be at the seeds sought
    if room <= 0:
        return None
    return max(n, int(math.ceil(per_seed / room)))


def chance_to_decide(c: trimmed.Contrast, n: int, cap: int, level: float, fixed_var: float = 0.0) -> float | None:
    """The chance that the contrast's test at `cap` seeds per cell rejects either way at the one-sided `level`, given
    its estimate and standard error at `n` seeds and a true contrast equal to the estimate (conditional power under
    the current trend; Lachin 2005). fixed_var: the part of the squared standard error that more seeds do not
    shrink (the random policy's episodes, a published reference's error); the rest shrinks as 1/n. A normal
    approximation at the last look only (Yuen's t there and a decision at a look between both make the true chance
    a little smaller and larger). None where it cannot be said (no finite error, or no seeds to add)."""
    from scipy import stats

    if cap <= n or not math.isfinite(c.se) or c.se <= 0:
        return None
    per_seed = shrinking_variance(c, n, fixed_var)
    edge = stats.norm.isf(level) * math.sqrt(per_seed / cap + fixed_var)  # |estimate at the cap| the test rejects beyond
    spread = math.sqrt(per_seed * (cap - n)) / cap  # of the estimate at the cap given the estimate now
    if spread == 0.0:
        return float(abs(c.estimate) > edge)
    return float(stats.norm.sf((edge - c.estimate) / spread) + stats.norm.cdf((-edge - c.estimate) / spread))


def fixed_variance(ref: trimmed.Summary, rand: trimmed.Summary, margin: float, ref_fixed: bool) -> float:
    """The part of margin_contrast's squared standard error that more seeds do not shrink: the random policy's (its
    episodes are measured once) and, for a fixed reference (a published score: ref_fixed), the reference's."""
    return margin * margin * rand.var + ((1.0 - margin) ** 2 * ref.var if ref_fixed else 0.0)


def failure_share_p(mixture: Sequence[float], reference: Sequence[float], rand: trimmed.Summary,
                    ref: trimmed.Summary) -> float:
    """p-value of 'the mixture's seeds fail more often than flat PPO's by SHARE_MARGIN or more' (shares.share_p): a
    seed fails below R + FAIL_GAIN (IQM(flat PPO) - R)."""
    bar = rand.mean + FAIL_GAIN * (ref.mean - rand.mean)
    mine, theirs = shares.share_of(mixture, bar), shares.share_of(reference, bar)
    return shares.share_p(mine.reached, mine.seeds, theirs.reached, theirs.seeds, SHARE_MARGIN)


def judge(mixture: Sequence[float], reference: "Sequence[float] | trimmed.Summary", random_returns: "Sequence[float] | float",
          margin: float = DEFAULT_MARGIN, level: float = ALPHA,
          final_level: float | None = None, final_seeds: int | None = None) -> Gap:
    """The verdict of one mixture cell (scores [n]) against `reference` (flat PPO's scores [n_f] or a trimmed.Summary)
    with the random policy's episode returns [n_r] (or one exact number), at `margin` and the look's one-sided
    `level`; the power estimates aim at `final_level` (the design's last look; default `level`), and an undecided
    cell's chance_by_cap at `final_seeds` (the seed cap; None: not computed)."""
    if not 0.0 < margin < 1.0:
        raise ValueError(f"the margin must be in (0, 1), got {margin}")
    mix, ref, rand = trimmed.trimmed(mixture), summarize_reference(reference), summarize_random(random_returns)
    n, n_ref = len(mixture), ref.n
    if not gain_shown(ref, rand):
        return Gap(math.nan, math.nan, math.nan, NO_SCALE, margin, level, n, n_ref, math.nan, math.nan, None, None)
    scale = ref.mean - rand.mean
    point = (mix.mean - ref.mean) / scale
    c = margin_contrast(mix, ref, rand, -margin)
    p_s, p_i = trimmed.p_above(c), trimmed.p_below(c)
    fixed_ref = isinstance(reference, trimmed.Summary)
    p_share = math.nan if fixed_ref else failure_share_p(mixture, reference, rand, ref)
    shown = p_s < level and (fixed_ref or p_share < level)
    verdict = SUFFICIENT if shown else INSUFFICIENT if p_i < level else UNDECIDED
    low, high = bound(mix, ref, rand, point, level, False), bound(mix, ref, rand, point, level, True)
    final = level if final_level is None else final_level
    fixed = fixed_variance(ref, rand, margin, fixed_ref)
    parity = seeds_for_power(c, n, margin * scale, final, fixed)
    observed = seeds_for_power(c, n, abs(point + margin) * scale, final, fixed)
    chance = None
    if final_seeds is not None and verdict == UNDECIDED:
        chance = chance_to_decide(c, n, final_seeds, final, fixed)
    return Gap(point, low, high, verdict, margin, level, n, n_ref, p_s, p_i, parity, observed, chance, p_share)


def smallest_sufficient(verdicts: dict) -> tuple:
    """(smallest sufficient K or None, [undecided K below it]) of {K: verdict}."""
    ks = sorted(verdicts)
    chosen = next((k for k in ks if verdicts[k] == SUFFICIENT), None)
    below = [k for k in ks if (chosen is None or k < chosen) and verdicts[k] == UNDECIDED]
    return chosen, below


def sentence(task: str, verdicts: dict, margin: float, versus: str) -> str:
    """The answer in one sentence from {K: verdict} at `margin` (versus: 'flat PPO', 'the target score S', ...)."""
    chosen, below = smallest_sufficient(verdicts)
    pct = f"{margin:.0%}"
    if verdicts and all(v == NO_SCALE for v in verdicts.values()):
        return (f"{task}: no answer: {versus} is not shown to score above a random policy, so no margin can be set.")
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
