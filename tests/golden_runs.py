"""The fixed runs' references, checked on every host: a refactor of the running code must leave what a run
computes unchanged.

Two references per fixed run, in tests/golden/fixed_runs.json:

- exact fingerprints, per host family: the sha256 of the run's metrics table (without wall-clock columns) and
  of every array in its parameter and metrics files. Bits are reproducible only within a family (host_key):
  the same jax/jaxlib/mujoco/mujoco-mjx/numpy versions, the same XLA_FLAGS, the same CPU as far as the code
  generation and kernel choice see it: its vector instruction sets (the CPUID flags /proc/cpuinfo lists) and
  its vendor, family and model (LLVM picks the CPU it compiles XLA's kernels for from them; under QEMU, an
  emulated Haswell and an emulated EPYC-Rome, both AVX2 and FMA, give different bits). The instruction sets
  are the host's, not the ones XLA's own code generation is capped to: XLA:CPU runs dots with YNNPACK, which
  picks its kernels from the host's CPUID at run time and ignores --xla_cpu_max_isa, so a fingerprint recorded
  with --xla_cpu_max_isa=AVX2 on an AVX-512 host is not an AVX2 host's (measured: the capped run gives the
  AVX-512 host's bits; the same run under QEMU emulating an AVX2-only EPYC gives others). A family is recorded
  on a host of that family; recording adds it and keeps the other families. MuJoCo C adds nothing
  host-specific: its library is one AVX build (no FMA or AVX-512 instructions, no CPUID dispatch).
- a summary, compared within a relative tolerance (RTOL) on any host: the run's continuous metrics (every
  iteration of every run) and, per parameter array and run, its L2 norm and two fixed projections. How far
  these move between builds and instruction sets, and how far a small deliberate change moves them: RTOL's
  comment.

A host whose family has fingerprints is checked bit for bit and against the summary; any other host against
the summary; the test skips only where the golden file has neither for the run. Discrete metrics (episode and
clip counts, clusters used) are left out of the summary: one comparison near its threshold can flip them by a
whole count on another host while the run is otherwise the same to 1e-6.

Record (on a host of a family not yet recorded, or after a deliberate change of what runs compute; then
commit tests/golden/fixed_runs.json with the reason): the command in RECORD_COMMAND. When a family's
fingerprints of a run change, or the summary no longer holds on the recording host, the other families'
fingerprints of that run are dropped (they describe the old computation) and the summary is recorded anew.
"""

import csv
import hashlib
import json
import math
import os
import platform
import re
import warnings

import numpy as np
import pytest

GOLDEN = os.path.join(os.path.dirname(__file__), "golden", "fixed_runs.json")
WALL_CLOCK = ("wall_s",)
RECORD = os.environ.get("GSA_RECORD_GOLDEN") == "1"
RECORD_COMMAND = ("GSA_RECORD_GOLDEN=1 .venv/bin/python -m pytest -p no:xdist tests/test_train_command.py tests/test_sweep.py "
                  "-k computes_what_it_computed")
# A summary quantity passes where |got - recorded| <= RTOL * its scale (a metric: its largest |value| over
# runs and iterations; a parameter array's norm or projection: that array's norm in that run). Measured on an
# AVX-512 EPYC (jax 0.10.1), largest deviation over the quantities of both fixed runs from the run there:
# --xla_cpu_max_isa=AVX2 0 (the same bits), SSE4_2 1.6e-5, --xla_backend_optimization_level=3 2.3e-5, the
# run under QEMU emulating an AVX2-only EPYC-Rome 2.9e-5 (policy_loss; parameters 5.5e-7). A deliberate small
# change of the training run: 1% larger learning rate 2.0e-2 (13 of 28 quantities beyond RTOL), 1% larger
# clip range 4.8e-3 (policy_loss), another seed 0.89.
RTOL = 1e-3
SUMMARY_METRICS = ("episode_return", "eval_return", "epsilon", "sigma_min", "lr", "policy_loss", "value_loss",
                   "approx_kl", "grad_norm", "partition_entropy")
ISA_FLAGS = ("sse4", "avx", "fma", "f16c", "amx")


