"""How long does `gsa answer` take to decide, from a cold and from a warm compilation cache?

    .venv/bin/python experiments/time_to_answer/run.py [--env dmc:cartpole-balance] [--budget-minutes 30]

Runs `gsa answer --env ENV` twice in fresh output directories: cold (an empty compilation cache: the answer's own,
OUT/cold/xla_cache) and warm (JAX_COMPILATION_CACHE_DIR set to the cold answer's cache, so every program loads). Per
answer: the wall time of the command, the step budget it chose, the answer's sentence; per sweep: its seconds, its
program's compile or load seconds (slowest worker), and the seconds estimated before it ran (the ETA's accuracy).
Writes results/<date>-<commit>/{summary.csv, sweeps.csv, <cold|warm>/ (answer.json, report.md, verdicts.csv, results/
with each sweep's controllers and controller_scores.csv, no training state)}.
"""

import argparse
import csv
import datetime
import json
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))


def commit() -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def run_answer(env: str, out: str, budget: float, cache: str | None) -> dict:
    """Run gsa answer once -> {wall_s, sentence, state}."""
    environ = dict(os.environ)
    environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    if cache:
        environ["JAX_COMPILATION_CACHE_DIR"] = cache
    cmd = [sys.executable, "-m", "gsa_jax.answer", "--env", env, "--budget-minutes", str(budget), "--out", out]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=ROOT, env=environ, capture_output=True, text=True)
    wall = time.monotonic() - t0
    with open(os.path.join(out, "command.log"), "w") as f:
        f.write(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise SystemExit(f"gsa answer failed ({proc.returncode}); see {out}/command.log")
    with open(os.path.join(out, "answer.json")) as f:
        state = json.load(f)
    return {"wall_s": wall, "sentence": proc.stdout.strip().splitlines()[-1], "state": state}


def sweep_rows(kind: str, state: dict) -> list:
    """One row per sweep of an answer: its name, seconds, compile or load seconds and estimate."""
    sweeps = [(c["name"], c["sweep"]) for c in state["steps"].get("calibration", [])]
    sweeps += [(n, s) for r in state["rounds"] for n, s in r["sweeps"].items()]
    return [{"cache": kind, "sweep": n, "policy": s["policy"], "steps": s["steps"], "runs": s["runs"],
             "seconds": s["seconds"], "compile_or_load_s": s.get("compile_wall_s", ""),
             "estimated_s": s.get("eta_s") if s.get("eta_s") is not None else ""} for n, s in sweeps]


def keep(out: str) -> None:
    """Drop what is training state or cache, keep the results."""
    for d in ("sweeps", "xla_cache", "specs"):
        shutil.rmtree(os.path.join(out, d), ignore_errors=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--env", default="dmc:cartpole-balance")
    p.add_argument("--budget-minutes", type=float, default=30.0)
    args = p.parse_args()
    res = os.path.join(HERE, "results", f"{datetime.date.today()}-{commit()}-{args.env.replace(':', '_')}")
    shutil.rmtree(res, ignore_errors=True)
    cold = run_answer(args.env, os.path.join(res, "cold"), args.budget_minutes, None)
    cache = os.path.join(res, "cache")
    shutil.copytree(os.path.join(res, "cold", "xla_cache"), cache)
    warm = run_answer(args.env, os.path.join(res, "warm"), args.budget_minutes, cache)
    shutil.rmtree(cache)
    rows, summary = [], []
    for kind, r in (("cold", cold), ("warm", warm)):
        rows += sweep_rows(kind, r["state"])
        comp = sum(float(x["compile_or_load_s"] or 0) for x in sweep_rows(kind, r["state"]))
        summary.append({"env": args.env, "cache": kind, "wall_s": round(r["wall_s"], 1),
                        "compile_or_load_s": round(comp, 1), "compile_share": round(comp / r["wall_s"], 3),
                        "step_budget": r["state"]["steps"]["budget"], "rounds": len(r["state"]["rounds"]),
                        "stopped": r["state"]["stopped"], "answer": r["sentence"], "commit": commit(),
                        "cores": os.cpu_count()})
        keep(os.path.join(res, kind))
    for name, table in (("summary.csv", summary), ("sweeps.csv", rows)):
        with open(os.path.join(res, name), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
