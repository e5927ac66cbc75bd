"""The constructive answer: is there a K-piece controller as good as a network, which one, and how often does
training find one?

Per class (flat PPO, each K) the runs of one search (the same seeds x steps) are candidates. Each class's best run on
the selection starts is its *exhibited* controller (exhibit); only its score on the *fresh* starts (a disjoint seed
range, the same starts for every exhibited controller: paired) is reported. The bar is the best flat PPO controller's
fresh score, or a published reference where that is higher. With R the random policy's return and margin delta,

    K suffices by construction   its fresh-start mean shown above R + (1 - delta) (bar - R)   (gap > -delta)

tested on the paired episode differences K_i - (1 - delta) flat_i (Welch's t with the random policy's error; a
published bar enters with its own error, unpaired). Otherwise it is *not found at this search*.

How often training finds one: a seed *reaches* when its controller's fresh-start mean is at least the threshold
R + (1 - delta) (bar - R). Per class the share of seeds that reach, with its exact (Clopper-Pearson) interval, and a
test of each K's share against flat PPO's: 'found as often, within delta' is shown when the exact unconditional
test (gsa_jax.analysis.verdicts.shares.share_p) rejects share(K) <= share(flat) - delta. A K whose seeds often fail
is not called 'as often' however good its best seed is.

Every claim of the answer (each K's exhibit and each K's share) shares one error rate: Holm's step-down over all of
them at ALPHA (judge). No JAX here: the scores come in as arrays.
"""

import math
from typing import NamedTuple, Sequence

import numpy as np

from gsa_jax.analysis.verdicts import baseline, trimmed, verdict
from gsa_jax.analysis.verdicts.shares import Share, holm, share_of, share_p

ALPHA = verdict.ALPHA  # one-sided: the chance that any claim of the answer is wrong
FOUND, NOT_FOUND, NO_SCALE = "suffices by construction", "not found at this search", "no answer"
NOT_LEARNED = "no answer: the bar has not learned the task"
LEARNED = 0.1  # where a task declares its maximum return, the bar must not be shown below this share of the way to it
AS_OFTEN, NOT_SHOWN = "as often", "not shown as often"


class Candidate(NamedTuple):
    """One run of a class: its seed, its controller's mean return on the selection starts, and its returns on the
    fresh starts [n] (episode i from fresh seed + i)."""

    seed: int
    selection: float
    fresh: np.ndarray


class Bar(NamedTuple):
    """What a K is compared with: its name, its value's Summary, and its fresh-start episodes [n] where it is a
    controller (paired with the exhibit's), None for a published score."""

    name: str
    summary: trimmed.Summary
    episodes: "np.ndarray | None"


class Exhibit(NamedTuple):
    """A class's exhibited controller judged against the bar: its seed, selection score, fresh mean, episode std and
    count, the gap (fresh mean - bar) / (bar - R) with its interval at the answer's level, the p-value of 'gap <=
    -margin', and the verdict (FOUND, NOT_FOUND or NO_SCALE)."""

    seed: int
    selection: float
    fresh: float
    fresh_std: float
    episodes: int
    gap: float
    low: float
    high: float
    p: float
    verdict: str


def exhibit(candidates: Sequence[Candidate]) -> Candidate:
    """The class's best run on the selection starts (ties to the lower seed): the controller the answer shows."""
    if not candidates:
        raise ValueError("a class needs at least one run")
    return min(candidates, key=lambda c: (-c.selection, c.seed))


def bar_of(flat: Candidate, reference: "Bar | None") -> Bar:
    """The higher bar: flat PPO's exhibited controller on the fresh starts, or a fixed score (reference) above it."""
    mine = Bar("the best flat PPO controller", trimmed.plain(flat.fresh), np.asarray(flat.fresh, np.float64))
    if reference is not None and reference.summary.mean > mine.summary.mean:
        return reference
    return mine


def published_bar(references: Sequence[dict], task: str, steps: int) -> "Bar | None":
    """The highest entry of a references table that applies to the task at `steps` as a fixed bar (its score with
    its error over its seeds); None where none applies."""
    top = baseline.highest(references, task, steps)
    return None if top is None else Bar(baseline.reference_name(top), baseline.reference_summary(top), None)