def cpu_info():
    """(vector instruction sets, 'vendor family F model M'): the host's CPU as the kernel reports CPUID in
    /proc/cpuinfo (its first processor); ('', '') where there is none. On x86 only the flags code generation
    and kernel choice go by are kept (SSE4, AVX*, FMA, F16C, AMX); elsewhere every flag."""
    if not os.path.exists("/proc/cpuinfo"):
        return "", ""
    fields = {}
    with open("/proc/cpuinfo") as f:
        for line in f:
            if not line.strip():
                break
            name, _, value = line.partition(":")
            fields[name.strip()] = value.strip()
    words = (fields.get("flags") or fields.get("Features") or "").split()
    if fields.get("flags"):
        words = [w for w in words if w.startswith(ISA_FLAGS)]
    model = " ".join(f"{k} {fields[k]}" for k in ("vendor_id", "cpu family", "model", "CPU implementer", "CPU part")
                     if k in fields)
    return " ".join(sorted(words)), model


def host_key():
    """What exact floating-point results depend on: versions, XLA flags, the CPU's vector instruction sets
    and model."""
    import importlib.metadata

    import jax
    import jaxlib
    import mujoco

    try:
        mjx = importlib.metadata.version("mujoco-mjx")
    except importlib.metadata.PackageNotFoundError:
        mjx = ""
    flags, model = cpu_info()
    return {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__, "mujoco_mjx": mjx,
            "numpy": np.__version__, "machine": platform.machine(), "cpu_flags": flags, "cpu": model,
            "xla_flags": " ".join(sorted(os.environ.get("XLA_FLAGS", "").split()))}


def family_id(key):
    """A short name for a host family: machine, widest vector instruction set, a hash of the whole key."""
    flags = key["cpu_flags"].split()
    isa = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), "base")
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:10]
    return f"{key['machine']}-{isa}-{digest}"


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


def _projections(n):
    """Two fixed unit vectors of length n (no random generator: the same on every numpy)."""
    i = np.arange(n, dtype=np.float64)
    v = np.stack([np.cos(0.7 * i + 0.3), np.cos(1.9 * i + 1.1)])
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def summarize(group):
    """The summary of a stored group of runs (a run directory or a sweep's group: metrics.npz and params.npz
    with a run axis first): {"metrics": {column: [[value per iteration] per run]}, "params": {array:
    [[norm, projection 1, projection 2] per run]}}; None for values not computed (an iteration without an
    evaluation)."""
    out = {"metrics": {}, "params": {}}
    with np.load(os.path.join(group, "metrics.npz")) as m:
        for col in SUMMARY_METRICS:
            a = np.asarray(m[col], np.float64)
            out["metrics"][col] = [[None if math.isnan(v) else float(v) for v in row] for row in a]
    with np.load(os.path.join(group, "params.npz")) as p:
        for name in sorted(n for n in p.files if not n.startswith("meta/")):
            a = np.asarray(p[name])
            if a.dtype.kind != "f":
                continue
            flat = a.reshape(a.shape[0], -1).astype(np.float64)
            proj = flat @ _projections(flat.shape[1]).T
            out["params"][name] = [[float(np.linalg.norm(r)), *map(float, pr)] for r, pr in zip(flat, proj)]
    return out


def summary_deviations(got, ref):
    """{quantity: largest |got - ref| / scale} (the scales in RTOL's comment); inf where a quantity is missing,
    its shape differs, or a value is computed in one and not in the other."""
    dev = {}
    for part in ("metrics", "params"):
        for name, r in ref[part].items():
            g = got[part].get(name)
            key = f"{part}/{name}"
            rr = np.array(r, dtype=np.float64)  # None -> nan
            gg = np.array(g, dtype=np.float64) if g is not None else None
            if gg is None or gg.shape != rr.shape or not np.array_equal(np.isnan(gg), np.isnan(rr)):
                dev[key] = math.inf
                continue
            scale = np.max(np.abs(rr), where=~np.isnan(rr), initial=0.0) if part == "metrics" else rr[:, :1]
            diff = np.where(np.isnan(rr), 0.0, np.abs(gg - rr))
            dev[key] = float(np.max(diff / np.maximum(scale, 1e-30), initial=0.0))
    for part in ("metrics", "params"):
        for name in set(got[part]) - set(ref[part]):
            dev[f"{part}/{name}"] = math.inf
    return dev


def _beyond(dev):
    return {k: v for k, v in sorted(dev.items(), key=lambda kv: -kv[1]) if v > RTOL}


