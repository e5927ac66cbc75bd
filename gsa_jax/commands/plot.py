"""Draw the figures and tables of sweeps (`gsa plot DIR [DIR ...] [--out OUT]`; a single run's learning curve:
gsa_jax.running.curve).

Merges every tidy metrics.csv under the directories (one per worker process, host, or separately run
sweep: a task's sweep may run on another day or machine; sweeps that hold the same group with other
steps, hyperparameters or settings are refused with the difference). Statistics with rliable
(gsa_jax/analysis/sweeps/stats.py): a run's final score is the mean deterministic return of its last 3 scheduled
evaluations (the training return over the last 10% of iterations for sweeps without evaluations); a
failed evaluation episode (non-finite physics) counts up to its last finite step and is counted in
eval_failures. Writes to OUT
(default: the first DIR):
  figure.png               per task, IQM learning curves of the deterministic controllers (95% bootstrap bands)
  figure_training.png      the same for the training return (the stochastic policy)
  return_vs_k.png          final score IQM (95% CI) against K, flat PPO as a band
  performance_profile.png  fraction of runs above each normalized score, per configuration over tasks
  final_returns.csv        per cell: mean (t CI), IQM (bootstrap CI), P(better than flat PPO) (CI), training return,
                           learning speed (curve_*: IQM of each run's mean over all its evaluations), and in
                           sweeps that list value_targets P(Retrace better than GAE) (CI)
  per_run_scores.csv       per run: its final score, last evaluation, failed evaluation episodes, training return
                           (last 10% of iterations, and last 100 episodes: how CleanRL's tables score a run)
  aggregate.csv            per configuration over tasks: IQM of normalized scores (0 = random policy, 1 = flat
                           PPO's final IQM on that task) and P(better than flat PPO), with CIs
  sufficient_k.csv         per task (and sub-policy class / swept setting): the smallest K whose P(better than
                           flat PPO) interval reaches 0.5 ("on par or better"), or none; marked in return_vs_k.png
Runs that stopped at a NaN/inf (sweep.json 'failed_runs') are left out of every statistic and listed apart
(failed_runs), as are runs with no return at one of their last 3 scheduled evaluations (unscored_runs:
only in tables written before failed evaluation episodes were counted).
"""

import argparse

from gsa_jax.analysis.sweep_report import plot_sweep
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import PlotError
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    """`gsa plot`'s options."""
    p = command_parser("plot", __doc__)
    p.add_argument("sweep_dirs", nargs="+", metavar="DIR", help="sweep directories (merged)")
    p.add_argument("--out", default=None, help="directory for the figures and tables (default: the first DIR)")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples of the tables' intervals (default %(default)s)")
    p.add_argument("--curve-reps", type=int, default=stats.CURVE_REPS,
                   help="bootstrap resamples of each learning-curve point's band (default %(default)s)")
    return p


def plot(argv: list | None) -> int:
    """Write the figures and tables and print the table's rows."""
    args = build_parser().parse_args(argv)
    if min(args.reps, args.curve_reps) < 1:
        raise PlotError(f"--reps and --curve-reps must be >= 1, got {args.reps} and {args.curve_reps}")
    try:
        png, table, rows = plot_sweep(args.sweep_dirs, args.out, reps=args.reps, curve_reps=args.curve_reps)
    except FileNotFoundError as e:
        raise PlotError(e) from None
    print(f"wrote {png} and {table}")
    for r in rows:
        print("  " + "  ".join(f"{k}={v}" for k, v in r.items() if v != ""))
    return 0


def main(argv: list | None = None) -> int:
    """`gsa plot`: exit status 0, or 2 on bad input."""
    return run_command("plot", lambda: plot(argv))
