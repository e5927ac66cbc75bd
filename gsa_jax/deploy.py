"""`python -m gsa_jax.deploy`: `gsa deploy` (gsa_jax.commands.deploy)."""

import sys

from gsa_jax.commands.deploy import main

if __name__ == "__main__":
    sys.exit(main())
