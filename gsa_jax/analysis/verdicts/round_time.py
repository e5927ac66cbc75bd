"""How long the answer's sweeps will take, from what its earlier sweeps took, and the least time of its first round.

Every sweep of an answer records its wall seconds (training, compiling or loading its program, exporting and scoring
its controllers), its program's compile or load seconds (the slowest worker's), its policy class, its runs (padded:
every sweep of a class runs the same program) and its step budget. A sweep is estimated as the fixed seconds of the
last sweep of its class (else of the answer's first sweep, which compiled) plus an overhead and its runs x steps at a
rate: the line through the last two sweeps of its class (else of any class) of different work, else through the
origin and the last one. Before any sweep, only a floor is known:
scoring the first round's controllers alone (10 episodes each in MuJoCo C, timed on the random policy's episodes).
"""

from typing import Sequence

from gsa_jax.analysis.sweeps import controller_scores


def fixed_seconds(sweep: dict) -> float:
    """A sweep's seconds that do not grow with its runs x steps: its program's compile or load."""
    return min(float(sweep.get("compile_wall_s", 0.0)), float(sweep["seconds"]))


def work(sweep: dict) -> int:
    """A sweep's trained run-steps (its padded runs x its steps)."""
    return max(int(sweep["runs"]) * int(sweep["steps"]), 1)


def line(sweeps: Sequence[dict]) -> tuple:
    """(overhead seconds, seconds per run-step) of sweeps' seconds beyond their fixed seconds: the line through the last
    two of different work (process start, exporting and scoring are the overhead), else through the origin and the
    last one."""
    last = sweeps[-1]
    other = next((s for s in reversed(sweeps[:-1]) if work(s) != work(last)), None)
    y1 = float(last["seconds"]) - fixed_seconds(last)
    if other is not None:
        y0 = float(other["seconds"]) - fixed_seconds(other)
        rate = (y1 - y0) / (work(last) - work(other))
        overhead = y1 - rate * work(last)
        if rate > 0 and overhead >= 0:
            return overhead, rate
    return 0.0, max(y1, 0.0) / work(last)


def sweep_estimate(history: Sequence[dict], policy: str, runs: int, steps: int) -> float | None:
    """Seconds a sweep of `runs` runs (padded) x `steps` steps of class `policy` will take, from the answer's earlier
    sweeps (each: policy, runs, steps, seconds, compile_wall_s) in the order they ran; None before any."""
    if not history:
        return None
    mine = [h for h in history if h["policy"] == policy]
    overhead, rate = line(mine or history)
    return fixed_seconds(mine[-1] if mine else history[0]) + overhead + rate * runs * steps


def scoring_floor(random_record: dict, controllers: int, workers: int = 1) -> float | None:
    """Seconds that scoring `controllers` controllers takes at least (controller_scores.EPISODES episodes each, at the
    random policy's measured seconds per episode, which end no later than a trained controller's), spread over
    `workers` processes; None where the random policy was not timed."""
    seconds = random_record.get("seconds")
    if not seconds:
        return None
    per_episode = float(seconds) / max(int(random_record["episodes"]), 1)
    return per_episode * controller_scores.EPISODES * controllers / max(workers, 1)
