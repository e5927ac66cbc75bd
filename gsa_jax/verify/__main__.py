"""Check an exported controller's closed loop in its task's MuJoCo C twin:

    python -m gsa_jax.verify CONTROLLER.npz [--out DIR] [--quick] [--seed N]

Writes DIR/verify.json (docs/verify.md), DIR/report.md and DIR/verify.png: fixed points and closed-loop eigenvalues
per piece, the region of attraction of the task's equilibrium (with an LQR beside it), the lowest-return start
states and pushes a cross-entropy search finds (replayable), and how the controller switches pieces.
"""

import argparse
import os
import sys
import time

from gsa_jax.verify.analysis import QUICK, Budget, verify
from gsa_jax.verify.report import write_all
from gsa_jax.verify.system import VerifyError, load_system


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m gsa_jax.verify", description=__doc__.split("\n")[0])
    p.add_argument("controller", help="an exported controller .npz (python -m gsa_jax.export)")
    p.add_argument("--out", default=None, help="output folder (default: verify_<controller name>)")
    p.add_argument("--quick", action="store_true", help="a small budget (under 2 minutes on 2 cores)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:
        system = load_system(args.controller)
    except VerifyError as e:
        print(f"gsa_jax.verify: error: {e}", file=sys.stderr)
        return 2
    budget = (QUICK if args.quick else Budget())._replace(seed=args.seed)
    out = args.out or f"verify_{os.path.splitext(os.path.basename(args.controller))[0]}"
    t0 = time.perf_counter()
    result = verify(system, budget)
    write_all(out, system, result, budget, args.quick)
    print(f"wrote {out}/verify.json, report.md, verify.png ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
