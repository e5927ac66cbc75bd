"""Verify committed controllers: `.venv/bin/python experiments/verify/run.py [--full] [--certify] [--seeds 0-4]
[--only mlp-,...] [GROUP ...]` (default: every group, every controller).

Each controller goes through the same analyses as `python -m gsa_jax.verify CONTROLLER --quick` (the quick budget,
equal for every controller; --full: the default budget, `python -m gsa_jax.verify CONTROLLER`), one after another in
this process, and its verify.json, report.md and verify.png go to results/<group>/<controller name>/
(results/full/<group>/... with --full; results/certified/<group>/... with --certify, which adds `gsa verify
--certify`'s certificates at the quick budget). A controller whose verify.json exists is skipped (the run resumes).
"""

import argparse
import glob
import os
import time

from gsa_jax.verify import certify
from gsa_jax.verify.analysis import QUICK, Budget, verify
from gsa_jax.verify.report import write_all
from gsa_jax.verify.system import VerifyError, load_system

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
FIG1 = "experiments/fig1_v5/results/fig1_v5_{0}/controllers/{0}-{1}-s{2}.npz"
ATLAS = "experiments/atlas_dmc/results/{0}/{1}/controllers/dmc.{0}-{2}-s*.npz"
REACHER = "experiments/your_task_reacher/results/controllers/examples.reacher.Reacher-{0}-s*.npz"
# group -> controller globs: flat PPO and every committed K of the task
GROUPS = {
    "InvertedDoublePendulum-v5": [FIG1.format("InvertedDoublePendulum-v5", "mlp", "*")]
    + [FIG1.format("InvertedDoublePendulum-v5", f"mixture-K{k}", "*") for k in (1, 2, 4)],
    "cartpole-balance": [ATLAS.format("cartpole-balance", "flat_ppo", "mlp")]
    + [ATLAS.format("cartpole-balance", "mixture", f"mixture-K{k}") for k in (1, 2, 4)],
    "pendulum-swingup": [ATLAS.format("pendulum-swingup", "flat_ppo", "mlp")]
    + [ATLAS.format("pendulum-swingup", "mixture", f"mixture-K{k}") for k in (1, 2, 4)],
    "Hopper-v5": [FIG1.format("Hopper-v5", "mlp", "*")] + [FIG1.format("Hopper-v5", f"mixture-K{k}", "*") for k in (2, 3, 6, 12)],
    "reacher": [REACHER.format("mlp")] + [REACHER.format(f"mixture-K{k}") for k in (1, 2, 4, 8)],
    # the atlas's LQR as a controller file (lqr_controller.py writes it)
    "cartpole-balance-lqr": ["experiments/verify/results/certified/lqr/dmc.cartpole-balance-lqr.npz"],
}


def controllers(group, seeds=None, only=None):
    """The group's controller paths, of the seeds given and with one of the `only` strings in their names."""
    paths = [p for g in GROUPS[group] for p in sorted(glob.glob(os.path.join(ROOT, g)))]
    return [p for p in paths if (seeds is None or seed_of(p) is None or seed_of(p) in seeds)
            and (only is None or any(o in os.path.basename(p) for o in only))]


def seed_of(path):
    """The seed of a controller named ...-s<seed>.npz; None for one without (the LQR controller)."""
    tail = os.path.splitext(os.path.basename(path))[0].rsplit("-s", 1)
    return int(tail[1]) if len(tail) == 2 and tail[1].isdigit() else None


def run_group(group, full=False, seeds=None, only=None, certified=False):
    budget = Budget() if full else QUICK
    cert_budget = (certify.CertifyBudget() if full else certify.QUICK) if certified else None
    where = (("full",) if full else ()) + (("certified",) if certified else ())
    for path in controllers(group, seeds, only):
        out = os.path.join(HERE, "results", *where, group, os.path.splitext(os.path.basename(path))[0])
        if os.path.exists(os.path.join(out, "verify.json")):
            continue
        t0 = time.perf_counter()
        system = load_system(os.path.relpath(path, ROOT))
        try:
            result = verify(system, budget, None, cert_budget)
        except VerifyError as e:  # nothing to certify: the rest of the analysis, with the reason recorded
            result = {**verify(system, budget), "certify_refused": str(e)}
        write_all(out, system, result, budget, quick=not full)
        print(f"{group}: {os.path.basename(path)} {time.perf_counter() - t0:.0f} s", flush=True)


def seed_range(text):
    lo, _, hi = text.partition("-")
    return set(range(int(lo), int(hi or lo) + 1))


if __name__ == "__main__":
    os.chdir(ROOT)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("groups", nargs="*", metavar="GROUP", help=f"default: all of {', '.join(GROUPS)}")
    p.add_argument("--full", action="store_true", help="the default budget instead of --quick's (results/full/)")
    p.add_argument("--certify", action="store_true", help="add the certificates (results/certified/)")
    p.add_argument("--seeds", type=seed_range, default=None, help="a seed range, e.g. 0-4 (default: every seed)")
    p.add_argument("--only", type=lambda t: t.split(","), default=None,
                   help="comma-separated parts of controller names to keep, e.g. mlp-,mixture-K4-")
    args = p.parse_args()
    if set(args.groups) - set(GROUPS):
        p.error(f"unknown group(s) {', '.join(sorted(set(args.groups) - set(GROUPS)))}; choose from {', '.join(GROUPS)}")
    for g in args.groups or list(GROUPS):
        run_group(g, args.full, args.seeds, args.only, args.certify)
