"""`python -m gsa_jax.extract`: `gsa extract` (gsa_jax.commands.extract)."""

import sys

from gsa_jax.commands.extract import main

if __name__ == "__main__":
    sys.exit(main())
