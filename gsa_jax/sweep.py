"""`python -m gsa_jax.sweep`: `gsa sweep` (gsa_jax.commands.sweep)."""

import sys

from gsa_jax.commands.sweep import main

if __name__ == "__main__":
    sys.exit(main())
