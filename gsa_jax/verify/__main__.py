"""`python -m gsa_jax.verify`: `gsa verify` (gsa_jax.commands.verify)."""

import sys

from gsa_jax.commands.verify import main

sys.exit(main())
