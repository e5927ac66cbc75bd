"""Fingerprints of fixed runs, recorded once and compared bit for bit: a refactor of the running code must
leave what a run computes unchanged (the same metrics and parameters, to the bit).

A fingerprint is the sha256 of a run's metrics table (without wall-clock columns) and of every array in its
parameter files. It is exact only for the same compiler and host instruction set, so the golden file records
those (host_key) and a test on another host or jax/mujoco version skips, naming the difference.
Record after a deliberate change of what runs compute: GSA_RECORD_GOLDEN=1 make test (then commit
tests/golden/fixed_runs.json with the reason).
"""

import csv
import hashlib
import json
import os
import platform

import numpy as np
import pytest

GOLDEN = os.path.join(os.path.dirname(__file__), "golden", "fixed_runs.json")
WALL_CLOCK = ("wall_s",)
RECORD = os.environ.get("GSA_RECORD_GOLDEN") == "1"


def host_key():
    """What exact floating-point results depend on: versions, XLA flags, the CPU's vector instruction sets."""
    import jax
    import jaxlib
    import mujoco

    flags = ""
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as f:
            words = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
        flags = " ".join(sorted(w for w in words if w.startswith(("avx", "fma", "sse4", "amx"))))
    return {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__, "numpy": np.__version__,
            "machine": platform.machine(), "cpu_flags": flags, "xla_flags": os.environ.get("XLA_FLAGS", "")}


def table_digest(path):
    """sha256 of a metrics CSV's rows, wall-clock columns dropped, columns in file order."""
    h = hashlib.sha256()
    with open(path) as f:
        for row in csv.DictReader(f):
            h.update(json.dumps([(k, v) for k, v in row.items() if k not in WALL_CLOCK]).encode())
    return h.hexdigest()


def arrays_digest(path, run=None):
    """sha256 of every array in an .npz (name, dtype, shape, bytes), in name order; 'meta/' entries (the run's
    config record: paths, command line) and wall-clock arrays are not what it computes and are left out. run:
    digest that run's row of every array (a run axis first)."""
    h = hashlib.sha256()
    with np.load(path) as f:
        for name in sorted(n for n in f.files if not n.startswith("meta/") and n not in WALL_CLOCK):
            a = np.ascontiguousarray(f[name] if run is None else f[name][run])
            h.update(f"{name}|{a.dtype.str}|{a.shape}".encode())
            h.update(a.tobytes())
    return h.hexdigest()


def check_fingerprint(name, fingerprint):
    """Compare {part: digest} with the golden file's entry `name` (GSA_RECORD_GOLDEN=1: write it instead)."""
    golden = {}
    if os.path.exists(GOLDEN):
        with open(GOLDEN) as f:
            golden = json.load(f)
    key = host_key()
    if RECORD:
        if golden.get("host_key", key) != key:
            golden = {}
        golden = {**golden, "host_key": key, name: fingerprint}
        os.makedirs(os.path.dirname(GOLDEN), exist_ok=True)
        with open(GOLDEN, "w") as f:
            json.dump(golden, f, indent=1, sort_keys=True)
        return
    if name not in golden:
        pytest.fail(f"no golden fingerprint '{name}' in {GOLDEN}; record it: GSA_RECORD_GOLDEN=1 pytest {__file__}")
    differs = {k: (golden["host_key"].get(k), v) for k, v in key.items() if golden["host_key"].get(k) != v}
    if differs:
        pytest.skip(f"golden fingerprints were recorded on another host or version: {differs}")
    assert fingerprint == golden[name], f"{name}: what the run computes changed (parts: " + ", ".join(
        k for k in fingerprint if fingerprint[k] != golden[name].get(k)) + ")"
