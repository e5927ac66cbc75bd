"""host_call: a pure host function called from inside a compiled program, NumPy arrays in and out.

    outs = host_call(fn, (jax.ShapeDtypeStruct(...), ...), *args)    # like jax.pure_callback(..., vmap_method="broadcast_all")

jax.pure_callback hands its function JAX arrays: every call device_puts each argument and converts every
result, several times this module's cost per call (measured in experiments/bench_c_backend/host_call_overhead.py).
Backend 'c' makes one such call per env step of a whole sub-batch, so the difference is a share of the physics
time. host_call calls fn on NumPy views of XLA's buffers, with pure_callback's sharding rule and its broadcast_all
batching rule. fn must not keep its arguments (they are XLA's buffers) and must return arrays of exactly the
declared shapes and dtypes (checked on every call, as pure_callback does). No derivatives (as pure_callback).

On CPU the call is the XLA FFI custom call xla_ffi.TARGET (a small C handler, envs/xla_ffi.py) with two integer
attributes: `key`, which names fn, and `site`, the call's place in its program. A program so holds no Python
callback, and JAX's persistent compilation cache stores it: an identical program in a new process is loaded, not
compiled, and calls that process's own fn. The key of fn is a hash of fn's name (module, class, method) and of how
many functions of that name this process keyed before it (key_of), so the same program built the same way in two
processes has the same key. On other platforms, or where the C handler cannot be built (no C compiler: said once on
stderr), the call is jax's python callback, which is never cached. Built on jax 0.10.1's internals (pinned in
pyproject.toml).
"""

import collections
import functools
import hashlib
import sys
import threading
import weakref
from typing import Callable

import numpy as np
from jax._src import callback as jax_callback
from jax._src import core, dispatch, dtypes, ffi
from jax._src.interpreters import ad, batching, mlir

from envs import xla_ffi

host_call_p = core.Primitive("gsa_host_call")
host_call_p.multiple_results = True


def host_call(fn, result_shapes, *args):
    """fn(*numpy args) -> tuple of arrays shaped result_shapes (ShapeDtypeStructs); vmaps as broadcast_all."""
    avals = tuple(core.ShapedArray(s.shape, s.dtype) for s in result_shapes)
    return host_call_p.bind(*args, callback=fn, result_avals=avals, vmap_method="broadcast_all")


@host_call_p.def_abstract_eval
def _abstract_eval(*avals, callback, result_avals, vmap_method):
    del avals, callback, vmap_method
    return result_avals


def _no_derivatives(*args, **kwargs):
    raise ValueError("host_call has no derivatives")


# ------------------------------------------------------------------------------------ keys of host functions
_LOCK = threading.Lock()
_LIVE = {}  # key -> weak reference to the host function it names (alive while a program or a trace holds it)
_ISSUED = {}  # fn's name -> keys issued under that name in this process, in order
# the host functions most recently keyed or called, held strongly: a program runs asynchronously, so the env whose
# host it calls may be dropped (with the jitted function holding the program) before the program has run, e.g.
# `roll(envs.make(...))` returning unread arrays
_RECENT = collections.OrderedDict()  # key -> host function
RECENT = 8


def hold(key: int, fn: Callable) -> None:
    """Keep fn (named by key) alive until RECENT other host functions have been keyed or called after it, or
    release_recent. Only lowering (key_of) and calls refresh it: a program dispatched again from jit's cache is
    covered only while its host is among the RECENT last used."""
    dropped = []  # released after the lock: a host's teardown (its simulations, threads) never runs under it
    with _LOCK:
        if _RECENT and next(reversed(_RECENT)) == key:  # the common case: the same host, call after call
            return
        _RECENT[key] = fn
        _RECENT.move_to_end(key)
        while len(_RECENT) > RECENT:
            dropped.append(_RECENT.popitem(last=False))
    del dropped


def release_recent() -> None:
    """Stop holding the recently used host functions (gsa_jax.running.programs.cached, when it drops a program
    whose results were read): their envs live on only where something else holds them."""
    with _LOCK:
        dropped = list(_RECENT.values())
        _RECENT.clear()
    del dropped


def describe(fn: Callable) -> str:
    """fn's name: 'module.Class.method' of a bound method, 'module.qualname' of a function, else its type's."""
    owner, func = getattr(fn, "__self__", None), getattr(fn, "__func__", None)
    if owner is not None and func is not None:
        return f"{type(owner).__module__}.{type(owner).__qualname__}.{func.__name__}"
    named = fn if hasattr(fn, "__qualname__") else type(fn)
    return f"{getattr(named, '__module__', '')}.{named.__qualname__}"


def _weak(fn: Callable) -> Callable:
    """A weak reference to fn (a bound method's: to its object); a callable that cannot be one is held for good."""
    try:
        return weakref.WeakMethod(fn) if hasattr(fn, "__func__") else weakref.ref(fn)
    except TypeError:
        return lambda: fn


