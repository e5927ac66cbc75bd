"""The step budget of an answer: train only as long as flat PPO still learns.

`gsa answer` (with --steps auto, its default) trains flat PPO's first-look seeds at doubling budgets
(candidates: the cap --max-steps halved four times, then doubled: 1M -> 62.5k, 125k, 250k, 500k, 1M, each the nearest
whole number of chunks of flat PPO's program, the cap rounded up) and stops at the first budget at which flat PPO

- has learned the task: its gain over the random policy is shown positive (verdict.gain_shown) and, where the task
  declares a maximum return, it reaches baseline.LEARNED of the way to it (baseline.learned); and
- has stopped learning, by either of two tests of its two sides: the verdict's own still-learning test passes at that
  budget (baseline.learning: the last fifth's gain shown inside plus or minus the margin), or its curve is shown not
  falling (the last fifth's lower bound above -margin) and flat PPO's first-look seeds trained to the next candidate
  are shown within the margin of its gain over the random policy above the chosen budget's controllers (confirm's
  `shown_within`: training longer is shown not to help by the margin); and
- is confirmed by its controllers at the next budget: those seeds are not shown above the chosen budget's
  controllers by more than the margin (confirm: a curve that flattens only for a while, or falls and recovers, is
  caught by what training longer gives).

The second test of the rising side reads what a budget is chosen for: with an annealed learning rate a run refines
until its last iteration, so its last fifth can rise in runs that a longer budget does not improve
(dmc:cartpole-balance at 245,760 steps in 7442423's committed calibration: the last fifth +0.14 of the gain, its upper
bound +0.31, while the controllers trained to 491,520 score +0.015 of it more, shown within the margin:
experiments/time_to_answer/results/budget_rejudged.csv). Each test runs at LEARNING_LEVEL; the two test different
things (the last fifth's slope; what the next budget gives), so where neither holds a candidate is called stopped
wrongly at most twice LEARNING_LEVEL, while where only the slope is within the margin and longer training does help,
the curve's path is guarded by the confirmation alone (not shown above: its power, not a level). The rule reads flat
PPO only: a mixture still rising at the budget is reported as such beside its verdict.
"""

from typing import Sequence

from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.verdicts import baseline, trimmed, verdict

HALVINGS = 4  # the smallest candidate is the cap / 2**HALVINGS


