"""`python -m gsa_jax.inspect RUN_DIR`: the controller report of gsa_jax.deployment.inspection.

This directory has no __init__.py on purpose: a namespace package never shadows the standard
library's `inspect`, even when gsa_jax/ itself is on sys.path."""

import sys

from gsa_jax.deployment.inspection import main

sys.exit(main())
