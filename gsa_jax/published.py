"""`python -m gsa_jax.published`: `gsa published` (gsa_jax.commands.published)."""

import sys

from gsa_jax.commands.published import main

if __name__ == "__main__":
    sys.exit(main())
