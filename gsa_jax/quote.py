"""`python -m gsa_jax.quote`: `gsa quote` (gsa_jax.commands.quote)."""

import sys

from gsa_jax.commands.quote import main

if __name__ == "__main__":
    sys.exit(main())
