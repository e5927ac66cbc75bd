"""Export a trained run's deterministic controller:
`python -m gsa_jax.export RUN [--format npz|onnx|c] [--out PATH]`.

npz: plain arrays (load with gsa_jax.numpy_policy.load, no JAX needed); onnx: one ONNX graph, obs in,
action and cluster out (gsa_jax.export_onnx; needs the `deploy` extra); c: one C99 header declaring
gsa_act(obs, action, cluster) (gsa_jax.export_c). RUN is a run directory (train, extract) or an
exported controller .npz. The format defaults to the one --out's suffix names (.npz, .onnx, .h).
"""

import argparse
import json
import os
import sys
import zipfile

import numpy as np

from gsa_jax.checkpoint import save_npz_atomic
from gsa_jax.export_c import cost, to_source


class ExportError(Exception):
    pass


def controller_arrays(run_dir):
    """Read config.json + params.npz of a run and return the controller arrays (see numpy_policy)."""
    cfg_path, params_path = os.path.join(run_dir, "config.json"), os.path.join(run_dir, "params.npz")
    if not os.path.isdir(run_dir):
        raise ExportError(f"{run_dir!r} is not a directory")
    for p in (cfg_path, params_path):
        if not os.path.exists(p):
            raise ExportError(f"{run_dir!r} is not a gsa_jax run: {os.path.basename(p)} is missing")
    with open(cfg_path) as f:
        meta = json.load(f)
    kind = meta["config"]["policy"]
    with np.load(params_path) as p:
        arrays = {k: p[k] for k in p.files}
    prefix = "['params']['policy']"
    net = "partition" if kind == "mixture" else "mlp"
    n_layers = 0
    while f"{prefix}['{net}'][{n_layers}]['w']" in arrays:
        n_layers += 1
    out = {
        "kind": np.array(kind),
        "obs_mean": arrays["['obs_stats']['mean']"],
        "obs_var": arrays["['obs_stats']['var']"],
        "obs_clip": np.array(10.0, np.float32),
        "n_layers": np.array(n_layers),
        "config_json": np.array(json.dumps({k: meta[k] for k in ("config", "hparams", "seed", "git_commit") if k in meta})),
    }
    if not meta["config"].get("normalize_obs", True):
        out["obs_mean"] = np.zeros_like(out["obs_mean"])
        out["obs_var"] = np.ones_like(out["obs_var"]) - 1e-8
        out["obs_clip"] = np.array(np.inf, np.float32)
    for i in range(n_layers):
        out[f"w{i}"] = arrays[f"{prefix}['{net}'][{i}]['w']"]
        out[f"b{i}"] = arrays[f"{prefix}['{net}'][{i}]['b']"]
    if kind == "mixture":
        out["subpolicy"] = np.array(meta["config"].get("subpolicy", "linear"))
        k = int(meta["hparams"]["K"])
        out["L"] = arrays[f"{prefix}['L']"][:k]
        out["b"] = arrays[f"{prefix}['b']"][:k]
    return out


SUFFIXES = {"npz": ".npz", "onnx": ".onnx", "c": ".h"}


def load_arrays(source):
    """Controller arrays of a run directory or of an exported controller .npz."""
    if os.path.isfile(source) and source.endswith(".npz"):
        if not zipfile.is_zipfile(source):
            raise ExportError(f"{source!r} is not an exported controller (not an .npz archive)")
        try:
            with np.load(source, allow_pickle=False) as f:
                arrays = {k: f[k] for k in f.files}
        except (OSError, ValueError) as e:
            raise ExportError(f"{source!r} is not an exported controller ({e})") from None
        if "kind" not in arrays or "obs_mean" not in arrays:
            raise ExportError(f"{source!r} is not an exported controller (no 'kind' / 'obs_mean' arrays)")
        return arrays
    return controller_arrays(source)


def pick_format(fmt, out):
    """(format, path): --format, else the format --out's suffix names, else npz."""
    if fmt is None:
        fmt = next((f for f, s in SUFFIXES.items() if out and out.endswith(s)), "npz")
    return fmt, out or f"controller{SUFFIXES[fmt]}"


def task_layout(arrays):
    """The task's observation layout (names), or None for an unknown task."""
    try:
        env = json.loads(str(arrays["config_json"]))["config"]["env"]
        from envs.mujoco_c import observation_layout

        layout = observation_layout(env)
    except (KeyError, ValueError, json.JSONDecodeError):
        return None
    return layout if len(layout) == np.asarray(arrays["obs_mean"]).shape[0] else None


def write(arrays, fmt, out):
    """Write the controller in `fmt`; returns the lines to print."""
    from gsa_jax.checkpoint import write_atomic

    if fmt == "npz":
        save_npz_atomic(out, **arrays)
        return []
    layout = task_layout(arrays)
    if fmt == "onnx":
        try:
            from gsa_jax.export_onnx import to_bytes
        except ImportError as e:  # pragma: no cover - depends on the install
            raise ExportError(f"ONNX export needs the deploy extra: pip install 'gsa_jax[deploy]' ({e})") from None
        write_atomic(out, to_bytes(arrays, layout), "wb")
        return []
    write_atomic(out, to_source(arrays, layout))
    c = cost(arrays)
    return [f"C controller: {c['constants']} float constants ({c['bytes'] / 1024:.1f} KiB); per call "
            f"{c['multiply_adds']} multiply-adds, {c['tanh']} tanhf, {c['compares']} compares"]


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.export", description=__doc__.split("\n")[1])
    p.add_argument("run_dir", metavar="RUN", help="a run directory (train, extract) or an exported controller .npz")
    p.add_argument("--format", choices=sorted(SUFFIXES), default=None,
                   help="npz (NumPy arrays), onnx (one ONNX graph), c (a C99 header); default: from --out's suffix, else npz")
    p.add_argument("--out", default=None, help="output file (default: controller.npz / .onnx / .h)")
    args = p.parse_args(argv)
    fmt, out = pick_format(args.format, args.out)
    try:
        arrays = load_arrays(args.run_dir)
        if not os.path.isdir(os.path.dirname(os.path.abspath(out))):
            raise ExportError(f"the directory of --out {out!r} does not exist")
        lines = write(arrays, fmt, out)
    except ExportError as e:
        print(f"gsa_jax.export: error: {e}", file=sys.stderr)
        return 2
    k = arrays["L"].shape[0] if "L" in arrays else None
    sub = str(arrays["subpolicy"]) if "subpolicy" in arrays else "linear"
    print(f"wrote {out} ({fmt}): {arrays['kind']} controller" + (f" with {k} {sub} pieces" if k else ""))
    for line in lines:
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
