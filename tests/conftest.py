import os
import sys

# examples/ (tasks a user defines, named 'examples.<module>:<Class>') imports from the repository root, as
# `python -m gsa_jax.train` run there does
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# Keep test programs small and compiled once: a persistent XLA cache shared by the CLI runs in a session.
os.environ.setdefault("MUJOCO_GL", "disable")
# The suite is compile-bound: its processes, and the processes its tests start (through XLA_FLAGS), compile
# without LLVM's optimizations, which takes about 0.7x the default's compile time for the same programs and
# gives the same results to float rounding (tests/test_sweep.py checks a run against one compiled at XLA's
# default level 3). Every comparison in the suite is between programs compiled the same way. To run the
# suite as users' programs compile: XLA_FLAGS=--xla_backend_optimization_level=3 make test
TEST_XLA_FLAGS = "--xla_backend_optimization_level=0"
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + TEST_XLA_FLAGS).strip()

import jax  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _compile_cache(tmp_path_factory):
    """One persistent compilation cache for the session, shared by its xdist workers (they compile some of
    the same programs) and by the processes the tests start (through the environment: a `gsa train` they start
    keeps its programs there, not in the user's cache)."""
    root = tmp_path_factory.getbasetemp()
    cache = (root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root) / "xla_cache"
    cache.mkdir(exist_ok=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(cache)
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    yield


@pytest.fixture
def random_controller(tmp_path):
    """make(env="hopper", **config) -> path of an exported mixture controller (2 random linear pieces) for
    hopper or allegro_cylinder, as `python -m gsa_jax.export` writes it; config entries go into its config
    (e.g. episode_length)."""
    import json

    import numpy as np

    from gsa_jax.running.checkpoint import save_npz_atomic

    def make(env="hopper", **config):
        obs, act = {"hopper": (11, 3), "allegro_cylinder": (10, 8)}[env]
        rng = np.random.default_rng(0)
        arrays = {"kind": np.array("mixture"), "subpolicy": np.array("linear"), "obs_mean": np.zeros(obs, np.float32),
                  "obs_var": np.ones(obs, np.float32), "obs_clip": np.array(10.0, np.float32), "n_layers": np.array(1),
                  "w0": rng.normal(size=(obs, 2)).astype(np.float32), "b0": np.zeros(2, np.float32),
                  "L": 0.1 * rng.normal(size=(2, act, obs)).astype(np.float32), "b": np.zeros((2, act), np.float32),
                  "config_json": np.array(json.dumps({"config": {"env": env, **config}}))}
        path = tmp_path / "controller.npz"
        save_npz_atomic(str(path), **arrays)
        return path

    return make
