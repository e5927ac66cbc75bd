"""A Python function as an XLA:CPU FFI target, through a small C handler (envs/host_trampoline.c).

    reason = register(handle)     # once per process; None, or why no handler could be built
    # then custom calls to TARGET (api_version 4) with an int64 attribute `key` run handle

handle(key, args, rets) gets the call's `key`, args [read-only NumPy views of the operands] and rets [writable
NumPy views of the results, to be filled]; the views are XLA's buffers, valid during the call only. An exception
becomes the call's error (its message "ExceptionType: text"), raised to the program's caller.

A program holds only the target's name and attributes, so unlike jax's python callbacks it can be written to and
loaded from JAX's persistent compilation cache. The handler is compiled on first use with the system's C compiler
($CC, else cc) against jaxlib's FFI header and kept in $XDG_CACHE_HOME/gsa_jax/ffi (default ~/.cache/gsa_jax/ffi),
one library per source, header and machine. ctypes takes the GIL for each call, from whichever thread XLA runs it on.
"""

import ctypes
import hashlib
import math
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
import threading
from typing import Callable

import jax
import numpy as np

TARGET = "gsa_host_call"
SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "host_trampoline.c")
DTYPES = {1: np.bool_, 2: np.int8, 3: np.int16, 4: np.int32, 5: np.int64, 6: np.uint8, 7: np.uint16, 8: np.uint32,
          9: np.uint64, 10: np.float16, 11: np.float32, 12: np.float64, 15: np.complex64, 18: np.complex128}
DTYPES = {k: np.dtype(v) for k, v in DTYPES.items()}  # XLA_FFI_DataType -> NumPy dtype
Dispatch = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(ctypes.c_int64))  # descriptor -> error message or NULL


def cache_dir() -> str:
    """Where the compiled handler is kept: $XDG_CACHE_HOME/gsa_jax/ffi (default ~/.cache/gsa_jax/ffi)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "gsa_jax", "ffi")


def _header_dir() -> str:
    return jax.ffi.include_dir()


def build() -> str:
    """The path of the compiled handler library, compiled now if this source, header and machine have none yet.
    Raises OSError where it cannot be built."""
    with open(SOURCE, "rb") as f:
        source = f.read()
    with open(os.path.join(_header_dir(), "xla", "ffi", "api", "c_api.h"), "rb") as f:
        header = f.read()
    tag = hashlib.sha256(source + header + platform.machine().encode()).hexdigest()[:16]
    path = os.path.join(cache_dir(), f"host_trampoline-{tag}.so")
    if os.path.exists(path):
        return path
    compiler = shlex.split(os.environ.get("CC", "")) or [shutil.which("cc")]
    if not compiler[0]:
        raise OSError("no C compiler (cc, or $CC)")
    os.makedirs(cache_dir(), exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=cache_dir())
    os.close(fd)
    try:
        done = subprocess.run([*compiler, "-O2", "-shared", "-fPIC", "-I", _header_dir(), SOURCE, "-o", tmp],
                              capture_output=True, text=True, timeout=120)
        if done.returncode != 0:
            raise OSError(f"{compiler[0]} failed: {(done.stderr.strip().splitlines() or [''])[0]}")
        os.replace(tmp, path)  # atomic: processes building at once each write their own file
    except subprocess.TimeoutExpired as e:
        raise OSError(f"{compiler[0]} took over {e.timeout:.0f} s") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def views(words: list, start: int, count: int, writable: bool) -> tuple:
    """(count NumPy views of the buffers described from words[start], the index after them): per buffer its data
    address, XLA_FFI_DataType, rank and dims."""
    out = []
    for _ in range(count):
        data, code, rank = words[start: start + 3]
        shape, dtype = tuple(words[start + 3: start + 3 + rank]), DTYPES[code]
        nbytes = dtype.itemsize * math.prod(shape)
        array = (np.frombuffer((ctypes.c_char * nbytes).from_address(data), dtype).reshape(shape) if nbytes
                 else np.zeros(shape, dtype))
        array.flags.writeable = writable
        out.append(array)
        start += 3 + rank
    return out, start


def make_dispatch(handle: Callable) -> Dispatch:
    """The C-callable dispatch around handle(key, args, rets): NULL, or the address of its error message (kept
    alive per thread until that thread's next error; the handler copies it at once). The messages are kept by thread
    id, not in a threading.local: XLA's threads are not Python's, and a foreign thread's locals go with the thread
    state ctypes makes for one call and drops on return, before XLA reads the message."""
    errors, lock = {}, threading.Lock()

    def call(descriptor):
        try:
            words = descriptor[: descriptor[0]]
            args, end = views(words, 4, words[2], False)
            rets, _ = views(words, end, words[3], True)
            handle(words[1], args, rets)
            return None
        except BaseException as e:  # noqa: BLE001 -- any failure is the call's error, never an unwinding into XLA
            message = ctypes.create_string_buffer(f"{type(e).__name__}: {e}".encode(errors="replace"))
            with lock:
                errors[threading.get_ident()] = message
            return ctypes.addressof(message)

    return Dispatch(call)


_REGISTERED = []  # (library, dispatch) once registered: kept alive, XLA holds only their function pointers


def register(handle: Callable) -> "str | None":
    """Register handle(key, args, rets) as the XLA:CPU FFI target TARGET, once per process. Returns None, or why
    the handler library could not be built or loaded (then nothing is registered)."""
    if _REGISTERED:
        return None
    try:
        library = ctypes.CDLL(build())
    except OSError as e:
        return str(e).splitlines()[0]
    dispatch = make_dispatch(handle)
    library.gsa_set_dispatch.argtypes = [Dispatch]
    library.gsa_set_dispatch(dispatch)
    jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(library.gsa_host_call), platform="cpu", api_version=1)
    _REGISTERED.append((library, dispatch))
    return None
