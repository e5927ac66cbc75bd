"""`python -m gsa_jax.robustness`: `gsa robustness` (gsa_jax.commands.robustness)."""

import sys

from gsa_jax.commands.robustness import main

if __name__ == "__main__":
    sys.exit(main())