def gap_contrast(returns: np.ndarray, bar: Bar, rand: trimmed.Summary, gap: float) -> trimmed.Contrast:
    """mean(K) - (1 + gap) bar + gap R: positive exactly when K's gap is above `gap`; paired over the common fresh
    starts where the bar is a controller."""
    if bar.episodes is None:
        return trimmed.contrast([(1.0, trimmed.plain(returns)), (-(1.0 + gap), bar.summary), (gap, rand)])
    n = min(len(returns), len(bar.episodes))
    diff = np.asarray(returns[:n], np.float64) - (1.0 + gap) * bar.episodes[:n]
    return trimmed.contrast([(1.0, trimmed.plain(diff)), (gap, rand)])


def judge_exhibit(shown: Candidate, bar: Bar, rand: trimmed.Summary, margin: float, level: float) -> Exhibit:
    """One exhibited controller against the bar; the verdict is FOUND where 'gap <= -margin' is rejected at `level`
    (judge sets it after Holm's step-down)."""
    fresh = np.asarray(shown.fresh, np.float64)
    std = float(fresh.std(ddof=1)) if len(fresh) > 1 else 0.0
    base = (shown.seed, shown.selection, float(fresh.mean()), std, len(fresh))
    if not verdict.gain_shown(bar.summary, rand):
        return Exhibit(*base, math.nan, math.nan, math.nan, math.nan, NO_SCALE)
    point = (float(fresh.mean()) - bar.summary.mean) / (bar.summary.mean - rand.mean)
    p = trimmed.p_above(gap_contrast(fresh, bar, rand, -margin))
    low = verdict.invert(lambda g: gap_contrast(fresh, bar, rand, g), point, level, False)
    high = verdict.invert(lambda g: gap_contrast(fresh, bar, rand, g), point, level, True)
    return Exhibit(*base, point, low, high, p, FOUND if p < level else NOT_FOUND)


def threshold(bar: Bar, rand: trimmed.Summary, margin: float) -> float:
    """The score a seed's controller must reach: R + (1 - margin) (bar - R)."""
    return float(rand.mean + (1.0 - margin) * (bar.summary.mean - rand.mean))


def bar_learned(bar: Bar, rand: trimmed.Summary, max_return: "float | None", level: float) -> bool:
    """Whether the bar counts as having learned the task: where the task declares its maximum return, the bar is not
    shown below LEARNED of the way from the random return to it (one-sided at `level`; its episodes' mean, or the
    published score with its error). Being as good as a controller that has not learned the task says nothing."""
    if max_return is None:
        return True
    summary = trimmed.plain(bar.episodes) if bar.episodes is not None else bar.summary
    c = trimmed.contrast([(1.0, summary), (-(1.0 - LEARNED), rand)])
    return not trimmed.p_below(trimmed.Contrast(c.estimate - LEARNED * max_return, c.se, c.df)) < level


class Answer(NamedTuple):
    """The constructive answer at one margin: the bar (Bar), the random return's Summary, the threshold a seed must
    reach, per class (FLAT and each K) its Exhibit and Share, per K its share test's p-value and verdict (AS_OFTEN or
    NOT_SHOWN), the smallest K found (None: not found) and the margin."""

    bar: Bar
    random: trimmed.Summary
    threshold: float
    exhibits: dict
    shares: dict
    share_p: dict
    share_verdicts: dict
    smallest: "int | None"
    margin: float


def seed_scores(candidates: Sequence[Candidate], episodes: "int | None") -> np.ndarray:
    """Each run's fresh-start mean over its first `episodes` fresh starts (all where None) [runs]."""
    return np.array([float(np.mean(np.asarray(c.fresh, np.float64)[:episodes])) for c in candidates])


