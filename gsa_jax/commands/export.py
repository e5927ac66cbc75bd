"""Export a trained run's deterministic controller:
`python -m gsa_jax.export RUN [--format npz|onnx|c] [--out PATH]`.

npz: plain arrays (load with gsa_jax.deployment.numpy_policy.load, no JAX needed); onnx: one ONNX graph, obs in,
action, cluster and raw_action out (gsa_jax.deployment.export_onnx; needs the `deploy` extra); c: one C99 header
declaring gsa_act(obs, action, cluster) and gsa_act_raw (gsa_jax.deployment.export_c). Each carries the task's
action bounds, and its action is inside them. RUN is a run directory (train, extract) or an exported controller
.npz. The format defaults to the one --out's suffix names (.npz, .onnx, .h).
"""

import argparse
import os
import sys

from gsa_jax.deployment.exporting import SUFFIXES, ExportError, load_arrays, write
from gsa_jax.running.runinfo import cli_description


def pick_format(fmt, out):
    """(format, path): --format, else the format --out's suffix names, else npz."""
    if fmt is None:
        fmt = next((f for f, s in SUFFIXES.items() if out and out.endswith(s)), "npz")
    return fmt, out or f"controller{SUFFIXES[fmt]}"


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.export", description=cli_description(__doc__))
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
