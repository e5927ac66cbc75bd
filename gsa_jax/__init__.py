"""gsa_jax: generalized state abstraction (mixtures of linear-Gaussian controllers) trained by PPO in pure JAX."""

import importlib.util
import os
import sys

__version__ = "0.1.0"


def _check_envs_package():
    """The task registry `envs` must be the one installed beside gsa_jax: a module or folder named `envs` in the
    working directory (first on sys.path) would shadow it silently, so it is refused in one line."""
    mod = sys.modules.get("envs")
    origin = getattr(mod, "__file__", None) if mod is not None else getattr(importlib.util.find_spec("envs"), "origin", None)
    ours = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "envs")
    if not origin or os.path.dirname(os.path.abspath(origin)) != ours:
        raise ImportError(f"gsa_jax: the module 'envs' found first on sys.path is {origin or 'a folder without __init__.py'}, "
                          f"not gsa_jax's ({ours}); rename your own 'envs' module or run from another directory")


_check_envs_package()

# The public API (gsa_jax/api.py), loaded on first use so that `import gsa_jax` stays light (no JAX).
API = ("answer_task", "export_controller", "improvement_probability", "iqm", "iqm_ci", "load_controller", "load_sweep",
       "options_argv", "read_csv", "read_record", "run_metadata", "run_sweep", "score_controller", "select_run",
       "sweep_runs", "train_run", "verify_controller", "write_csv")
__all__ = ["__version__", *API]


def __getattr__(name: str):
    """A name of the public API (gsa_jax.api), or a submodule of gsa_jax (gsa_jax.cli, ...)."""
    if name in API:
        from gsa_jax import api

        return getattr(api, name)
    if name.startswith("_"):  # dunder and private lookups (copy, pickle, hasattr probes) import nothing
        raise AttributeError(f"module 'gsa_jax' has no attribute {name!r}")
    try:
        return importlib.import_module(f"gsa_jax.{name}")
    except ModuleNotFoundError as e:
        if e.name != f"gsa_jax.{name}":
            raise
        raise AttributeError(f"module 'gsa_jax' has no attribute {name!r}") from None
