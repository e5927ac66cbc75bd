"""Figures and tables of sweeps: `python -m gsa_jax.plot DIR [DIR ...] [--out OUT]` (a single run's learning
curve: gsa_jax.running.curve).

Merges every tidy metrics.csv under the directories (one per worker process, host, or separately run
sweep: a task's sweep may run on another day or machine; sweeps that hold the same group with other
steps, hyperparameters or settings are refused with the difference). Statistics with rliable
(gsa_jax/analysis/stats.py): a run's final score is the mean deterministic return of its last 3 scheduled
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
import sys

from gsa_jax.analysis import stats
from gsa_jax.analysis.figures import plot_sweep
from gsa_jax.analysis.results import PlotError
from gsa_jax.running.runinfo import cli_description


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.plot", description=cli_description(__doc__))
    p.add_argument("sweep_dirs", nargs="+", metavar="DIR", help="sweep directories (merged)")
    p.add_argument("--out", default=None, help="directory for the figures and tables (default: the first DIR)")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples of the tables' intervals (default %(default)s)")
    p.add_argument("--curve-reps", type=int, default=stats.CURVE_REPS,
                   help="bootstrap resamples of each learning-curve point's band (default %(default)s)")
    args = p.parse_args(argv)
    try:
        if min(args.reps, args.curve_reps) < 1:
            raise PlotError(f"--reps and --curve-reps must be >= 1, got {args.reps} and {args.curve_reps}")
        png, table, rows = plot_sweep(args.sweep_dirs, args.out, reps=args.reps, curve_reps=args.curve_reps)
    except (FileNotFoundError, PlotError) as e:
        print(f"gsa_jax.plot: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {png} and {table}")
    for r in rows:
        print("  " + "  ".join(f"{k}={v}" for k, v in r.items() if v != ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
