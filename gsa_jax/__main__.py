"""`python -m gsa_jax`: `gsa` (gsa_jax.cli)."""

import sys

from gsa_jax.cli import main

sys.exit(main())
