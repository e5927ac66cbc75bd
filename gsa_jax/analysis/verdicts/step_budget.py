"""The step budget of an answer: train only as long as flat PPO still learns.

`gsa answer` (with --steps auto, its default) trains flat PPO's first-look seeds at doubling budgets
(candidates: the cap --max-steps halved four times, then doubled: 1M -> 62.5k, 125k, 250k, 500k, 1M, each the nearest
whole number of chunks of flat PPO's program, the cap rounded up) and stops at the first budget at which flat PPO

- has learned the task: its gain over the random policy is shown positive (verdict.gain_shown) and, where the task
  declares a maximum return, it reaches baseline.LEARNED of the way to it (baseline.learned); and
- has stopped learning: the verdict's own still-learning test (baseline.learning: the last fifth's gain shown below the
  margin) passes at that budget.

Every class then trains to that budget (equal steps), and the runs trained at it are flat PPO's first look. Each
candidate budget is a run of its own (the learning rate anneals over the run's budget), so the test reads curves of runs
that trained exactly to the budget it judges. At the cap the budget is the cap whatever the test says: the baseline
check then reports flat PPO as still learning.
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
                 margin: float, max_return: float | None) -> dict:
    """Whether flat PPO's runs trained to `steps` have learned the task and stopped learning. scores: their controller
    scores [n]; curves: [(env_steps [T], eval_return [T])] per run; random_returns: the random policy's episodes [n_r].
    -> {"steps", "learned", "why", "learning": {...}, "stopped", "enough"} (enough: both hold)."""
    rand = verdict.summarize_random(random_returns)
    iqm = stats.iqm(list(scores)) if len(scores) else float("nan")
    shown = len(scores) >= 2 and verdict.gain_shown(trimmed.trimmed(list(scores)), rand)
    ok, why = baseline.learned(list(scores), rand, max_return)
    if not shown:
        ok, why = False, f"flat PPO's gain over the random policy is not shown positive (IQM {iqm:.1f}, random {rand.mean:.1f})"
    learn = baseline.learning(curves, steps, iqm - rand.mean, margin)
    record = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in learn._asdict().items()}
    return {"steps": int(steps), "learned": bool(ok), "why": why, "learning": record, "stopped": bool(learn.stopped),
            "enough": bool(ok and learn.stopped)}


def next_budget(judged: Sequence[dict], budgets: Sequence[int]) -> tuple:
    """(the chosen budget or None, the next budget to try or None) after the judged candidates (in order): the first
    one judged enough, else the cap once it is judged, else the next candidate."""
    for record in judged:
        if record["enough"]:
            return int(record["steps"]), None
    if judged and int(judged[-1]["steps"]) >= int(budgets[-1]):
        return int(budgets[-1]), None
    return None, int(budgets[len(judged)])
