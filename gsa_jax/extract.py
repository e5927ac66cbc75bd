"""Take one finished run out of a sweep as a run directory (config.json + params.npz), so that the
single-run tools work on it (inspect, export, deploy, gsa_jax.render --run):

    python -m gsa_jax.extract runs/sweeps/fig1_idp_hopper --env hopper --policy mixture --clusters 6 --seed 0 --out runs/hopper-K6-s0
    python -m gsa_jax.extract SWEEP_DIR --list      # the finished runs it holds
    python -m gsa_jax.extract SWEEP_DIR --controllers DIR   # every finished run's deterministic controller,
                                                            # DIR/<env>-<policy>[-K<k>]-s<seed>.npz (gsa_jax.export's npz)
    python -m gsa_jax.extract SWEEP_DIR --results DIR       # what a finished sweep's results commit holds: sweep.json,
                                                            # tidy metrics gzipped, failed runs, every controller
                                                            # (no training state); gsa_jax.plot DIR reads it

Swept hyperparameters, sub-policy classes and critics select with --hparam NAME=VALUE, --subpolicy and
--value-target.
"""

import argparse
import sys

from gsa_jax.analysis.extraction import ExtractError, collect_results, export_controllers, extract, finished_runs, select


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.extract", description=__doc__.split("\n")[0])
    p.add_argument("sweep_dir")
    p.add_argument("--list", action="store_true", help="list the finished runs")
    p.add_argument("--env")
    p.add_argument("--policy", default="mixture")
    p.add_argument("--clusters", "-K", type=int, default=None)
    p.add_argument("--subpolicy", default=None)
    p.add_argument("--value-target", default=None, help="gae or retrace, in a sweep that lists value_targets")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hparam", action="append", default=[], metavar="NAME=VALUE", help="a swept hyperparameter's value")
    p.add_argument("--out", default=None)
    p.add_argument("--controllers", metavar="DIR", default=None,
                   help="write every finished run's deterministic controller (exported npz) to DIR")
    p.add_argument("--results", metavar="DIR", default=None,
                   help="copy the sweep's results (sweep.json, tidy metrics gzipped, failed runs, controllers) to DIR")
    args = p.parse_args(argv)
    try:
        if args.results:
            paths = collect_results(args.sweep_dir, args.results)
            print(f"wrote {len(paths)} files to {args.results} (gsa_jax.plot {args.results} draws its figures)")
            return 0
        if args.controllers:
            paths = export_controllers(args.sweep_dir, args.controllers)
            print(f"wrote {len(paths)} controllers to {args.controllers}")
            return 0
        runs = finished_runs(args.sweep_dir)
        if args.list:
            for gdir, i, row in runs:
                print(" ".join(f"{c}={v}" for c, v in row.items() if c != "run"))
            return 0
        if not args.env or not args.out:
            raise ExtractError("--env and --out are required (or --list)")
        if args.policy == "mixture" and args.clusters is None:
            raise ExtractError("--clusters is required for a mixture run")
        hps = []
        for item in args.hparam:
            if "=" not in item:
                raise ExtractError(f"--hparam takes NAME=VALUE, got {item!r}")
            hps.append(tuple(item.split("=", 1)))
        gdir, i, row = select(runs, args.env, args.policy, args.clusters, args.seed, args.subpolicy, hps, args.value_target)
        out = extract(args.sweep_dir, gdir, i, row, args.out)
    except ExtractError as e:
        print(f"gsa_jax.extract: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({', '.join(f'{c}={v}' for c, v in row.items() if c != 'run')})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
