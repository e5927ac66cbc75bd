"""The policy kinds, named once: a mixture of simple controllers (MIXTURE) or the flat Gaussian MLP baseline (MLP).
The strings are what configs, experiment files, results' `policy` column and exported controllers' `kind` hold.
No JAX: the result readers and deployed controllers import it."""

MIXTURE = "mixture"
MLP = "mlp"
POLICY_KINDS = (MIXTURE, MLP)
VALUE_TARGETS = ("gae", "retrace")  # the value function's targets: GAE(lambda) or Retrace (algorithm/retrace.py)
MIXTURE_COLUMNS = ("subpolicy", "partition")  # a mixture's own classes: the group axes of mixtures only (running/spec.py)
