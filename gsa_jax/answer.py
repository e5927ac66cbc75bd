"""`python -m gsa_jax.answer`: `gsa answer` (gsa_jax.commands.answer)."""

import sys

from gsa_jax.commands.answer import main

if __name__ == "__main__":
    sys.exit(main())
