"""`make demo`'s run from an empty compilation cache, in one or more checkouts, interleaved: its compile seconds, its
training rate and its final deterministic evaluation.

    .venv/bin/python experiments/compile_time/demo_compile.py --checkout after=. --checkout before=/tmp/wt --rounds 4
    [--first-round 5]

Per round, each checkout in turn runs the demo's `gsa train` (DEMO, as the Makefile's demo target) with this
venv's Python in the checkout's directory (so its gsa_jax and envs are imported), with XDG_CACHE_HOME a fresh empty
folder (`gsa train`'s persistent cache starts empty), XLA_FLAGS unset and nothing else from this script running. A row per run goes
to results/demo_compile.csv: the label, the round, the checkout's commit (with '+dirty' where files other than this
table have uncommitted changes), config.json's timing (compile_s: from the run's start to its first chunk; train_s and eval_s: the seconds
of its training chunks and of its evaluations), its steps per second and final evaluation, the process's wall
seconds and the load average before it (the machine may be shared).
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
RESULTS = os.path.join(HERE, "results", "demo_compile.csv")
DEMO = ["--env", "inverted_double_pendulum", "--policy", "mixture", "--clusters", "4", "--steps", "400000"]
COLUMNS = ("label", "round", "commit", "compile_s", "train_s", "eval_s", "steps_per_s", "final_eval", "wall_s", "load_before",
           "machine")


def commit_of(path: str, table: str = RESULTS) -> str:
    """The checkout's short commit, with '+dirty' where tracked files other than `table` (the measuring script's
    own results, which it writes as it goes) have uncommitted changes."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=path, capture_output=True, text=True,
                          check=True).stdout.strip()
    table = os.path.relpath(table, os.path.join(HERE, "..", ".."))
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", f":!{table}"], cwd=path,
                           capture_output=True, text=True, check=True).stdout.strip()
    return head + ("+dirty" if dirty else "")


def final_eval(out: str) -> str:
    """The run's last deterministic evaluation, as its metrics.csv writes it ('' if none)."""
    with open(os.path.join(out, "metrics.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r.get("eval_return") not in ("", None, "nan")]
    return rows[-1]["eval_return"] if rows else ""


def run_demo(label: str, path: str, rnd: int) -> dict:
    """One demo run in checkout `path` from an empty cache -> its row."""
    with tempfile.TemporaryDirectory() as tmp:
        out, cache = os.path.join(tmp, "run"), os.path.join(tmp, "cache")
        os.makedirs(cache)
        env = dict(os.environ, XDG_CACHE_HOME=cache)
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        env.pop("XLA_FLAGS", None)  # as `make demo` runs: XLA's own defaults
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "gsa_jax.train", *DEMO, "--out", out], cwd=path, env=env, check=True,
                       stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        with open(os.path.join(out, "config.json")) as f:
            timing = json.load(f)["timing"]
        return {"label": label, "round": rnd, "commit": commit_of(path), "compile_s": round(timing["compile_s"], 2),
                "train_s": round(timing["train_s"], 2), "eval_s": round(timing["eval_s"], 2),
                "steps_per_s": round(timing["env_steps_per_s"]), "final_eval": final_eval(out),
                "wall_s": round(wall, 1), "load_before": round(load, 2), "machine": os.uname().nodename}


def append(rows: list, path: str = RESULTS, columns: tuple = COLUMNS) -> None:
    """Add rows to the table at `path` (its header of `columns` first where the file is new)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    new = not os.path.exists(path)
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        if new:
            writer.writeheader()
        writer.writerows(rows)


def main() -> None:
    """Run the demo in each checkout, --rounds times, interleaved; a row per run."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", action="append", required=True, help="LABEL=PATH of a checkout to run the demo in")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--first-round", type=int, default=1, help="the first round's number (to add rounds to a table)")
    args = ap.parse_args()
    checkouts = [c.split("=", 1) for c in args.checkout]
    for rnd in range(args.first_round, args.first_round + args.rounds):
        for label, path in checkouts:
            row = run_demo(label, os.path.abspath(path), rnd)
            append([row])
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
