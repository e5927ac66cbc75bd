"""Read a trained mixture controller: each piece as u = u0 + K (x - x*) in the task's units, its cell and, for a
run, its clusters along rollouts (`gsa inspect RUN [--episodes 8] [--out DIR]`; RUN a run directory or
SWEEP_DIR/<run label>: rollouts, figures and files in DIR; or an exported controller .npz: its pieces and cells
printed, no rollouts, written to DIR only with --out).

Every piece's law is printed: u0 (the raw action at x*) and the gains K (action per unit of each observation, named
by the task's observation layout and actuators; the normalization folded in), x* the task's equilibrium observation
where it declares one (else the normalization mean), with the piece's cell (every state for K = 1; a linear
partition's inequalities); exact while each observation is within 10 std of its mean (the observation clip).

An exported controller .npz (gsa export, an answer's controller/controller.npz) gives only that: its pieces and
cells, no rollouts (--episodes, --seed unused); with --out DIR it writes pieces.txt, controllers.md, summary.json
(and cells.txt, cells.png) there. A run directory also rolls out the deterministic controller (most probable
cluster, mean action) and the stochastic policy for a few episodes, then writes to DIR (default
<run dir>/inspect/, SWEEP_DIR/inspect/<run label>/):
  summary.json        returns (deterministic vs stochastic), cluster usage, clusters ever used,
                      mean dwell time and switches per episode; each piece's u0, K and x* (pieces)
  clusters_time.png   the active cluster over one episode, above the main state variables
  clusters_pca.png    visited states (PCA of normalized observations) coloured by cluster
  pieces.txt          the printed laws
  controllers.md      each cluster's u0 and K in the task's units, with the inputs that drive each
                      actuator most (per observation std)
and, for a linear partition (--partition linear), printed too:
  cells.txt           each cluster's cell as inequalities A s >= d in the task's own units (the observation
                      normalization folded in), one per other cluster; summary.json holds A and d
  cells.png           the cells on the two observations that part them most (the largest spread of the
                      partition's weights over the clusters, per observation std), the others at their mean
"""

import argparse
import os

from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    """`gsa inspect`'s options."""
    p = command_parser("inspect", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    p.add_argument("run_dir", metavar="RUN", help="a run directory (gsa train), SWEEP_DIR/<run label> or an "
                   "exported controller .npz (its pieces and cells only, no rollouts)")
    p.add_argument("--out", default=None, help="output directory (default: <run dir>/inspect/, "
                   "SWEEP_DIR/inspect/<run label>/; for a controller .npz: none, printed only)")
    p.add_argument("--episodes", type=int, default=8,
                   help="episodes of the deterministic controller and of the stochastic policy (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the episodes (start states, the stochastic policy's draws; default %(default)s)")
    return p


def inspect_command(argv: list | None) -> int:
    """Inspect the run and print its returns and cluster usage."""
    args = build_parser().parse_args(argv)
    from gsa_jax.deployment.inspection import InspectError, inspect_file, inspect_run  # loads JAX: not for --help

    if args.episodes < 1:
        raise InspectError("--episodes must be >= 1")
    if os.path.isfile(args.run_dir):  # an exported controller: its pieces and cells, no rollouts
        text, written = inspect_file(args.run_dir, args.out)
        print(text + (f"wrote {args.out}/{', '.join(written)}\n" if written else ""), end="")
        return 0
    s, out = inspect_run(args.run_dir, args.out, args.episodes, args.seed)
    d = s["deterministic"]
    print(f"{s['env']}, K={s['K']}: return deterministic {s['return_deterministic_mean']:.1f} vs stochastic "
          f"{s['return_stochastic_mean']:.1f} over {s['episodes']} episodes")
    print(f"deterministic controller: {d['clusters_used']}/{s['K']} clusters used, usage "
          + ", ".join(f"{u:.0%}" for u in d["usage"])
          + f"; mean dwell {d['mean_dwell_steps']:.1f} steps, {d['switches_per_episode']:.1f} switches/episode")
    with open(os.path.join(out, "pieces.txt")) as f:
        print(f.read(), end="")
    cells = ""
    if "cells" in s:
        with open(os.path.join(out, "cells.txt")) as f:
            print(f.read(), end="")
        cells = ", cells.txt" + (", cells.png" if os.path.exists(os.path.join(out, "cells.png")) else "")
    print(f"wrote {out}/summary.json, pieces.txt, controllers.md, clusters_time.png, clusters_pca.png{cells}")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa inspect`: exit status 0, or 2 on bad input."""
    return run_command("inspect", lambda: inspect_command(argv))
