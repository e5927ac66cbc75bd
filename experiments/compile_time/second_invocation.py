"""A `gsa train` run twice, identically, from an empty compilation cache: how long the first compiles and how long the
second takes to load its programs, on MJX and on MuJoCo C in the program ('c').

    .venv/bin/python experiments/compile_time/second_invocation.py [--env TASK] [--steps 20000]

Per physics: `gsa train --env ENV --physics P --steps STEPS` (ENV: inverted_double_pendulum on MJX, InvertedDoublePendulum-v5 on
'c', or --env) in a fresh process with XDG_CACHE_HOME an empty
temporary folder (the user's cache, `gsa_jax.running.xla_cache.user_dir()`, where `gsa train` keeps its programs), then
the same command again with the same cache. Per invocation: wall seconds of the process, the run's compile seconds
(`timing.compile_s` in its config.json: tracing, lowering and compiling or loading its programs, before the first
iteration) and the persistent cache's size after it. Rows go to results/second_invocation.csv (commit, physics,
invocation, wall_s, compile_s, cache_files, load average before).
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
RESULTS = os.path.join(HERE, "results", "second_invocation.csv")
FIELDS = ["commit", "env", "steps", "physics", "invocation", "wall_s", "compile_s", "cache_files", "load_before"]


DEFAULT_ENVS = {"mjx": "inverted_double_pendulum", "c": "InvertedDoublePendulum-v5"}


def commit_of() -> str:
    return subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def train_once(env: str, steps: int, physics: str, cache_home: str, out: str) -> dict:
    """One `gsa train` in a fresh process with the user's cache under cache_home -> {wall_s, compile_s, cache_files}."""
    environ = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")}
    environ["XDG_CACHE_HOME"] = cache_home
    cmd = [sys.executable, "-m", "gsa_jax.train", "--env", env, "--physics", physics, "--steps", str(steps),
           "--quiet", "--no-tensorboard", "--out", out]
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=ROOT, env=environ, capture_output=True, text=True)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"gsa train failed:\n{proc.stderr[-2000:]}")
    timing = json.load(open(os.path.join(out, "config.json")))["timing"]
    files = sum(len(f) for _, _, f in os.walk(os.path.join(cache_home, "gsa_jax", "xla")))
    return {"wall_s": round(wall, 2), "compile_s": round(float(timing["compile_s"]), 2), "cache_files": files,
            "load_before": round(load, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", help="the task on every physics (default: the double pendulum, each physics' own name "
                                  f"of it: {DEFAULT_ENVS})")
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--physics", nargs="+", default=["mjx", "c"])
    args = ap.parse_args()
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    new, commit = not os.path.exists(RESULTS), commit_of()  # before the first row makes the checkout dirty
    with open(RESULTS, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        if new:
            writer.writeheader()
        for physics in args.physics:
            with tempfile.TemporaryDirectory() as tmp:
                for invocation in (1, 2):
                    env = args.env or DEFAULT_ENVS[physics]
                    row = {"commit": commit, "env": env, "steps": args.steps, "physics": physics,
                           "invocation": invocation, **train_once(env, args.steps, physics, os.path.join(tmp, "cache"),
                                                                  os.path.join(tmp, f"run{invocation}"))}
                    writer.writerow(row)
                    f.flush()
                    print(row, flush=True)


if __name__ == "__main__":
    main()
