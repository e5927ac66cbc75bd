"""Verify committed controllers: `.venv/bin/python experiments/verify/run.py [GROUP ...]` (default: every group).

Each controller goes through the same analyses as `python -m gsa_jax.verify CONTROLLER --quick` (the quick budget,
equal for every controller), one after another in this process, and its verify.json, report.md and verify.png go to
results/<group>/<controller name>/. A controller whose verify.json exists is skipped (the run resumes).
"""

import glob
import os
import sys
import time

from gsa_jax.verify.analysis import QUICK, verify
from gsa_jax.verify.report import write_all
from gsa_jax.verify.system import load_system

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
FIG1 = "experiments/fig1_v5/results/fig1_v5_{0}/controllers/{0}-{1}-s{2}.npz"
ATLAS = "experiments/atlas_dmc/results/{0}/{1}/controllers/dmc.{0}-{2}-s*.npz"
REACHER = "experiments/your_task_reacher/results/controllers/examples.reacher.Reacher-{0}-s*.npz"
# group -> controller globs: flat PPO against the mixture the task's study found best (or smallest on par); Hopper-v5
# (the slowest, ~100 s a controller here) 5 seeds of each
GROUPS = {
    "InvertedDoublePendulum-v5": [FIG1.format("InvertedDoublePendulum-v5", "mlp", "*"),
                                  FIG1.format("InvertedDoublePendulum-v5", "mixture-K4", "*")],
    "cartpole-balance": [ATLAS.format("cartpole-balance", "flat_ppo", "mlp"),
                         ATLAS.format("cartpole-balance", "mixture", "mixture-K2")],
    "pendulum-swingup": [ATLAS.format("pendulum-swingup", "flat_ppo", "mlp"),
                         ATLAS.format("pendulum-swingup", "mixture", "mixture-K4")],
    "Hopper-v5": [FIG1.format("Hopper-v5", "mlp", "[0-4]"), FIG1.format("Hopper-v5", "mixture-K2", "[0-4]")],  # 5 seeds
    "reacher": [REACHER.format("mlp"), REACHER.format("mixture-K4")],
}


def controllers(group):
    return [p for g in GROUPS[group] for p in sorted(glob.glob(os.path.join(ROOT, g)))]


def run_group(group):
    for path in controllers(group):
        out = os.path.join(HERE, "results", group, os.path.splitext(os.path.basename(path))[0])
        if os.path.exists(os.path.join(out, "verify.json")):
            continue
        t0 = time.perf_counter()
        system = load_system(os.path.relpath(path, ROOT))
        write_all(out, system, verify(system, QUICK), QUICK, quick=True)
        print(f"{group}: {os.path.basename(path)} {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    os.chdir(ROOT)
    for g in sys.argv[1:] or list(GROUPS):
        run_group(g)
