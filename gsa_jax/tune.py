"""`python -m gsa_jax.tune`: `gsa tune` (gsa_jax.commands.tune)."""

import sys

from gsa_jax.commands.tune import main

if __name__ == "__main__":
    sys.exit(main())