def load_golden():
    if not os.path.exists(GOLDEN):
        return {"families": {}, "summaries": {}}
    with open(GOLDEN) as f:
        golden = json.load(f)
    return {"families": golden.get("families", {}), "summaries": golden.get("summaries", {})}


def record(name, fingerprint, summary, key=None):
    """Write run `name`'s fingerprints for this host family, keeping the other families; when this family's
    fingerprints changed, or there is no summary, or the summary no longer holds: the summary anew, and the
    other families' fingerprints of the run dropped. Returns what was done, in words."""
    key = key or host_key()
    fam = family_id(key)
    golden = load_golden()
    families, summaries = golden["families"], golden["summaries"]
    old = families.get(fam, {}).get("fingerprints", {}).get(name)
    ref = summaries.get(name)
    changed = old is not None and old != fingerprint
    stale = ref is None or bool(_beyond(summary_deviations(summary, ref)))
    done = []
    if changed or stale:
        for other, entry in families.items():
            if other != fam and entry.get("fingerprints", {}).pop(name, None) is not None:
                done.append(f"dropped {other}'s fingerprints of {name}")
        summaries[name] = {"recorded_in": fam, **summary}
        done.append(f"recorded the summary of {name}")
    families.setdefault(fam, {"host_key": key, "fingerprints": {}})
    families[fam]["host_key"] = key
    families[fam]["fingerprints"][name] = fingerprint
    families = {f: e for f, e in families.items() if e.get("fingerprints")}
    done.append(f"recorded the fingerprints of {name} for {fam}")
    os.makedirs(os.path.dirname(GOLDEN), exist_ok=True)
    about = ("Fixed runs' references (tests/golden_runs.py): exact fingerprints per host family, a summary "
             f"compared within a tolerance on any host. Record: {RECORD_COMMAND}")
    text = json.dumps({"about": about, "families": families, "summaries": summaries}, indent=1, sort_keys=True)
    one_line = re.compile(r"\[\s+([^\[\]\"]*?)\s+\]")  # a list of numbers
    text = one_line.sub(lambda m: "[" + " ".join(m.group(1).split()) + "]", text)
    with open(GOLDEN + ".tmp", "w") as f:
        f.write(text + "\n")
    os.replace(GOLDEN + ".tmp", GOLDEN)
    return "; ".join(done)


def check_fingerprint(name, fingerprint, summary):
    """Check fixed run `name`: its {part: digest} bit for bit against this host family's recorded fingerprints,
    where recorded, and its summary (summarize) within RTOL on every host; GSA_RECORD_GOLDEN=1: record instead."""
    if RECORD:
        print(record(name, fingerprint, summary))
        return
    golden = load_golden()
    fam = family_id(host_key())
    exact = golden["families"].get(fam, {}).get("fingerprints", {}).get(name)
    ref = golden["summaries"].get(name)
    if exact is None and ref is None:
        pytest.skip(f"no reference for fixed run '{name}' in {GOLDEN}; record one: {RECORD_COMMAND}")
    beyond = _beyond(summary_deviations(summary, ref)) if ref is not None else None
    if exact is not None and fingerprint != exact:
        parts = ", ".join(k for k in fingerprint if fingerprint[k] != exact.get(k))
        held = (f"; its summary holds within rtol {RTOL}: where no code changed, this host computes differently "
                "from the family's recording host in a way host_key does not record") if ref and not beyond else ""
        pytest.fail(f"{name}: what the run computes changed, bit for bit on host family {fam} (parts: {parts})"
                    f"{held}; if deliberate: {RECORD_COMMAND}")
    if beyond:
        pytest.fail(f"{name}: what the run computes changed beyond the tolerance of hosts (rtol {RTOL}; largest "
                    "relative deviations: " + ", ".join(f"{k} {v:.2g}" for k, v in list(beyond.items())[:6]) +
                    f"; summary recorded on {ref.get('recorded_in')}, this host is {fam}); if deliberate: "
                    f"{RECORD_COMMAND}")
    if exact is None:
        warnings.warn(f"{name}: checked within rtol {RTOL} only: no exact fingerprints for host family {fam} "
                      f"(tests/golden_runs.py); record them on this host: {RECORD_COMMAND}", stacklevel=2)
