"""One compile for all worker processes (gsa_jax.running.xla_cache): a follower process waits for the leader's
program and loads it from the cache (a cache hit, same results); without a leader it compiles by
itself; XLA:CPU's spurious cache-load errors are dropped from stderr and nothing else is."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.running import xla_cache

# a process that compiles one small program through compile_shared, runs it and reports
PROGRAM = textwrap.dedent("""
    import json, sys
    import jax, jax.numpy as jnp, numpy as np
    from jax._src import monitoring
    from gsa_jax.running import xla_cache

    cache, marks, leader, grace = sys.argv[1], sys.argv[2], sys.argv[3] == "1", float(sys.argv[4])
    events = []
    monitoring.register_event_listener(lambda name, **kw: events.append(name))
    xla_cache.enable(cache, min_compile_s=0)

    def f(x):
        for i in range(30):
            x = jnp.tanh(x @ x.T / 64 + i / 30)
        return x.sum(axis=0)

    x = np.arange(64 * 64, dtype=np.float32).reshape(64, 64) / 4096  # NumPy: no eager op to compile
    compiled, how = xla_cache.compile_shared(jax.jit(f).lower(x), marks, leader, grace_s=grace)
    print(json.dumps({"how": how, "hits": events.count("/jax/compilation_cache/cache_hits"),
                      "y": np.asarray(compiled(x)).tolist()}))
""")


def start(tmp_path, leader, grace=120.0, cache="cache", marks="marks"):
    script = tmp_path / "program.py"
    script.write_text(PROGRAM)
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    return subprocess.Popen([sys.executable, str(script), str(tmp_path / cache), str(tmp_path / marks),
                             "1" if leader else "0", str(grace)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def result(proc):
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    assert "cpu_aot_loader" not in err  # the spurious load errors are filtered
    return json.loads(out.strip().splitlines()[-1])


def test_follower_waits_for_the_leader_and_loads_its_program(tmp_path):
    follower = start(tmp_path, leader=False)  # started first: it must wait
    leader = start(tmp_path, leader=True)
    lead, follow = result(leader), result(follower)
    assert lead["how"] == "compiled"
    assert follow["how"].startswith("loaded after waiting") and follow["hits"] >= 1
    assert follow["y"] == lead["y"]
    assert any(n.endswith(".ready") for n in os.listdir(tmp_path / "marks"))
    # a later leader (a resumed worker) loads it too
    again = result(start(tmp_path, leader=True))
    assert again["how"] == "loaded" and again["hits"] >= 1 and again["y"] == lead["y"]


def test_a_cache_moved_to_another_path_loads_and_says_so(tmp_path):
    """The cache key does not depend on the cache's directory (JAX would put its path in the key), and a leader whose
    program an earlier process compiled says it loaded it."""
    import shutil

    first = result(start(tmp_path, leader=True))
    shutil.copytree(tmp_path / "cache", tmp_path / "moved")
    moved = result(start(tmp_path, leader=True, cache="moved", marks="new_marks"))
    assert first["how"] == "compiled" and moved["how"] == "loaded from the cache" and moved["hits"] >= 1
    assert moved["y"] == first["y"]


def test_follower_without_a_leader_compiles_itself(tmp_path):
    alone = result(start(tmp_path, leader=False, grace=0.5))
    assert alone["how"] == "compiled (no leader for this program)" and alone["hits"] == 0


def test_quiet_aot_loader_drops_only_the_spurious_lines(capfd):
    noise = ("E1121 17:20:05.978323    6788 cpu_aot_loader.cc:195] Loading XLA:CPU AOT result. Target machine "
             "feature +prefer-no-gather is not  supported on the host machine. This could lead to SIGILL.\n")
    other = "E1121 17:20:06.000000    6788 something_else.cc:12] a real error\n"
    with xla_cache.quiet_aot_loader():
        os.write(2, (noise + other + noise.replace("gather", "scatter")).encode())
    assert capfd.readouterr().err == other


def test_enabled_restores_the_previous_cache_settings(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    with xla_cache.enabled(str(tmp_path / "default")):
        assert jax.config.jax_compilation_cache_dir == (before or os.path.abspath(tmp_path / "default"))
        assert jax.config.jax_persistent_cache_min_compile_time_secs >= 1.0
        np.testing.assert_allclose(jax.jit(lambda x: x * 2)(jnp.ones(3)), 2.0)
    assert jax.config.jax_compilation_cache_dir == before
