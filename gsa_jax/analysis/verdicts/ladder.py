"""Every K of an answer judged at the design's looks with Holm's shares (gsa_jax.analysis.verdicts.sequential), so that "K* is
the smallest sufficient K" is wrong at most ALPHA of the time over all K and all looks.

A cell is judged when its seeds reach a look: with the first `look` seeds of the cell (in seed order) against as many
of the reference's (flat PPO has as many at that look). A decided cell is frozen at that look; an undecided one keeps its last look's p-values,
which are compared again with a higher level when another K is shown sufficient (Holm passes that K's share on). The
same function judges a fixed grid (gsa_jax.plot's tables: the look its seed count reaches) and every round of
gsa_jax.answer, so an answer continued from a committed table (--start-from) is one design from its first look.
"""

import math
from typing import Sequence

from gsa_jax.analysis.verdicts import sequential, trimmed, verdict

DECIDED = (verdict.SUFFICIENT, verdict.INSUFFICIENT)


def first_seeds(scores: dict, n: int) -> list:
    """The scores of a cell's first n seeds (in seed order) from {seed: score}."""
    return [scores[s] for s in sorted(scores)[:n]]


def judged_record(g: verdict.Gap, look: int, design: sequential.Design, share: float) -> dict:
    """A cell's record (what answer.json and the tables keep) from its Gap at `look` with Holm share `share`."""
    return {"verdict": g.verdict, "look": look, "seeds": g.n, "reference_seeds": g.n_ref, "gap": g.point,
            "low": g.low, "high": g.high, "level": g.level, "share": share, "p_sufficient": g.p_sufficient,
            "p_insufficient": g.p_insufficient, "p_share": None if math.isnan(g.p_share) else g.p_share,
            "seeds_parity": g.seeds_parity, "seeds_observed": g.seeds_observed,
            "chance_by_cap": g.chance_by_cap, "looks": list(design.looks)}


def judge_cell(scores: dict, reference: "Sequence[float] | trimmed.Summary", random_returns: "Sequence[float] | float", margin: float, design: sequential.Design, look: int,
               share: float) -> dict:
    """One cell ({seed: score}) judged at design look `look` with one-sided share `share` of the answer's error: its
    first looks[look] seeds against the reference's first looks[look] (flat PPO had as many then), or a fixed score."""
    levels = sequential.look_levels(design, share)
    n = design.looks[look]
    ref = reference if isinstance(reference, trimmed.Summary) else list(reference)[:n]
    g = verdict.judge(first_seeds(scores, n), ref, random_returns, margin, levels[look], final_level=levels[-1],
                      final_seeds=design.looks[-1])
    return judged_record(g, look, design, share)


def looks_due(ladder: Sequence[int], scores: dict, design: sequential.Design, history: dict) -> dict:
    """{K: [looks]} of the cells whose seeds reached looks they were not judged at, in order (decided cells stay
    frozen; a cell given many seeds at once, as --start-from may, is judged at every look on the way)."""
    due = {}
    for k in ladder:
        past = history.get(str(k))
        look = sequential.look_index(design, len(scores.get(k, {})))
        if look is None or (past and past["verdict"] in DECIDED):
            continue
        start = past["look"] + 1 if past and "look" in past else 0
        if start <= look:
            due[k] = list(range(start, look + 1))
    return due


def holm_pass(ladder: Sequence[int], scores: dict, reference: "Sequence[float] | trimmed.Summary",
              random_returns: "Sequence[float] | float", margin: float,
              design: sequential.Design, records: dict) -> None:
    """Holm's step-down: while another K is shown sufficient, every undecided K is compared again at its look with
    the larger share (in place)."""
    changed = True
    while changed:
        changed = False
        shown = sum(r["verdict"] == verdict.SUFFICIENT for r in records.values())
        share = sequential.holm_share(design, len(ladder), shown)
        for key, r in records.items():
            if r["verdict"] == verdict.UNDECIDED and "look" in r and share > r["share"] + 1e-15:
                records[key] = judge_cell(scores[int(key)], reference, random_returns, margin, design, r["look"], share)
                changed = changed or records[key]["verdict"] == verdict.SUFFICIENT


def judge_ladder(ladder: Sequence[int], scores: dict, reference: "Sequence[float] | trimmed.Summary",
                 random_returns: "Sequence[float] | float", margin: float,
                 design: sequential.Design, history: dict | None = None) -> dict:
    """{str(K): record} of every K with seeds at a look: look by look, the cells that reached it judged there, then
    Holm's step-down. scores: {K: {seed: score}}; reference: flat PPO's scores in seed order or a trimmed.Summary;
    history: the previous call's records (None: none)."""
    records = {k: dict(r) for k, r in (history or {}).items()}
    due = looks_due(ladder, scores, design, records)
    for look in sorted({j for js in due.values() for j in js}):
        for k in [k for k, js in due.items() if look in js]:
            if records.get(str(k), {}).get("verdict") in DECIDED:
                continue
            shown = sum(r["verdict"] == verdict.SUFFICIENT for r in records.values())
            records[str(k)] = judge_cell(scores[k], reference, random_returns, margin, design, look,
                                         sequential.holm_share(design, len(ladder), shown))
        if any(r["verdict"] == verdict.NO_SCALE for r in records.values()):
            return records
        holm_pass(ladder, scores, reference, random_returns, margin, design, records)
    return records
