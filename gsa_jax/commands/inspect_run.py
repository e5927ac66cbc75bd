"""Read a trained mixture controller: its clusters and each piece's L and b (`gsa inspect RUN [--episodes 8]
[--out DIR]`, RUN a run directory or SWEEP_DIR/<run label>).

Rolls out the deterministic controller (most probable cluster, mean action) and the stochastic
policy for a few episodes, then writes to DIR (default <run dir>/inspect/, SWEEP_DIR/inspect/<run label>/):
  summary.json        returns (deterministic vs stochastic), cluster usage, clusters ever used,
                      mean dwell time and switches per episode
  clusters_time.png   the active cluster over one episode, above the main state variables
  clusters_pca.png    visited states (PCA of normalized observations) coloured by cluster
  controllers.md      each active cluster's L and b (normalized observation units), with the state
                      variables that drive each actuator most
and, for a linear partition (--partition linear), printed too:
  cells.txt           each cluster's cell as inequalities A s >= d in the task's own units (the observation
                      normalization folded in), one per other cluster; summary.json holds A and d
  cells.png           the cells on the two observations that part them most (the largest spread of the
                      partition's weights over the clusters, per observation std), the others at their mean
"""

import argparse
import os

from gsa_jax.cli import command_parser, run_command
from gsa_jax.deployment.inspection import InspectError, inspect_run


def build_parser() -> argparse.ArgumentParser:
    """`gsa inspect`'s options."""
    p = command_parser("inspect", __doc__)
    p.add_argument("run_dir", metavar="RUN", help="a run directory (gsa train) or SWEEP_DIR/<run label>")
    p.add_argument("--out", default=None)
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    return p


def inspect_command(argv: list | None) -> int:
    """Inspect the run and print its returns and cluster usage."""
    args = build_parser().parse_args(argv)
    if args.episodes < 1:
        raise InspectError("--episodes must be >= 1")
    s, out = inspect_run(args.run_dir, args.out, args.episodes, args.seed)
    d = s["deterministic"]
    print(f"{s['env']}, K={s['K']}: return deterministic {s['return_deterministic_mean']:.1f} vs stochastic "
          f"{s['return_stochastic_mean']:.1f} over {s['episodes']} episodes")
    print(f"deterministic controller: {d['clusters_used']}/{s['K']} clusters used, usage "
          + ", ".join(f"{u:.0%}" for u in d["usage"])
          + f"; mean dwell {d['mean_dwell_steps']:.1f} steps, {d['switches_per_episode']:.1f} switches/episode")
    cells = ""
    if "cells" in s:
        with open(os.path.join(out, "cells.txt")) as f:
            print(f.read(), end="")
        cells = ", cells.txt" + (", cells.png" if os.path.exists(os.path.join(out, "cells.png")) else "")
    print(f"wrote {out}/summary.json, controllers.md, clusters_time.png, clusters_pca.png{cells}")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa inspect`: exit status 0, or 2 on bad input."""
    return run_command("inspect", lambda: inspect_command(argv))
