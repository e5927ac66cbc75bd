"""How long a backend-'c' worker process takes to start: Python, its imports and the task's env, before it traces
its program. Every sweep of an answer starts one such process per core, and its scoring processes import the same.

    .venv/bin/python experiments/time_to_answer/worker_start.py --label after [--checkout DIR --checkout-label before] [--rounds 5]

Per round and checkout (this one, labelled --label; --checkout DIR runs another checkout's code, e.g. an earlier
commit's `git worktree`, with this environment's Python), interleaved: one fresh process that imports what a sweep
worker imports (gsa_jax.orchestration.sweep_job, or an older checkout's gsa_jax.sweep; the run driver), makes the task on backend 'c' (envs.make) and reads its observation
size (a traced reset). Rows go to results/worker_start.csv (label, commit, round, wall_s, which of Brax, Flax and
MJX the process imported, load average before).
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
RESULTS = os.path.join(HERE, "results", "worker_start.csv")
FIELDS = ["label", "commit", "round", "task", "wall_s", "heavy_imports", "load_before"]
WORKER = """
import json, sys
import envs, gsa_jax.running.driver
try:
    import gsa_jax.orchestration.sweep_job
except ImportError:  # a checkout from before the sweep job
    import gsa_jax.sweep
from envs.physics import Physics
env = envs.make(sys.argv[1], physics=Physics(backend="c"))
size = env.observation_size
heavy = sorted({m.split(".")[0] if m != "mujoco.mjx" else m for m in sys.modules if m.startswith(("brax", "flax", "mujoco.mjx"))})
print(json.dumps({"obs": size, "heavy": heavy}))
"""


def commit_of(root: str) -> str:
    return subprocess.run(["git", "describe", "--always", "--dirty"], cwd=root, capture_output=True, text=True).stdout.strip()


def start_worker(root: str, task: str) -> dict:
    """One fresh worker-like process from checkout `root` -> {wall_s, heavy_imports, load_before}."""
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", WORKER, task], cwd=root, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": root})
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"the worker start failed in {root}:\n{proc.stderr[-2000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"wall_s": round(wall, 3), "heavy_imports": " ".join(out["heavy"]) or "none", "load_before": round(load, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True)
    ap.add_argument("--checkout", help="another checkout to time beside this one")
    ap.add_argument("--checkout-label", default="before")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--task", default="dmc:cartpole-balance")
    args = ap.parse_args()
    roots = [(args.label, ROOT)] + ([(args.checkout_label, os.path.abspath(args.checkout))] if args.checkout else [])
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    new = not os.path.exists(RESULTS)
    with open(RESULTS, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        if new:
            writer.writeheader()
        for r in range(1, args.rounds + 1):
            for label, root in roots:
                row = {"label": label, "commit": commit_of(root), "round": r, "task": args.task,
                       **start_worker(root, args.task)}
                writer.writerow(row)
                f.flush()
                print(row, flush=True)


if __name__ == "__main__":
    main()
