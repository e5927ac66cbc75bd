"""Exported controllers under shifted physics, observations and actions: from the tidy rows, the CSV files and
figures of the analysis (aggregate.csv, correlation.csv, robustness.png, profile.png, and with paired
pushes paired_pushes.csv, pushes.png, fair.csv); `gsa robustness` is its command. The
evaluation is retention_eval, the statistics retention_stats, the shared row helpers shift_rows."""

import os
from typing import Callable, Sequence

from gsa_jax.analysis.robustness.fairness import fair_rows
from gsa_jax.analysis.robustness.paired import aggregate_pushes, plot_pushes
from gsa_jax.analysis.robustness.retention_plots import plot_robustness
from gsa_jax.analysis.robustness.retention_stats import aggregate, correlations, profile_scores
from gsa_jax.analysis.robustness.shift_rows import controller_key
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.figures import plot_profiles
from gsa_jax.analysis.sweeps.results import task_records, write_csv

EARLY_PUSHES = 300  # env steps: paired_pushes_early.csv's pushes


def analyse(rows: list, sens: list, out: str, reps: int = stats.REPS, log: Callable = print, events: Sequence = (),
            nominal: Sequence = (), windows: Sequence = ()) -> tuple:
    """aggregate.csv, correlation.csv, robustness.png, profile.png from the tidy rows; with the paired
    pushes' events and nominal rows also paired_pushes.csv, pushes.png and fair.csv."""
    agg = aggregate(rows, reps)
    write_csv(os.path.join(out, "aggregate.csv"), agg)
    corr = correlations(sens, rows)
    if corr:
        write_csv(os.path.join(out, "correlation.csv"), corr)
    plot_robustness(agg, os.path.join(out, "robustness.png"))
    scores = profile_scores(rows, {e: t.action_size() for e, t in task_records(r["env"] for r in rows).items()})
    if scores:
        plot_profiles(scores, os.path.join(out, "profile.png"), reps,
                      xlabel="tau: a run's mean retained fraction over the shifts (1 = its nominal score, 0 = random)")
    for c in corr:
        log(f"sensitivity vs retained fraction, {c['env']}: Spearman rho {c['spearman_rho']} (p {c['p_value']}; "
            f"given nominal score {c['partial_rho_given_nominal']}, p {c['partial_p_value']}; {c['controllers']} controllers)")
    if events:
        analyse_pairs(rows, out, reps, events, nominal, windows, log)
    return agg, corr


def analyse_pairs(rows: list, out: str, reps: int, events: Sequence, nominal: Sequence, windows: Sequence,
                  log: Callable) -> None:
    """paired_pushes.csv (and paired_pushes_early.csv: pushes before step EARLY_PUSHES only, where the counted
    pushes of controllers that fall early and of those that do not come from the same part of the episode),
    pushes.png, fair.csv (gsa_jax.analysis.robustness.paired, .fairness), and how far the paired pushes' control
    episodes' scores are from the nominal scores of the shifts' evaluation."""
    pushes = aggregate_pushes(events, windows, reps)
    write_csv(os.path.join(out, "paired_pushes.csv"), pushes)
    early = [r for r in events if int(r["time"]) < EARLY_PUSHES]  # the same pushes where every controller still stands
    write_csv(os.path.join(out, "paired_pushes_early.csv"), aggregate_pushes(early, windows, reps))
    plot_pushes(pushes, os.path.join(out, "pushes.png"))
    write_csv(os.path.join(out, "fair.csv"), fair_rows(rows, nominal, reps))
    held = {controller_key(r): float(r["nominal_score"]) for r in rows if r["shift"] == "nominal"}
    diffs = [abs(float(r["nominal_score"]) - held[controller_key(r)]) for r in nominal if controller_key(r) in held]
    if diffs:
        log(f"paired pushes' control episodes vs the shifts' nominal scores: largest difference {max(diffs):.3g} "
            f"over {len(diffs)} controllers")
