"""`python -m gsa_jax.plot`: `gsa plot` (gsa_jax.commands.plot)."""

import sys

from gsa_jax.commands.plot import main

if __name__ == "__main__":
    sys.exit(main())
