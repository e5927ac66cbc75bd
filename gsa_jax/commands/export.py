"""Export a trained run's deterministic controller as npz, ONNX or a C header (`gsa export RUN [--format
npz|onnx|c] [--out PATH]`).

npz: plain arrays (load with gsa_jax.deployment.numpy_policy.load, no JAX needed); onnx: one ONNX graph, obs in,
action, cluster and raw_action out (gsa_jax.deployment.export_onnx; needs the `deploy` extra); c: one C99 header
declaring gsa_act(obs, action, cluster) and gsa_act_raw (gsa_jax.deployment.export_c). Each carries the task's
action bounds, and its action is inside them. RUN is a run directory (train, extract) or an exported controller
.npz. The format defaults to the one --out's suffix names (.npz, .onnx, .h).
"""

import argparse

from gsa_jax.algorithm import partitions, subpolicies
from gsa_jax.commands.command_line import check_output, command_parser
from gsa_jax.errors import run_command
from gsa_jax.deployment.exporting import SUFFIXES, ExportError, load_arrays, write


def pick_format(fmt: str | None, out: str | None) -> tuple:
    """(format, path): --format, else the format --out's suffix names (an unknown suffix is an ExportError),
    else npz."""
    if fmt is None and out is not None:
        fmt = next((f for f, s in SUFFIXES.items() if out.endswith(s)), None)
        if fmt is None:
            suffixes = ", ".join(f"{s} ({f})" for f, s in sorted(SUFFIXES.items()))
            raise ExportError(f"--out {out!r}: unknown suffix; name the format with --format or end --out with {suffixes}")
    fmt = fmt or "npz"
    return fmt, out or f"controller{SUFFIXES[fmt]}"


def build_parser() -> argparse.ArgumentParser:
    """`gsa export`'s options."""
    p = command_parser("export", __doc__)
    p.add_argument("run_dir", metavar="RUN", help="a run directory (train, extract) or an exported controller .npz")
    p.add_argument("--format", choices=sorted(SUFFIXES), default=None,
                   help="npz (NumPy arrays), onnx (one ONNX graph), c (a C99 header); default: from --out's suffix, else npz")
    p.add_argument("--out", default=None, help="output file (default: controller.npz / .onnx / .h)")
    return p


def export_controller(argv: list | None) -> int:
    """Write the controller in its format and print what was written."""
    args = build_parser().parse_args(argv)
    fmt, out = pick_format(args.format, args.out)
    arrays = load_arrays(args.run_dir)
    check_output(out, "--out")  # the default name too
    lines = write(arrays, fmt, out)
    k = arrays["L"].shape[0] if "L" in arrays else None
    sub = str(arrays["subpolicy"]) if "subpolicy" in arrays else subpolicies.DEFAULT
    part = str(arrays["partition"]) if "partition" in arrays else partitions.DEFAULT
    pieces = f" with one {sub} piece (no partition)" if k == 1 else f" with {k} {sub} pieces" if k else ""
    print(f"wrote {out} ({fmt}): {arrays['kind']} controller" + pieces
          + (f", {part} partition" if k and k > 1 and part != partitions.DEFAULT else ""))
    for line in lines:
        print(line)
    return 0


def main(argv: list | None = None) -> int:
    """`gsa export`: exit status 0, or 2 on bad input."""
    return run_command("export", lambda: export_controller(argv))
