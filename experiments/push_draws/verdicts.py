"""Which paired-push verdicts survive the variation of the push draw? For every committed paired_pushes.csv (the
robustness experiment's nominal-trained controllers and the randomized experiment's randomized-trained ones), each
mixture configuration's P(falls less / loses less than flat PPO) against two 95% intervals: the controllers-only one
(rliable, under the one committed draw of push events) and the one that resamples the push events too
(gsa_jax.analysis.robustness.paired.crossed_interval: columns p_*_events_ci_*). A verdict is "less" where an interval lies
above 0.5, "more" where below, "not shown" otherwise; it survives where both intervals give the same verdict.

    .venv/bin/python experiments/push_draws/verdicts.py

Writes results/verdicts.csv (one row per experiment x task x K x size x window x measure) and
results/verdict_counts.csv (per experiment x window x measure: verdicts shown by the controllers-only interval,
and how many of them survive).
"""

import os

from gsa_jax import read_csv, write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
TASKS = ("Hopper-v5", "HalfCheetah-v5", "InvertedDoublePendulum-v5", "Walker2d-v5", "Ant-v5")
SOURCES = {**{("nominal-trained", t): f"experiments/robustness/results/{t}/paired_pushes.csv" for t in TASKS},
           **{("randomized-trained", t): f"experiments/randomized/results/{t}/robustness/paired_pushes.csv"
              for t in ("Hopper-v5", "Walker2d-v5")}}
MEASURES = {"falls_less": ("p_falls_less_than_flat_ppo", "p_fall"), "loses_less": ("p_loses_less_than_flat_ppo", "p_lost")}


def verdict(low, high):
    """'less' (the interval above 0.5), 'more' (below), else 'not shown'."""
    return "less" if low > 0.5 else "more" if high < 0.5 else "not shown"


def rows_of(experiment, path):
    """One verdicts.csv row per mixture row of a paired_pushes.csv and measure."""
    out = []
    for r in read_csv(os.path.join(ROOT, path)):
        if r["policy"] != "mixture" or r["p_falls_less_than_flat_ppo"] in ("", None):
            continue
        for measure, (col, ci) in MEASURES.items():
            low, high = float(r[f"{ci}_ci_low"]), float(r[f"{ci}_ci_high"])
            elow, ehigh = float(r[f"{ci}_events_ci_low"]), float(r[f"{ci}_events_ci_high"])
            out.append({"experiment": experiment, "env": r["env"], "K": r["K"], "size": r["size"], "window": r["window"],
                        "measure": measure, "p": r[col], "ci_low": low, "ci_high": high, "events_ci_low": elow,
                        "events_ci_high": ehigh, "verdict": verdict(low, high), "verdict_with_events": verdict(elow, ehigh),
                        "survives": int(verdict(low, high) == verdict(elow, ehigh))})
    return out


def counts(rows):
    """Per experiment x window x measure: verdicts shown (controllers-only interval off 0.5), survivors."""
    out = {}
    for r in rows:
        c = out.setdefault((r["experiment"], r["window"], r["measure"]),
                           {"experiment": r["experiment"], "window": r["window"], "measure": r["measure"], "cells": 0,
                            "shown_less": 0, "shown_more": 0, "survive_less": 0, "survive_more": 0,
                            "shown_only_with_events": 0})
        c["cells"] += 1
        if r["verdict"] != "not shown":
            c[f"shown_{r['verdict']}"] += 1
            c[f"survive_{r['verdict']}"] += r["survives"]
        elif r["verdict_with_events"] != "not shown":
            c["shown_only_with_events"] += 1
    return list(out.values())


def main():
    rows = [r for (experiment, _), path in SOURCES.items() for r in rows_of(experiment, path)]
    out = os.path.join(HERE, "results")
    write_csv(os.path.join(out, "verdicts.csv"), rows)
    write_csv(os.path.join(out, "verdict_counts.csv"), counts(rows))
    print(f"wrote {out}/verdicts.csv ({len(rows)} rows), verdict_counts.csv")


if __name__ == "__main__":
    main()