def judge(classes: dict, random_returns: "Sequence[float] | float", margin: float = verdict.DEFAULT_MARGIN,
          reference: "Bar | None" = None, share_episodes: "int | None" = None, alpha: float = ALPHA, flat_key: str = "flat",
          max_return: "float | None" = None) -> Answer:
    """The constructive answer from {flat_key: [Candidate], K: [Candidate], ...} and the random policy's returns
    [n_r] (or one exact number): every exhibit and every share test under one Holm step-down at alpha. Shares count
    each run's mean over its first share_episodes fresh starts (all where None); max_return: the task's declared
    maximum (bar_learned), None where it declares none."""
    if not 0.0 < margin < 1.0:
        raise ValueError(f"the margin must be in (0, 1), got {margin}")
    ks = sorted(k for k in classes if k != flat_key)
    rand = verdict.summarize_random(random_returns)
    if flat_key in classes:
        bar = bar_of(exhibit(classes[flat_key]), reference)
    elif reference is not None:  # a target alone (no flat PPO trained): the bar, and no share to compare with
        bar = reference
    else:
        raise ValueError("the constructive answer needs flat PPO's runs or a reference score")
    judged = ([flat_key] if flat_key in classes else []) + ks
    exhibits = {c: judge_exhibit(exhibit(classes[c]), bar, rand, margin, alpha) for c in judged}
    bar_score = threshold(bar, rand, margin)
    shares = {c: share_of(seed_scores(classes[c], share_episodes), bar_score, alpha) for c in judged}
    if not verdict.gain_shown(bar.summary, rand):
        return Answer(bar, rand, bar_score, exhibits, shares, {}, {}, None, margin)
    if not bar_learned(bar, rand, max_return, alpha):
        exhibits = {c: e._replace(verdict=NOT_LEARNED) for c, e in exhibits.items()}
        return Answer(bar, rand, bar_score, exhibits, shares, {}, {}, None, margin)
    ref = shares.get(flat_key)
    share_ps = {} if ref is None else {k: share_p(shares[k].reached, shares[k].seeds, ref.reached, ref.seeds, margin)
                                       for k in ks}
    shown = holm({**{("exhibit", k): exhibits[k].p for k in ks}, **{("share", k): p for k, p in share_ps.items()}}, alpha)
    exhibits = {c: e._replace(verdict=FOUND if c == flat_key or ("exhibit", c) in shown else NOT_FOUND)
                for c, e in exhibits.items()}
    share_verdicts = {k: AS_OFTEN if ("share", k) in shown else NOT_SHOWN for k in share_ps}
    smallest = next((k for k in ks if exhibits[k].verdict == FOUND), None)
    return Answer(bar, rand, bar_score, exhibits, shares, share_ps, share_verdicts, smallest, margin)


def share_words(s: Share) -> str:
    """'9 of 10 seeds (0.90 [0.55, 1.00])'."""
    return f"{s.reached} of {s.seeds} seeds ({s.share:.2f} [{s.low:.2f}, {s.high:.2f}])"


def sentence(task: str, answer: Answer, search: str, flat_key: str = "flat") -> str:
    """The constructive answer in one sentence (search: the seeds x steps every class trained, in words)."""
    ks = sorted(k for k in answer.exhibits if k != flat_key)
    pct = f"{answer.margin:.0%}"
    if any(e.verdict == NO_SCALE for e in answer.exhibits.values()):
        return (f"{task}: no constructive answer: {answer.bar.name} is not shown to score above a random policy, "
                f"so no margin can be set.")
    if any(e.verdict == NOT_LEARNED for e in answer.exhibits.values()):
        return (f"{task}: no constructive answer: {answer.bar.name} ({answer.bar.summary.mean:.1f}) is shown below "
                f"{LEARNED:.0%} of the way from the random policy ({answer.random.mean:.1f}) to the task's maximum "
                f"at this search ({search}): it has not learned the task.")
    if answer.smallest is None:
        best = max(ks, key=lambda k: answer.exhibits[k].gap)
        e = answer.exhibits[best]
        return (f"{task}: no K of {ks} is found within {pct} of {answer.bar.name} at this search ({search}); the "
                f"closest, K = {best} (seed {e.seed}), has gap {e.gap:+.3f} [{e.low:+.3f}, {e.high:+.3f}] on "
                f"{e.episodes} fresh starts.")
    k, e = answer.smallest, answer.exhibits[answer.smallest]
    head = (f"{task}: K = {k} suffices by construction: its best seed ({e.seed}) scores {e.fresh:.1f} on {e.episodes} "
            f"fresh starts, within {pct} of {answer.bar.name} ({answer.bar.summary.mean:.1f}) found with the same "
            f"search ({search}; gap {e.gap:+.3f} [{e.low:+.3f}, {e.high:+.3f}]); training finds one on "
            f"{share_words(answer.shares[k])}")
    if k not in answer.share_verdicts:
        return head + "."
    often = ("as often as flat PPO (within the margin)" if answer.share_verdicts[k] == AS_OFTEN
             else "not shown as often as flat PPO")
    return f"{head}, {often}; flat PPO on {share_words(answer.shares[flat_key])}."
