"""`python -m gsa_jax.render`: `gsa render` (gsa_jax.commands.render)."""

import sys

from gsa_jax.commands.render import main

if __name__ == "__main__":
    sys.exit(main())
