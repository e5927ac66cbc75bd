"""How long a fresh process takes to import MJX and Brax where warp-lang is installed (the playground extra, the test
extras), with mujoco.mjx's warp backend (mujoco.mjx imported before `envs`, as every process did before
envs/mjx_import.py) and without it (`envs` first: envs/mjx_import.py hides `warp` from mujoco.mjx's import).

    .venv/bin/python experiments/compile_time/mjx_import.py [--rounds 7]

Per round, one fresh process of each label, interleaved: the seconds of the imports inside the process (`import_s`)
and of the whole process (`wall_s`), whether MJX's warp backend loaded, and the load average before. Rows go to
results/mjx_import.csv (earlier rows of the same commit are replaced).
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
RESULTS = os.path.join(HERE, "results", "mjx_import.csv")
FIELDS = ["commit", "label", "round", "import_s", "wall_s", "warp_backend", "warp_installed", "load_before"]
IMPORTS = {"with_warp_backend": "import mujoco.mjx, brax.envs, envs", "without_warp_backend": "import envs, mujoco.mjx, brax.envs"}
PROBE = ("import time, json, importlib.util, contextlib, io\nt = time.perf_counter()\n"
         "with contextlib.redirect_stdout(io.StringIO()):\n    {imports}\ns = time.perf_counter() - t\n"
         "from mujoco.mjx import warp\n"
         "print(json.dumps([s, warp.WARP_INSTALLED, importlib.util.find_spec('warp') is not None]))")


def commit_of() -> str:
    return subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def measure(label: str) -> dict:
    """One fresh process importing as `label` says -> its row's measurements."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", PROBE.format(imports=IMPORTS[label])], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    wall = time.perf_counter() - t0
    import_s, backend, installed = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"label": label, "import_s": round(import_s, 3), "wall_s": round(wall, 3), "warp_backend": backend,
            "warp_installed": installed, "load_before": round(load, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    commit = commit_of()
    rows = []
    for r in range(1, args.rounds + 1):
        for label in IMPORTS:
            rows.append({"commit": commit, "round": r, **measure(label)})
            print(rows[-1], flush=True)
    old = []
    if os.path.exists(RESULTS):
        old = [row for row in csv.DictReader(open(RESULTS)) if row["commit"] != commit]
    with open(RESULTS, "w", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        w.writeheader()
        w.writerows(old + rows)


if __name__ == "__main__":
    main()