def key_of(fn: Callable) -> int:
    """The int64 that names fn in this process's programs: the same for fn each time; for the n-th function keyed
    under describe(fn) in a process, the same in every process (sha256 of the name and n)."""
    name = describe(fn)
    with _LOCK:
        issued = _ISSUED.setdefault(name, [])
        for key in issued:
            live = _LIVE[key]() if key in _LIVE else None
            if live is None:
                _LIVE.pop(key, None)  # its programs are gone; the key is not issued again
            elif live == fn:
                break
        else:
            digest = hashlib.sha256(f"{name}#{len(issued)}".encode()).digest()
            key = int.from_bytes(digest[:8], "little", signed=True)
            issued.append(key)
            _LIVE[key] = _weak(fn)
    hold(key, fn)
    return key


def checked_results(outs, expected: list) -> list:
    """fn's results as NumPy arrays of JAX's canonical dtypes, each of the (shape, dtype) in `expected`, else a
    RuntimeError saying which differs (pure_callback's checks and messages)."""
    if len(outs) != len(expected):
        raise RuntimeError(f"Mismatched number of outputs from callback. Expected: {len(expected)}, Actual: {len(outs)}")
    checked = []
    for i, (out, (shape, dtype)) in enumerate(zip(outs, expected)):
        out = np.asarray(out)
        if out.dtype != dtype:  # an expected dtype is canonical: only another one can change
            out = dtypes.canonicalize_value(out)
        if out.shape != shape:
            raise RuntimeError(f"Incorrect output shape for return value #{i}: Expected: {shape}, Actual: {out.shape}")
        if out.dtype != dtype:
            raise RuntimeError(f"Incorrect output dtype for return value #{i}: Expected: {dtype}, Actual: {out.dtype}")
        checked.append(out)
    return checked


def _handle(key: int, args: list, rets: list) -> None:
    """The FFI target: the host function named by `key` on the argument views; its results into rets."""
    ref = _LIVE.get(key)
    fn = ref() if ref is not None else None
    if fn is None:
        raise RuntimeError(f"no host function with key {key} in this process: the env whose program this is was "
                           f"dropped before the program ran, and {RECENT} others were used since (keep the env until "
                           "its results are read)")
    hold(key, fn)
    for ret, out in zip(rets, checked_results(fn(*args), [(r.shape, r.dtype) for r in rets])):
        np.copyto(ret, out)


# ------------------------------------------------------------------------------------------------ lowering
def _sharding(ctx):
    return jax_callback._callback_op_sharding(ctx.module_context.axis_context, None, ctx.avals_out)


@functools.cache
def ffi_available() -> bool:
    """Whether the FFI handler is registered in this process (registered here on first use); if not, says why."""
    reason = xla_ffi.register(_handle)
    if reason:
        print(f"gsa_jax: backend 'c' calls its host through jax's python callback, so its programs are compiled in "
              f"every process, never cached ({reason})", file=sys.stderr)
    return reason is None


def _lower_ffi(ctx, *args, callback, result_avals, vmap_method):
    """CPU: the custom call xla_ffi.TARGET with attributes key (key_of(callback)) and site (its place in the
    program); the program keeps callback alive (a keepalive of the executable) so that its key stays live while
    the program is held, and hold() while it may still be running after it was dropped. Without the FFI handler:
    _lower_callback."""
    if not ffi_available():
        return _lower_callback(ctx, *args, callback=callback, result_avals=result_avals, vmap_method=vmap_method)
    ctx.module_context.add_keepalive(callback)
    site = len(ctx.module_context.keepalives)
    op = ffi.build_ffi_lowering_function(xla_ffi.TARGET, has_side_effect=False)(
        ctx, *args, key=np.int64(key_of(callback)), site=np.int64(site))
    sharding = _sharding(ctx)
    if sharding is not None:
        mlir.set_sharding(ctx.module_context, op, sharding)
    return op.results


def _lower_callback(ctx, *args, callback, result_avals, vmap_method):
    """Other platforms, and CPU without the FFI handler: jax's python callback (the program is never cached)."""
    del result_avals, vmap_method
    results, _, _ = jax_callback.emit_python_callback(ctx, callback, None, list(args), ctx.avals_in, ctx.avals_out,
                                                      has_side_effect=False, returns_token=False, sharding=_sharding(ctx))
    return results


host_call_p.def_impl(functools.partial(dispatch.apply_primitive, host_call_p))
ad.primitive_jvps[host_call_p] = _no_derivatives
ad.primitive_transposes[host_call_p] = _no_derivatives
batching.primitive_batchers[host_call_p] = functools.partial(ffi.ffi_batching_rule, host_call_p)
mlir.register_lowering(host_call_p, _lower_callback, cacheable=False)
mlir.register_lowering(host_call_p, _lower_ffi, platform="cpu", cacheable=False)
