"""JAX's persistent compilation cache: where programs are kept between processes, and one compile for all worker
processes.

Every command that enables the cache does it here (enable, enabled): a single run (gsa train) keeps its programs
in the user's cache (JAX_COMPILATION_CACHE_DIR, else user_dir()), so an identical second invocation loads them; a
sweep, an answer and the benchmark keep theirs in their own directory. Loads from the cache are quiet
(quiet_cache_loads). JAX_ENABLE_COMPILATION_CACHE=false turns the cache off.

once_options: the compiler options of the programs a run runs once or now and then (init, the evaluation).

Sweeps and the benchmark run one worker process per core, and every worker builds the same program
(same shapes; seeds, K and hyperparameters are array arguments). Compiling it in every worker at once
costs more wall time than compiling it once: the compiles compete for the same cores. So worker 0
(the leader) compiles and writes the executable to the cache; the other workers lower their program
meanwhile, wait for the leader's mark, and load the executable from the cache (seconds). A resumed or
restarted worker loads its program from the cache the same way.

The mark is named after a hash of the lowered program, so a follower only waits for the very program
it needs; a follower whose program the leader does not build (a different run count) or whose leader
has not announced a compile within `grace_s` compiles by itself, as it would without the cache.
"""

import contextlib
import hashlib
import os
import re
import sys
import tempfile
import time
from typing import Callable, Iterator

import jax
from jax._src import compilation_cache as cache_internals  # jax 0.10.1's internals: pinned in pyproject.toml
from jax.experimental.compilation_cache import compilation_cache

# XLA:CPU logs these at ERROR level on every load of a cached executable: on a host with AVX-512 its IR compiler
# adds LLVM's tuning flags +prefer-no-gather/+prefer-no-scatter to the target features recorded with the executable,
# and its AOT loader (cpu_aot_loader.cc) checks every recorded feature against the host's CPUID features, where
# these flags never appear (openxla/xla#44565, jax-ml/jax#38445). The executable is used; the lines are noise. No
# option turns the check off without changing the code generated (--xla_cpu_max_isa below AVX-512 drops the flags
# and the AVX-512 code with them), so quiet_cache_loads drops the lines at each load.
AOT_LOADER_NOISE = re.compile(r"cpu_aot_loader\.cc:\d+\] Loading XLA:CPU AOT result\. Target machine feature \+prefer-no-")


_OPTIONS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
            "jax_persistent_cache_min_entry_size_bytes", "jax_persistent_cache_enable_xla_caches")
# JAX's default also keeps XLA's GPU autotuning cache under the cache directory, and writes that directory's path into
# every program's compile options, hence into its cache key: the same program cached under another path (an answer's
# cache copied, a sweep's next to an answer's) would never load. "none": no XLA-side caches, keys independent of paths.
NO_XLA_CACHES = "none"


def _set(values):
    for name, value in zip(_OPTIONS, values):
        jax.config.update(name, value)
    compilation_cache.reset_cache()  # JAX reads the options once, at its first compile
    quiet_cache_loads()


def user_dir() -> str:
    """The user's cache of compiled programs: $XDG_CACHE_HOME/gsa_jax/xla (default ~/.cache/gsa_jax/xla)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "gsa_jax", "xla")


def enable(cache_dir: str, min_compile_s: float = 1.0) -> None:
    """Use `cache_dir` as JAX's persistent compilation cache for programs that take at least
    `min_compile_s` to compile (not the many small eager ops, whose loads XLA:CPU would log as errors)."""
    os.makedirs(cache_dir, exist_ok=True)
    _set((os.path.abspath(cache_dir), float(min_compile_s), -1, NO_XLA_CACHES))


@contextlib.contextmanager
def enabled(default_dir: str) -> Iterator[None]:
    """A persistent compilation cache for every program inside the block: the one the user configured
    (JAX_COMPILATION_CACHE_DIR), else `default_dir`. JAX's previous cache settings after it."""
    before = tuple(getattr(jax.config, name) for name in _OPTIONS)
    enable(before[0] or default_dir, min_compile_s=max(before[1], 1.0))  # sets every option of _OPTIONS
    try:
        yield
    finally:
        _set(before)


