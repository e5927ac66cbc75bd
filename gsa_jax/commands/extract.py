"""List a sweep's finished runs, or copy out their controllers or the results to commit.

    gsa extract SWEEP_DIR --list                    # the finished runs' addresses, SWEEP_DIR/<run label>:
                                              # every single-run tool reads them as it reads a run
                                              # directory (inspect, export, deploy, render --run)
    gsa extract SWEEP_DIR --controllers DIR   # every finished run's deterministic controller,
                                              # DIR/<run label>.npz (gsa export's npz)
    gsa extract SWEEP_DIR --results DIR       # what a finished sweep's results commit holds: sweep.json,
                                              # tidy metrics gzipped, failed runs, every controller
                                              # (no training state); gsa plot DIR reads it
"""

import argparse
import os

from gsa_jax.analysis.sweeps.extraction import collect_results, export_controllers, sweep_runs
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    """`gsa extract`'s options."""
    p = command_parser("extract", __doc__)
    p.outputs = ("controllers", "results")
    p.add_argument("sweep_dir", help="a sweep's output directory (gsa sweep --out)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--list", action="store_true", help="list the finished runs' addresses (SWEEP_DIR/<run label>)")
    what.add_argument("--controllers", metavar="DIR", default=None,
                      help="write every finished run's deterministic controller (exported npz) to DIR")
    what.add_argument("--results", metavar="DIR", default=None,
                      help="copy the sweep's results (sweep.json, tidy metrics gzipped, failed runs, controllers) to DIR")
    return p


def extract(argv: list | None) -> int:
    """List the runs, or write their controllers or results."""
    args = build_parser().parse_args(argv)
    if args.results:
        paths = collect_results(args.sweep_dir, args.results)
        print(f"wrote {len(paths)} files to {args.results} (gsa plot {args.results} draws its figures)")
    elif args.controllers:
        paths = export_controllers(args.sweep_dir, args.controllers)
        print(f"wrote {len(paths)} controllers to {args.controllers}")
    else:
        for label, _, _, row in sweep_runs(args.sweep_dir):
            print(os.path.join(args.sweep_dir, label) + "   " + " ".join(f"{c}={v}" for c, v in row.items() if c != "run"))
    return 0


def main(argv: list | None = None) -> int:
    """`gsa extract`: exit status 0, or 2 on bad input."""
    return run_command("extract", lambda: extract(argv))
