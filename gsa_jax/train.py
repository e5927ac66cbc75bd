"""`python -m gsa_jax.train`: `gsa train` (gsa_jax.commands.train)."""

import sys

from gsa_jax.commands.train import main

if __name__ == "__main__":
    sys.exit(main())
