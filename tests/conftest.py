import os

# Keep test programs small and compiled once: a persistent XLA cache shared by the CLI runs in a session.
os.environ.setdefault("MUJOCO_GL", "disable")

import jax  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _compile_cache(tmp_path_factory):
    jax.config.update("jax_compilation_cache_dir", str(tmp_path_factory.mktemp("xla_cache")))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    yield
