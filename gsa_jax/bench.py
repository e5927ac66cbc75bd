"""`python -m gsa_jax.bench`: `gsa bench` (gsa_jax.commands.bench)."""

import sys

from gsa_jax.commands.bench import main

if __name__ == "__main__":
    sys.exit(main())
