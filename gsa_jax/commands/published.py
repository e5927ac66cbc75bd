"""Compare flat PPO with published PPO scores, computed the way the published table computes them
(`gsa published REFERENCE.csv PER_RUN.csv [PER_RUN.csv ...] --out OUT.csv`).

The comparison's rows: gsa_jax.analysis.quoting.published.
"""

import argparse

from gsa_jax.analysis.quoting.published import compare
from gsa_jax.analysis.sweeps.results import read_csv, write_csv
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.errors import UserError


def build_parser() -> argparse.ArgumentParser:
    """`gsa published`'s options."""
    p = command_parser("published", __doc__)
    p.add_argument("reference", help="CSV of published scores: env, mean, std, source")
    p.add_argument("per_run", nargs="+", help="per_run_scores.csv files of gsa plot")
    p.add_argument("--out", required=True, help="the comparison CSV to write")
    return p


def compare_published(argv: list | None) -> int:
    """Write the comparison and print one line per task."""
    args = build_parser().parse_args(argv)
    try:
        rows = compare(read_csv(args.reference), [r for path in args.per_run for r in read_csv(path)])
    except (OSError, KeyError) as e:
        raise UserError(e) from None
    if not rows:
        raise UserError("no flat PPO task matches a published one")
    write_csv(args.out, rows)
    for r in rows:
        print(f"{r['env']} ({r['seeds']} seeds): {r['last_100_episodes_mean']:.0f} ± {r['last_100_episodes_std']:.0f}"
              f"  vs {r['published_env']}: {float(r['published_mean']):.0f} ± {float(r['published_std']):.0f}")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa published`: exit status 0, or 2 on bad input."""
    return run_command("published", lambda: compare_published(argv))
