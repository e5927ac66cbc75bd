"""Rewrite the numbers quoted in Markdown pages from the committed tables (`gsa quote PAGE.md [PAGE.md ...]
[--check]`).

The spans and their kinds: gsa_jax.analysis.quoting.quote. --check rewrites nothing and exits 1 naming every span whose
TEXT is not what the tables give.
"""

import argparse
import os

from gsa_jax.analysis.quoting.quote import QuoteError, requote
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    """`gsa quote`'s options."""
    p = command_parser("quote", __doc__)
    p.add_argument("pages", nargs="+", metavar="PAGE", help="Markdown pages")
    p.add_argument("--check", action="store_true", help="rewrite nothing; exit 1 if any quoted number is stale")
    return p


def quote_pages(argv: list | None) -> int:
    """Requote every page (or, with --check, only name the stale spans). Exit status 1 when --check finds any."""
    args = build_parser().parse_args(argv)
    stale = 0
    for page in args.pages:
        try:
            with open(page) as f:
                text, changed = requote(f.read(), os.path.dirname(page) or ".")
        except (OSError, QuoteError) as e:
            raise QuoteError(f"{page}: {e}") from None
        for spec, old, new in changed:
            print(f"{page}: quote {spec}: {old.strip()[:80]!r} -> {new.strip()[:80]!r}")
        stale += len(changed)
        if changed and not args.check:
            with open(page, "w") as f:
                f.write(text)
    return 1 if args.check and stale else 0


def main(argv: list | None = None) -> int:
    """`gsa quote`: exit status 0, 1 (--check found stale numbers) or 2 (bad input)."""
    return run_command("quote", lambda: quote_pages(argv))
