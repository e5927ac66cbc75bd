"""Score committed controllers as anyone re-running them would: every controllers/<run label>.npz under the
directories, in plain MuJoCo C, over a fixed set of start states.

    gsa score DIR [DIR ...] [--episodes 10] [--start-seed 10000] [--jobs N]

Writes DIR/.../controller_scores.csv beside each controllers/ folder (gsa_jax.analysis.sweeps.controller_scores):
per controller its file's sha256, the start seeds and its mean deterministic return (`controller_score`),
which gsa plot puts in per_run_scores.csv and every verdict uses. Controllers already scored with the
same file, episodes and start seed are kept; an interrupted scoring resumes where it stopped.
"""

import argparse
import os

from gsa_jax.analysis.sweeps.controller_scores import (EPISODES, START_SEED, ScoreError, controller_dirs, default_jobs,
                                                       score_directory)
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    """`gsa score`'s options."""
    p = command_parser("score", __doc__)
    p.add_argument("dirs", nargs="+", metavar="DIR", help="results directories (searched for controllers/*.npz)")
    p.add_argument("--episodes", type=int, default=EPISODES, help="start states per controller (default %(default)s)")
    p.add_argument("--start-seed", type=int, default=START_SEED,
                   help="the first start state's seed; episode i starts from seed START_SEED + i (default %(default)s)")
    p.add_argument("--jobs", type=int, default=default_jobs(),
                   help="processes scoring at once, one controller each (default: the cores, %(default)s)")
    return p


def score(argv: list | None) -> int:
    """Score every controllers/ folder under the directories."""
    args = build_parser().parse_args(argv)
    if args.episodes < 1:
        raise ScoreError(f"--episodes must be >= 1, got {args.episodes}")
    if args.jobs < 1:
        raise ScoreError(f"--jobs must be >= 1, got {args.jobs}")
    missing = [d for d in args.dirs if not os.path.isdir(d)]
    if missing:
        raise ScoreError(f"no directory {missing[0]!r}")
    found = controller_dirs(args.dirs)
    if not found:
        raise ScoreError(f"no controllers/*.npz under {' '.join(args.dirs)}")
    for d in found:
        rows = score_directory(d, args.episodes, args.start_seed, jobs=args.jobs)
        print(f"{d}: {len(rows)} controllers scored ({os.path.join(d, 'controller_scores.csv')})", flush=True)
    return 0


def main(argv: list | None = None) -> int:
    """`gsa score`: exit status 0, or 2 on bad input."""
    return run_command("score", lambda: score(argv))