def candidates(cap: int, floor: int = 1, quantum: int = 1) -> list:
    """Increasing budgets [env steps]: cap / 2**j for j = HALVINGS .. 0, each rounded to the nearest whole number of
    `quantum` env steps (at least one; the cap rounded up; quantum = a chunk of flat PPO's program, so its runs train exactly the budget
    judged, not the budget rounded up to whole chunks), those at or above `floor` (the smallest budget giving flat PPO
    enough evaluations for the still-learning test); [the cap] if none below it qualifies."""
    q = max(1, int(quantum))

    def snap(steps: float) -> int:
        return max(q, int(round(steps / q)) * q)

    top = max(q, -(-int(cap) // q) * q)  # the cap rounded up, as a run of cap steps trains: never below the floor
    below = sorted({snap(cap / 2 ** j) for j in range(HALVINGS, 0, -1)})
    return [b for b in below if floor <= b < top] + [top]


def judge_budget(steps: int, scores: Sequence[float], curves: Sequence[tuple], random_returns: Sequence[float],
                 margin: float, max_return: float | None, before: dict | None = None) -> dict:
    """Whether flat PPO's runs trained to `steps` have learned the task and stopped learning. scores: their controller
    scores [n]; curves: [(env_steps [T], eval_return [T])] per run; random_returns: the random policy's episodes [n_r];
    before: the previous candidate's record (its confirmation by these controllers is judged where it could be chosen).
    -> {"steps", "learned", "why", "learning": {...}, "stopped" (the curve's two-sided test), "enough" (learned and
    stopped), "candidate" (learned and its curve shown not falling: chosen where the next budget shows it within the
    margin), "scores", "confirms" (None, or confirm's record of `before`)}."""
    rand = verdict.summarize_random(random_returns)
    iqm = stats.iqm(list(scores)) if len(scores) else float("nan")
    shown = len(scores) >= 2 and verdict.gain_shown(trimmed.trimmed(list(scores)), rand)
    ok, why = baseline.learned(list(scores), rand, max_return)
    if not shown:
        ok, why = False, f"flat PPO's gain over the random policy is not shown positive (IQM {iqm:.1f}, random {rand.mean:.1f})"
    learn = baseline.learning(curves, steps, iqm - rand.mean, margin)
    record = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in learn._asdict().items()}
    confirms = (confirm(before["scores"], scores, random_returns, margin)
                if before is not None and candidate(before) and "scores" in before else None)
    return {"steps": int(steps), "learned": bool(ok), "why": why, "learning": record, "stopped": bool(learn.stopped),
            "enough": bool(ok and learn.stopped), "candidate": could_choose(ok, learn.stopped, learn.lower, margin),
            "scores": [float(x) for x in scores], "confirms": confirms}


def could_choose(learned: bool, stopped: bool, lower: float, margin: float) -> bool:
    """Whether a budget can be chosen once the next budget's controllers are read: learned, and its curve stopped or
    shown not falling (the last fifth's lower bound above -margin; a nan bound, no gain to judge, is not)."""
    return bool(learned and (stopped or lower > -margin))


def candidate(record: dict) -> bool:
    """Whether a judged budget can be chosen once the next budget's controllers are read."""
    return bool(record["candidate"])


def confirm(chosen: Sequence[float], later: Sequence[float], random_returns: Sequence[float], margin: float) -> dict:
    """Whether the controllers trained to the next budget (later [n']) confirm the chosen budget's (chosen [n]): their
    IQM is not shown above the chosen IQM by more than `margin` of its gain over the random policy (Yuen's one-sided
    test at baseline.LEARNING_LEVEL, the still-learning test's level). -> {"gain": the later IQM's gain over the chosen
    on that scale, "p": the test's p-value (small: training longer is shown to help), "confirmed", "p_within": the
    opposite one-sided test's p-value (small: the later IQM is shown below the chosen one plus the margin),
    "shown_within": it is below LEARNING_LEVEL}."""
    rand = verdict.summarize_random(random_returns)
    now, then = trimmed.trimmed(list(chosen)), trimmed.trimmed(list(later))
    scale = now.mean - rand.mean
    contrast = verdict.margin_contrast(then, now, rand, margin)
    p, p_within = trimmed.p_above(contrast), trimmed.p_below(contrast)
    gain = (then.mean - now.mean) / scale if scale > 0 else float("nan")
    return {"gain": round(float(gain), 4), "p": float(p), "confirmed": bool(p >= baseline.LEARNING_LEVEL),
            "p_within": float(p_within), "shown_within": bool(scale > 0 and p_within < baseline.LEARNING_LEVEL)}


def next_budget(judged: Sequence[dict], budgets: Sequence[int]) -> tuple:
    """(the chosen budget or None, the next budget to try or None) after the judged candidates (in order): the first
    one chosen by its next candidate (chosen_by; the cap needs none where it is enough), else the cap once it is
    judged, else the next candidate."""
    for i, record in enumerate(judged):
        at_cap = int(record["steps"]) >= int(budgets[-1])
        if (at_cap and record["enough"]) or (i + 1 < len(judged) and chosen_by(record, judged[i + 1])):
            return int(record["steps"]), None
    if judged and int(judged[-1]["steps"]) >= int(budgets[-1]):
        return int(budgets[-1]), None
    return None, int(budgets[len(judged)])


def chosen_by(record: dict, later: dict) -> bool:
    """Whether `record`'s budget is chosen once the next candidate `later` is judged: enough (the curve's two-sided
    test) and confirmed by later's controllers, or a candidate whose later controllers are shown within the margin."""
    confirms = later.get("confirms")
    within = bool(confirms and confirms.get("shown_within"))  # shown within the margin implies not shown above it
    return bool((record["enough"] and confirmed(later)) or (candidate(record) and within))


def confirmed(record: dict) -> bool:
    """Whether a candidate's record confirms the enough budget before it (a record without a confirmation, judged
    after one kept no controller scores, confirms: the curve's test alone decides, as it did for such records)."""
    confirms = record.get("confirms")
    return True if confirms is None else bool(confirms["confirmed"])
