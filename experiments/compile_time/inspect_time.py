"""How long `gsa inspect` takes on a fresh process, and how many XLA compiles it runs (its rollouts' programs).

    .venv/bin/python experiments/compile_time/inspect_time.py --label after [--checkout DIR --checkout-label before] [--rounds 2]

Trains one small MJX mixture run once (inverted_double_pendulum, K = 4, 16 envs, 200-step episodes: the cheapest
task to compile with MJX's dense solver), then runs `gsa inspect RUN --episodes 2` in fresh processes with no
persistent compilation cache, `--rounds` times per checkout given (this one, labelled --label; --checkout DIR runs
another checkout's code, e.g. an earlier commit's `git worktree`, with this environment's Python), interleaved. Per
run: wall seconds of the command, the XLA compiles JAX logs (JAX_LOG_COMPILES=1) and the seconds they took. Rows go
to results/inspect_time.csv (label, commit, round, wall_s, xla_compiles, xla_compile_s, load average before).
"""

import argparse
import csv
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
RESULTS = os.path.join(HERE, "results", "inspect_time.csv")
TRAIN = ["--env", "inverted_double_pendulum", "--policy", "mixture", "--clusters", "4", "--steps", "8192",
         "--num-envs", "16", "--episode-length", "200", "--quiet", "--no-tensorboard"]
COMPILE = re.compile(r"Finished XLA compilation of (.*?) in ([\d.e-]+) sec")
FIELDS = ["label", "commit", "round", "wall_s", "xla_compiles", "xla_compile_s", "load_before"]


def commit_of(root: str) -> str:
    return subprocess.run(["git", "describe", "--always", "--dirty"], cwd=root, capture_output=True, text=True).stdout.strip()


def clean_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    return {**env, "JAX_LOG_COMPILES": "1"}


def train_run(out: str) -> None:
    cmd = [sys.executable, "-m", "gsa_jax.train", *TRAIN, "--out", out]
    subprocess.run(cmd, cwd=ROOT, env=clean_env(), check=True, capture_output=True)


def time_inspect(root: str, run: str, out: str) -> dict:
    """One `gsa inspect` from checkout `root` in a fresh process -> {wall_s, xla_compiles, xla_compile_s}."""
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "gsa_jax.inspect", run, "--episodes", "2", "--out", out], cwd=root,
                          env=clean_env(), capture_output=True, text=True)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"gsa inspect failed in {root}:\n{proc.stderr[-2000:]}")
    found = [float(m.group(2)) for m in COMPILE.finditer(proc.stderr + proc.stdout)]
    return {"wall_s": round(wall, 2), "xla_compiles": len(found), "xla_compile_s": round(sum(found), 2),
            "load_before": round(load, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True, help="this checkout's label")
    ap.add_argument("--checkout", default=None, help="another checkout to time beside this one")
    ap.add_argument("--checkout-label", default="before")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    roots = [(args.label, ROOT)] + ([(args.checkout_label, os.path.abspath(args.checkout))] if args.checkout else [])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        run = os.path.join(tmp, "run")
        train_run(run)
        for r in range(1, args.rounds + 1):
            for label, root in roots if r % 2 else roots[::-1]:
                row = {"label": label, "commit": commit_of(root), "round": r,
                       **time_inspect(root, run, os.path.join(tmp, f"inspect-{label}-{r}"))}
                print(row, flush=True)
                rows.append(row)
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    with open(RESULTS, "w", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
