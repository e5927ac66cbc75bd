"""The answer's one progress line while a sweep trains: where the answer is (the step budget's calibration or round
r, sweep i of n), the share of the sweep's iterations done, the runs done of the runs planned, elapsed, what is left
of the round and of the budget. Read from the chunk lines the sweep's worker processes print
(`[process p] [group] it done/total | ...`, gsa_jax.running.driver.progress_line), so every worker's line becomes
one line for the whole answer."""

import re
import time
from typing import Callable, NamedTuple

from gsa_jax.running.driver import duration

CHUNK_LINE = re.compile(r"(?:\[process (\d+)\] )?\[([^\]]+)\] it (\d+)/(\d+) \|")
EVERY_S = 30.0  # seconds between two progress lines (and one as each sweep ends)


class Where(NamedTuple):
    """What a sweep is within the answer: a heading ('round 2, sweep 2 of 2: K=1,2,4 seeds 10-19') and the part of
    the answer it belongs to ('round 2', 'the step budget'), its program's
    parts (its runs over the runs per program), its runs, the runs the round plans and those it has done before this
    sweep, the seconds the answer had used before it, its estimated seconds and those of the round's later sweeps
    (None: no estimate yet), and the answer's budget."""

    heading: str
    scope: str
    parts: int
    runs: int
    round_runs: int
    round_done: int
    elapsed_s: float
    estimate_s: "float | None"
    later_s: "float | None"
    budget_s: float


def share_done(seen: dict, parts: int) -> float:
    """The share of a sweep's iterations done from its chunk lines' latest (done, total) per (group, process): a
    group counts as far as its slowest process, groups not yet seen as 0."""
    groups = {}
    for (group, _), (done, total) in seen.items():
        groups[group] = min(groups.get(group, 1.0), done / max(total, 1))
    return min(1.0, sum(groups.values()) / max(parts, 1))


def line_of(where: Where, share: float, sweep_s: float) -> str:
    """The progress line of a sweep `share` done after `sweep_s` seconds."""
    if share > 0.05:  # its own pace, once it has one; the answer's estimate before
        left = sweep_s * (1 - share) / share
    else:
        left = None if where.estimate_s is None else max(where.estimate_s - sweep_s, 0.0)
    left = None if left is None or where.later_s is None else left + where.later_s
    elapsed = where.elapsed_s + sweep_s
    runs = where.round_done + share * where.runs
    budget = f" | budget left {duration(where.budget_s - elapsed)}" if where.budget_s < float("inf") else ""
    return (f"answer: {where.heading} {share:.0%} | runs {runs:.0f}/{where.round_runs} | elapsed {duration(elapsed)} | "
            f"~{duration(left) if left is not None else '?'} left in {where.scope}{budget}")


def watch(where: Where, log: Callable, clock: Callable = time.monotonic, every_s: float = EVERY_S) -> Callable:
    """A function to hand each line the sweep prints: it logs the answer's progress line at most every `every_s`
    seconds, and once more when called with None (the sweep's end)."""
    seen, start, last = {}, clock(), [-float("inf")]

    def feed(text: "str | None") -> None:
        m = CHUNK_LINE.search(text) if text is not None else None
        if m:
            seen[(m.group(2), m.group(1))] = (int(m.group(3)), int(m.group(4)))
        now = clock()
        if text is None or (m and now - last[0] >= every_s):
            last[0] = now
            log(line_of(where, 1.0 if text is None else share_done(seen, where.parts), now - start))

    return feed
