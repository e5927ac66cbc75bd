"""Check an exported controller's closed loop in its task's MuJoCo C twin.

    gsa verify CONTROLLER.npz [--out DIR] [--quick] [--seed N] [--certify] [--force]
    gsa verify CONTROLLER.npz --pwa VERIFY_JSON [--out DIR]

Writes DIR/verify.json (docs/verify.md), DIR/report.md and DIR/verify.png: fixed points and closed-loop eigenvalues
per piece, the region of attraction of the task's equilibrium (with an LQR beside it), the lowest-return start
states and pushes a cross-entropy search finds (replayable), and how the controller switches pieces. --certify adds
a certified region of attraction of the closed loop's stable fixed point and, for a hold kept by switching between
pieces, an invariant set around it: exact on the linearization, tested on the plant (the optional extra verify:
pip install 'gsa_jax[verify]'). A controller whose task's definition changed since it was trained is refused in one
line, as deploy refuses it (--force verifies it where the sizes agree). --pwa hands a linear-partition controller's
certificate (its verify.json) to the field's verifiers: DIR/pwa/ holds the piecewise-affine closed loop, an ONNX graph
with VNN-LIB properties of the certificate's decrease and a mixed-integer bound (HiGHS), each checked on the same
points (gsa_jax.verify.pwa_export).
"""

import argparse
import os
import time
from typing import TYPE_CHECKING

from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command

if TYPE_CHECKING:  # gsa_jax.verify loads MuJoCo and SciPy: imported where used, so `gsa verify --help` loads neither
    from gsa_jax.verify.analysis import LqrWeights
    from gsa_jax.verify.system import System


def parse_weights(text: str, flag: str) -> tuple:
    """Comma-separated numbers of --lqr-q / --lqr-r; VerifyError names the flag."""
    from gsa_jax.verify.system import VerifyError

    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise VerifyError(f"{flag} takes comma-separated numbers, got {text!r}") from None


def lqr_weights_of(args: argparse.Namespace, system: "System") -> "LqrWeights | None":
    """The LQR's weights of --lqr-q / --lqr-r (both or neither), checked against the task: q one per tangent
    state coordinate (2 nv) and >= 0, r one per action and > 0."""
    from gsa_jax.verify.analysis import LqrWeights
    from gsa_jax.verify.system import VerifyError, equilibrium_guess

    if args.lqr_q is None and args.lqr_r is None:
        return None
    if args.lqr_q is None or args.lqr_r is None:
        raise VerifyError("--lqr-q and --lqr-r go together (the state and the action weights)")
    if equilibrium_guess(system.task) is None:
        raise VerifyError(f"{system.env!r} declares no equilibrium (Task.equilibrium_qpos): no LQR to weight")
    q, r = parse_weights(args.lqr_q, "--lqr-q"), parse_weights(args.lqr_r, "--lqr-r")
    n, d_a = 2 * system.task.model.nv, system.ctrl.action_size
    if len(q) != n or min(q) < 0:
        raise VerifyError(f"--lqr-q needs {n} weights >= 0 (qpos's {n // 2} tangent coordinates, then qvel's), got {len(q)}: {args.lqr_q}")
    if len(r) != d_a or min(r) <= 0:
        raise VerifyError(f"--lqr-r needs {d_a} weights > 0 (one per action), got {len(r)}: {args.lqr_r}")
    return LqrWeights(q, r)


def build_parser() -> argparse.ArgumentParser:
    """`gsa verify`'s options."""
    p = command_parser("verify", __doc__)
    p.add_argument("controller", help="an exported controller .npz (gsa export)")
    p.add_argument("--out", default=None, help="output folder (default: verify_<controller name>)")
    p.add_argument("--quick", action="store_true", help="a small budget (under 2 minutes on 2 cores)")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the searches and samples; nominal episode i starts from seed 10000 + N + i (default "
                        "%(default)s: its first 10 are the selection starts `gsa score` and `gsa deploy` score)")
    p.add_argument("--lqr-q", default=None, metavar="Q1,...", help="the LQR beside the controller weights the tangent "
                   "state by these (the task's units: positions, then velocities; default: Q = I on scaled states)")
    p.add_argument("--lqr-r", default=None, metavar="R1,...", help="... and the actions by these (default R = I)")
    p.add_argument("--certify", action="store_true", help="a certified region of attraction of the closed loop's "
                   "stable fixed point, and an invariant set of a hold kept by switching between pieces (needs the "
                   "optional extra verify: pip install 'gsa_jax[verify]')")
    p.add_argument("--pwa", default=None, metavar="VERIFY_JSON",
                   help="instead of the analyses: export this controller's certificate (a verify.json written by "
                        "--certify) as a piecewise-affine model, ONNX + VNN-LIB and a mixed-integer bound into DIR/pwa/")
    p.add_argument("--force", action="store_true",
                   help="verify a controller whose task's definition changed since it was trained, or that names "
                        "another task, where the observation sizes agree")
    return p


def verify_controller(argv: list | None) -> int:
    """Analyse the controller and write the report."""
    args = build_parser().parse_args(argv)
    from gsa_jax.verify import certify
    from gsa_jax.verify.analysis import QUICK, Budget, verify
    from gsa_jax.verify.report import certificate_lines, hold_set_lines, write_all
    from gsa_jax.verify.system import load_system

    if args.certify:
        certify.require_solver()
    system = load_system(args.controller, args.force)
    out = args.out or f"verify_{os.path.splitext(os.path.basename(args.controller))[0]}"
    if args.pwa:
        return export_pwa_files(system, args.pwa, out)
    weights = lqr_weights_of(args, system)
    budget = (QUICK if args.quick else Budget())._replace(seed=args.seed)
    cert_budget = (certify.QUICK if args.quick else certify.CertifyBudget())._replace(seed=args.seed)
    t0 = time.perf_counter()
    result = verify(system, budget, weights, cert_budget if args.certify else None)
    doc = write_all(out, system, result, budget, args.quick)
    if "certificate" in doc:
        print("\n".join(["Certified region of attraction.", *certificate_lines(doc["certificate"])]))
    if "hold_set" in doc:
        print("\n".join(["Invariant set of the hold kept by switching.", *hold_set_lines(doc["hold_set"])]))
    print(f"wrote {out}/verify.json, report.md, verify.png ({time.perf_counter() - t0:.0f} s)")
    return 0


def export_pwa_files(system: "System", cert_path: str, out: str) -> int:
    """Write OUT/pwa/ and print what its checks found."""
    from gsa_jax.verify.pwa_export import export_pwa
    from gsa_jax.verify.report import pwa_lines

    print("\n".join(["The certificate as a piecewise-affine closed loop.", *pwa_lines(export_pwa(system, cert_path, out))]))
    print(f"wrote {out}/pwa/: pwa.json, certificate.onnx, decrease.vnnlib, cells.vnnlib (where it has cells), checks.json")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa verify`: exit status 0, or 2 on bad input."""
    return run_command("verify", lambda: verify_controller(argv))
