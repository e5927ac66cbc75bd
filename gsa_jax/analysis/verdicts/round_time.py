"""How long the answer's sweeps will take, from what its earlier sweeps took, and the least time of its first round.

Every sweep of an answer records its wall seconds (training, compiling or loading its program, exporting and scoring
its controllers), its program's compile or load seconds (the slowest worker's), its policy class, its runs (padded:
every sweep of a class runs the same program) and its step budget. A sweep is estimated as the fixed seconds of the
last sweep of its class (else of the answer's first sweep, which compiled) plus its runs x steps at the seconds per
run-step of the last sweep of its class (else of the last sweep of any class). Before any sweep, only a floor is known:
scoring the first round's controllers alone (10 episodes each in MuJoCo C, timed on the random policy's episodes).
"""

from typing import Sequence

from gsa_jax.analysis.sweeps import controller_scores


def fixed_seconds(sweep: dict) -> float:
    """A sweep's seconds that do not grow with its runs x steps: its program's compile or load."""
    return min(float(sweep.get("compile_wall_s", sweep.get("compile_s", 0.0))), float(sweep["seconds"]))


def seconds_per_run_step(sweep: dict) -> float:
    """A sweep's seconds per trained run-step beyond its fixed seconds."""
    work = max(int(sweep["runs"]) * int(sweep["steps"]), 1)
    return max(float(sweep["seconds"]) - fixed_seconds(sweep), 0.0) / work


def sweep_estimate(history: Sequence[dict], policy: str, runs: int, steps: int) -> float | None:
    """Seconds a sweep of `runs` runs (padded) x `steps` steps of class `policy` will take, from the answer's earlier
    sweeps (each: policy, runs, steps, seconds, compile_wall_s) in the order they ran; None before any."""
    if not history:
        return None
    mine = [h for h in history if h["policy"] == policy]
    fixed = fixed_seconds(mine[-1] if mine else history[0])
    rate = seconds_per_run_step(mine[-1] if mine else history[-1])
    return fixed + rate * runs * steps


def scoring_floor(random_record: dict, controllers: int, workers: int = 1) -> float | None:
    """Seconds that scoring `controllers` controllers takes at least (controller_scores.EPISODES episodes each, at the
    random policy's measured seconds per episode, which end no later than a trained controller's), spread over
    `workers` processes; None where the random policy was not timed."""
    seconds = random_record.get("seconds")
    if not seconds:
        return None
    per_episode = float(seconds) / max(int(random_record["episodes"]), 1)
    return per_episode * controller_scores.EPISODES * controllers / max(workers, 1)
