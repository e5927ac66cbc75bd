"""`python -m gsa_jax.export`: `gsa export` (gsa_jax.commands.export)."""

import sys

from gsa_jax.commands.export import main

if __name__ == "__main__":
    sys.exit(main())
