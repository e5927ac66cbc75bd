"""The step budget each committed answer's calibration would get under the current rule, without training:
`.venv/bin/python experiments/time_to_answer/rejudge_budget.py`

For every results/*/cold/answer.json whose budget was chosen by calibration (`--steps auto`), each calibration record
is judged again by gsa_jax.analysis.verdicts.step_budget from what it kept (its learning test's bounds, its
controllers' scores) and the budget is chosen as `gsa answer` now chooses it, from the records trained up to it.
Writes results/budget_rejudged.csv: the answer, the budget it chose, the budget the current rule chooses, the
calibration sweeps that needs (and the seconds those took when they ran) and the next budget's confirmation.
"""

import glob
import json
import os

from gsa_jax import write_csv
from gsa_jax.analysis.verdicts import step_budget

HERE = os.path.dirname(os.path.abspath(__file__))


def rejudged(records: list, random_returns: list, margin: float) -> list:
    """The calibration records with 'candidate' and 'confirms' as the current rule sets them (from their kept
    learning bounds and scores; the curve's own test, 'stopped', is what it was)."""
    out = []
    for c in records:
        c = dict(c)
        c["candidate"] = step_budget.could_choose(c["learned"], c["stopped"], c["learning"].get("lower", float("nan")),
                                                  margin)
        before = out[-1] if out else None
        c["confirms"] = (step_budget.confirm(before["scores"], c["scores"], random_returns, margin)
                         if before is not None and step_budget.candidate(before) and "scores" in before else None)
        out.append(c)
    return out


def row(path: str) -> "dict | None":
    with open(path) as f:
        state = json.load(f)
    steps = state.get("steps") or {}
    if (steps.get("mode") != "auto" or "candidates" not in steps
            or not all("scores" in c for c in steps.get("calibration", []))):
        return None
    margin = float(state["setup"]["margin"])
    records = rejudged(steps["calibration"], state["random"]["returns"], margin)
    chosen, n = None, 0
    for n in range(1, len(records) + 1):
        chosen, _ = step_budget.next_budget(records[:n], steps["candidates"])
        if chosen is not None:
            break
    at = next((i for i, c in enumerate(records) if int(c["steps"]) == chosen), None)
    conf = (records[at + 1].get("confirms") or {}) if at is not None and at + 1 < len(records) else {}
    seconds = [c["sweep"].get("seconds", 0.0) for c in steps["calibration"]]
    return {"answer": os.path.relpath(os.path.dirname(path), os.path.join(HERE, "results")),
            "budget_then": steps["budget"], "budget_now": chosen if chosen is not None else "",
            "sweeps_then": len(records), "sweeps_now": n if chosen is not None else "",
            "calibration_s_then": round(sum(seconds), 1), "calibration_s_now": round(sum(seconds[:n]), 1),
            "next_gain": conf.get("gain", ""), "next_p_within": conf.get("p_within", ""),
            "shown_within": conf.get("shown_within", "")}


def main() -> None:
    rows = [r for r in (row(p) for p in sorted(glob.glob(os.path.join(HERE, "results", "*", "cold", "answer.json")))) if r]
    write_csv(os.path.join(HERE, "results", "budget_rejudged.csv"), rows)
    print(f"{len(rows)} answers -> results/budget_rejudged.csv")


if __name__ == "__main__":
    main()
