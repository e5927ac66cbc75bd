"""Export a trained run's deterministic controller as plain arrays:
`python -m gsa_jax.export <run dir> --out controller.npz` (load with gsa_jax.numpy_policy.load)."""

import argparse
import json
import os
import sys

import numpy as np

from gsa_jax.checkpoint import save_npz_atomic


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
        "config_json": np.array(json.dumps({k: meta[k] for k in ("config", "hparams", "seed") if k in meta})),
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


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.export", description=__doc__.split("\n")[0])
    p.add_argument("run_dir")
    p.add_argument("--out", default="controller.npz")
    args = p.parse_args(argv)
    try:
        arrays = controller_arrays(args.run_dir)
    except ExportError as e:
        print(f"gsa_jax.export: error: {e}", file=sys.stderr)
        return 2
    save_npz_atomic(args.out, **arrays)
    k = arrays["L"].shape[0] if "L" in arrays else None
    print(f"wrote {args.out}: {arrays['kind']} controller" + (f" with {k} {arrays['subpolicy']} pieces" if k else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
