"""One compile for all worker processes: JAX's persistent compilation cache, shared through a directory.

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
import threading
import time
from typing import Callable, Iterator

import jax
from jax.experimental.compilation_cache import compilation_cache

# XLA:CPU logs these at ERROR level on every load of a cached executable: LLVM's tuning flags
# +prefer-no-gather/+prefer-no-scatter are recorded with the executable but never reported as host
# features (openxla/xla#44565, jax-ml/jax#38445). The executable is used; the lines are noise.
AOT_LOADER_NOISE = re.compile(r"cpu_aot_loader\.cc:\d+\] Loading XLA:CPU AOT result\. Target machine feature \+prefer-no-")


_OPTIONS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
            "jax_persistent_cache_min_entry_size_bytes")


def _set(values):

    for name, value in zip(_OPTIONS, values):
        jax.config.update(name, value)
    compilation_cache.reset_cache()  # JAX reads the options once, at its first compile


def enable(cache_dir: str, min_compile_s: float = 1.0) -> None:
    """Use `cache_dir` as JAX's persistent compilation cache for programs that take at least
    `min_compile_s` to compile (not the many small eager ops, whose loads XLA:CPU would log as errors)."""
    os.makedirs(cache_dir, exist_ok=True)
    _set((os.path.abspath(cache_dir), float(min_compile_s), -1))


@contextlib.contextmanager
def enabled(default_dir: str) -> Iterator[None]:
    """A persistent compilation cache for every program inside the block: the one the user configured
    (JAX_COMPILATION_CACHE_DIR), else `default_dir`. JAX's previous cache settings after it."""
    before = tuple(getattr(jax.config, name) for name in _OPTIONS)
    enable(before[0] or default_dir, min_compile_s=max(before[1], 1.0))
    try:
        yield
    finally:
        _set(before)


_QUIET = {"lock": threading.Lock(), "depth": 0, "saved": -1, "tmp": None}  # one redirect shared by concurrent loads


def _redirect_stderr() -> None:
    """Point file descriptor 2 at a temporary file (the first of nested or concurrent quiet sections only)."""
    with _QUIET["lock"]:
        if _QUIET["depth"] == 0:
            sys.stderr.flush()
            _QUIET["saved"], _QUIET["tmp"] = os.dup(2), tempfile.TemporaryFile(mode="w+b")
            os.dup2(_QUIET["tmp"].fileno(), 2)
        _QUIET["depth"] += 1


def _restore_stderr() -> None:
    """Undo _redirect_stderr once the last quiet section ends: descriptor 2 restored, the captured lines but
    AOT_LOADER_NOISE written to it."""
    with _QUIET["lock"]:
        _QUIET["depth"] -= 1
        if _QUIET["depth"] > 0:
            return
        sys.stderr.flush()
        os.dup2(_QUIET["saved"], 2)
        os.close(_QUIET["saved"])
        tmp, _QUIET["tmp"] = _QUIET["tmp"], None
        with tmp:
            tmp.seek(0)
            lines = tmp.read().decode(errors="replace").splitlines(keepends=True)
        kept = [ln for ln in lines if not AOT_LOADER_NOISE.search(ln)]
        if kept:
            sys.stderr.write("".join(kept))
            sys.stderr.flush()


@contextlib.contextmanager
def quiet_aot_loader() -> Iterator[None]:
    """Drop XLA:CPU's spurious cache-load errors (AOT_LOADER_NOISE) from stderr; pass every other line on.
    Works on file descriptor 2, where XLA's C++ logging writes. Safe when programs load in several threads at once
    (compile_concurrently): one redirect while any section is open, so descriptor 2 is always restored."""
    _redirect_stderr()
    try:
        yield
    finally:
        _restore_stderr()


def program_hash(lowered: jax.stages.Lowered) -> str:
    """Short hash of a lowered program's text (StableHLO): equal programs, equal hashes."""
    return hashlib.sha256(lowered.as_text().encode()).hexdigest()[:20]


def compile_shared(lowered: jax.stages.Lowered, mark_dir: str, leader: bool, grace_s: float = 120.0,
                   max_wait_s: float = 3600.0, log: "Callable | None" = None) -> tuple:
    """lowered.compile(), once for all processes sharing `mark_dir` (with enable() on the same cache dir).

    leader: True in exactly one process (worker 0). The leader announces `<hash>.compiling`, compiles
    (writing the cache) and marks `<hash>.ready`; a follower waits for `<hash>.ready` and then compiles,
    which loads from the cache. Returns (compiled, how) with how one of "compiled", "loaded after
    waiting N s" or "compiled (no leader for this program)"."""
    os.makedirs(mark_dir, exist_ok=True)
    h = program_hash(lowered)
    ready, compiling = os.path.join(mark_dir, h + ".ready"), os.path.join(mark_dir, h + ".compiling")
    if leader:
        if not os.path.exists(ready):
            open(compiling, "w").close()
            with quiet_aot_loader():
                compiled = lowered.compile()
            open(ready, "w").close()
            return compiled, "compiled"
        with quiet_aot_loader():
            return lowered.compile(), "loaded"
    t0 = time.monotonic()
    while not os.path.exists(ready):
        waited = time.monotonic() - t0
        if waited > max_wait_s or (waited > grace_s and not os.path.exists(compiling)):
            if log:
                log(f"no compiled program from the leader process after {waited:.0f} s; compiling here")
            with quiet_aot_loader():
                return lowered.compile(), "compiled (no leader for this program)"
        time.sleep(0.05)
    waited = time.monotonic() - t0
    with quiet_aot_loader():
        return lowered.compile(), f"loaded after waiting {waited:.0f} s"


def has_host_callbacks(lowered: jax.stages.Lowered) -> bool:
    """Whether a lowered program calls back into Python (physics backend 'c'). JAX never writes such a
    program to the persistent cache (the callbacks are baked into the executable), so it cannot be shared."""
    return "python_cpu_callback" in lowered.as_text()


def compile_with(lowered: jax.stages.Lowered, share: "tuple | None" = None, log: "Callable | None" = None) -> tuple:
    """(compiled, how): lowered.compile() alone (share None, or a program with host callbacks: every
    process compiles its own) or compile_shared(lowered, *share) with share = (mark_dir, leader)."""
    if share is None:
        return lowered.compile(), "compiled"
    if has_host_callbacks(lowered):
        return lowered.compile(), "compiled (host callbacks: not shareable)"
    return compile_shared(lowered, *share, log=log)
