"""host_call: a pure host function called from inside a compiled program, NumPy arrays in and out.

    outs = host_call(fn, (jax.ShapeDtypeStruct(...), ...), *args)    # like jax.pure_callback(..., vmap_method="broadcast_all")

jax.pure_callback hands its function JAX arrays: every call device_puts each argument and converts every
result, several times this module's cost per call (measured in experiments/bench_c_backend/host_call_overhead.py).
Backend 'c' makes one such call per env step of a whole sub-batch, so the difference is a share of the physics time. host_call is the same XLA custom call (jax's
emit_python_callback, with pure_callback's sharding rule and its broadcast_all batching rule) with fn
called on the NumPy views XLA passes. fn must not keep its arguments (they are XLA's buffers) and must
return arrays of exactly the declared shapes and dtypes (checked on every call, as pure_callback does).
No derivatives (as pure_callback). Built on jax 0.10.1's internals (pinned in pyproject.toml).
"""

import functools

from jax._src import callback as jax_callback
from jax._src import core, dispatch, ffi
from jax._src.interpreters import ad, batching, mlir

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


def _lower(ctx, *args, callback, result_avals, vmap_method):
    del result_avals, vmap_method
    sharding = jax_callback._callback_op_sharding(ctx.module_context.axis_context, None, ctx.avals_out)
    results, _, _ = jax_callback.emit_python_callback(ctx, callback, None, list(args), ctx.avals_in, ctx.avals_out,
                                                      has_side_effect=False, returns_token=False, sharding=sharding)
    return results


host_call_p.def_impl(functools.partial(dispatch.apply_primitive, host_call_p))
ad.primitive_jvps[host_call_p] = _no_derivatives
ad.primitive_transposes[host_call_p] = _no_derivatives
batching.primitive_batchers[host_call_p] = functools.partial(ffi.ffi_batching_rule, host_call_p)
mlir.register_lowering(host_call_p, _lower)
