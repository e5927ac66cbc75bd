"""A sweep's runs as trained runs: their addresses, every finished run's controller, the results to commit.

    python -m gsa_jax.extract SWEEP_DIR --list      # the finished runs' addresses, SWEEP_DIR/<run label>:
                                                    # every single-run tool reads them as it reads a run
                                                    # directory (inspect, export, deploy, render --run)
    python -m gsa_jax.extract SWEEP_DIR --controllers DIR   # every finished run's deterministic controller,
                                                            # DIR/<run label>.npz (gsa_jax.export's npz)
    python -m gsa_jax.extract SWEEP_DIR --results DIR       # what a finished sweep's results commit holds: sweep.json,
                                                            # tidy metrics gzipped, failed runs, every controller
                                                            # (no training state); gsa_jax.plot DIR reads it
"""

import argparse
import os
import sys

from gsa_jax.analysis.extraction import ExtractError, collect_results, export_controllers, sweep_runs
from gsa_jax.running.runinfo import cli_description


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.extract", description=cli_description(__doc__))
    p.add_argument("sweep_dir")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--list", action="store_true", help="list the finished runs' addresses (SWEEP_DIR/<run label>)")
    what.add_argument("--controllers", metavar="DIR", default=None,
                      help="write every finished run's deterministic controller (exported npz) to DIR")
    what.add_argument("--results", metavar="DIR", default=None,
                      help="copy the sweep's results (sweep.json, tidy metrics gzipped, failed runs, controllers) to DIR")
    args = p.parse_args(argv)
    try:
        if args.results:
            paths = collect_results(args.sweep_dir, args.results)
            print(f"wrote {len(paths)} files to {args.results} (gsa_jax.plot {args.results} draws its figures)")
        elif args.controllers:
            paths = export_controllers(args.sweep_dir, args.controllers)
            print(f"wrote {len(paths)} controllers to {args.controllers}")
        else:
            for label, _, _, row in sweep_runs(args.sweep_dir):
                print(os.path.join(args.sweep_dir, label) + "   " + " ".join(f"{c}={v}" for c, v in row.items() if c != "run"))
    except ExtractError as e:
        print(f"gsa_jax.extract: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