@contextlib.contextmanager
def quiet_aot_loader() -> Iterator[None]:
    """Drop XLA:CPU's spurious cache-load errors (AOT_LOADER_NOISE) from stderr; pass every other line on.
    Works on file descriptor 2, where XLA's C++ logging writes."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            kept = [ln for ln in tmp.read().decode(errors="replace").splitlines(keepends=True) if not AOT_LOADER_NOISE.search(ln)]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def quiet_cache_loads() -> None:
    """Every later load from the persistent cache in this process runs inside quiet_aot_loader (once per process:
    wraps jax's compilation_cache.get_executable_and_time, which deserializes the cached executable)."""
    read = cache_internals.get_executable_and_time
    if getattr(read, "quiet", False):
        return

    def quiet_read(*args, **kwargs):
        with quiet_aot_loader():
            return read(*args, **kwargs)

    quiet_read.quiet = True
    cache_internals.get_executable_and_time = quiet_read


def program_hash(lowered: jax.stages.Lowered) -> str:
    """Short hash of a lowered program's text (StableHLO): equal programs, equal hashes."""
    return hashlib.sha256(lowered.as_text().encode()).hexdigest()[:20]


# XLA:CPU's older fusion code generation (before its MLIR fusion emitters) for the programs a run runs once or now
# and then: init (on MJX, the physics' reset) and the deterministic evaluation (a reset and an episode loop). They
# compile faster that way (the demo's whole compile: median 34.8 -> 32.0 s) and its evaluations run no slower; the
# training chunk keeps XLA's default code generation, which runs it faster (experiments/compile_time/README.md, "Older
# code generation for init and the evaluation").
ONCE_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
# At XLA_FLAGS' --xla_backend_optimization_level=0 (the test suite's) the older code generation computed NaN weights
# in a vmapped init of one run whose orthogonal init was unrolled (tests/test_tune.py's tuning sweep), finite ones at
# levels 1 and 3 (a probe); with that init as one loop (gsa_jax.algorithm.nn.orthogonal_from) it is finite at level 0
# too (a probe, made before init_mlp drew its layers' Gaussians in one draw). Programs compiled with ONCE_OPTIONS
# still hold at least this level: a miscompile, not understood.
ONCE_MIN_LEVEL = 1
_LEVEL_FLAG = re.compile(r"--xla_backend_optimization_level=(\d+)")


def once_options(platform: "str | None" = None) -> "dict | None":
    """jax.jit's compiler_options for a program run once or now and then: ONCE_OPTIONS where it compiles for the
    CPU (`platform`, default JAX's default backend), with level ONCE_MIN_LEVEL where XLA_FLAGS sets a lower one
    (users' runs: XLA's default level 3); None elsewhere (the option is XLA:CPU's)."""
    if (platform or jax.default_backend()) != "cpu":
        return None
    levels = [int(x) for x in _LEVEL_FLAG.findall(os.environ.get("XLA_FLAGS", ""))]
    low = bool(levels) and levels[-1] < ONCE_MIN_LEVEL
    return dict(ONCE_OPTIONS, **({"xla_backend_optimization_level": ONCE_MIN_LEVEL} if low else {}))


_HITS = [0]  # this process's loads from the persistent cache (jax's monitoring event), read by compile_counted


def _count_hit(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _HITS[0] += 1


jax.monitoring.register_event_listener(_count_hit)


def compile_counted(lowered: jax.stages.Lowered) -> tuple:
    """(lowered.compile(), whether it was loaded from the persistent cache rather than compiled)."""
    before = _HITS[0]
    compiled = lowered.compile()
    return compiled, _HITS[0] > before


def compile_shared(lowered: jax.stages.Lowered, mark_dir: str, leader: bool, grace_s: float = 120.0,
                   max_wait_s: float = 3600.0, log: "Callable | None" = None) -> tuple:
    """lowered.compile(), once for all processes sharing `mark_dir` (with enable() on the same cache dir).

    leader: True in exactly one process (worker 0). The leader announces `<hash>.compiling`, compiles
    (writing the cache) and marks `<hash>.ready`; a follower waits for `<hash>.ready` and then compiles,
    which loads from the cache. Returns (compiled, how) with how one of "compiled", "loaded from the cache" (a
    program an earlier process compiled), "loaded after waiting N s" or "compiled (no leader for this program)"."""
    os.makedirs(mark_dir, exist_ok=True)
    h = program_hash(lowered)
    ready, compiling = os.path.join(mark_dir, h + ".ready"), os.path.join(mark_dir, h + ".compiling")
    if leader:
        if not os.path.exists(ready):
            open(compiling, "w").close()
            compiled, loaded = compile_counted(lowered)
            open(ready, "w").close()
            return compiled, "loaded from the cache" if loaded else "compiled"
        return lowered.compile(), "loaded"
    t0 = time.monotonic()
    while not os.path.exists(ready):
        waited = time.monotonic() - t0
        if waited > max_wait_s or (waited > grace_s and not os.path.exists(compiling)):
            if log:
                log(f"no compiled program from the leader process after {waited:.0f} s; compiling here")
            return lowered.compile(), "compiled (no leader for this program)"
        time.sleep(0.05)
    waited = time.monotonic() - t0
    return lowered.compile(), f"loaded after waiting {waited:.0f} s"


def has_host_callbacks(lowered: jax.stages.Lowered) -> bool:
    """Whether a lowered program holds jax's python callbacks (jax.debug.print, pure_callback; not backend 'c''s
    host calls, envs/host_call.py). JAX never writes such a program to the persistent cache (the callbacks are
    baked into the executable), so it cannot be shared."""
    return "python_cpu_callback" in lowered.as_text()


def compile_with(lowered: jax.stages.Lowered, share: "tuple | None" = None, log: "Callable | None" = None) -> tuple:
    """(compiled, how): lowered.compile() alone (share None, or a program with host callbacks: every
    process compiles its own) or compile_shared(lowered, *share) with share = (mark_dir, leader)."""
    if share is None:
        return lowered.compile(), "compiled"
    if has_host_callbacks(lowered):
        return lowered.compile(), "compiled (host callbacks: not shareable)"
    return compile_shared(lowered, *share, log=log)
