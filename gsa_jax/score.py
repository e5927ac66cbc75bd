"""`python -m gsa_jax.score`: `gsa score` (gsa_jax.commands.score)."""

import sys

from gsa_jax.commands.score import main

if __name__ == "__main__":
    sys.exit(main())
