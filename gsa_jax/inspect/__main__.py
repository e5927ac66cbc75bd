"""`python -m gsa_jax.inspect`: `gsa inspect` (gsa_jax.commands.inspect_run).

This directory has no __init__.py on purpose: a namespace package never shadows the standard
library's `inspect`, even when gsa_jax/ itself is on sys.path."""

import sys

from gsa_jax.commands.inspect_run import main

sys.exit(main())
