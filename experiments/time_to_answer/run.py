"""How long does `gsa answer` take to decide, from a cold and from a warm compilation cache?

    .venv/bin/python experiments/time_to_answer/run.py [--env dmc:cartpole-balance] [--budget-minutes 30]
        [--checkout DIR] [--cold-only] [--answer-args "--futility 0"]

Runs `gsa answer --env ENV` twice in fresh output directories: cold (an empty compilation cache: the answer's own,
OUT/cold/xla_cache) and warm (JAX_COMPILATION_CACHE_DIR set to the cold answer's cache, so every program loads). Per
answer: the wall time of the command, the seconds until it first printed an answer (the answer so far, printed before
a further round trains; the whole wall time where the first look decided) and that answer, the step budget it chose,
the answer's sentence; per sweep: its seconds, its
program's compile or load seconds (slowest worker), and the seconds estimated before it ran (the ETA's accuracy).
--checkout runs the answers from another checkout of the project (e.g. an earlier commit's `git worktree`, with this
environment's Python: the checkout's code is imported from its directory), --cold-only skips the warm answer; --answer-args passes more options to `gsa answer` (recorded in summary.csv's
answer_args and in the results folder's name); --recount only writes results/trained_env_steps.csv (the env steps every committed
answer trained).
Writes results/<date>-<commit>-<task>[-<answer args>]/{summary.csv, sweeps.csv, <cold|warm>/ (answer.json, report.md, verdicts.csv, results/
with each sweep's controllers and controller_scores.csv, no training state)}.
"""

import argparse
import csv
import datetime
import glob
import gzip
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))


def commit(root: str = ROOT) -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()


def run_answer(env: str, out: str, budget: float, cache: str | None, root: str = ROOT, extra: tuple = ()) -> dict:
    """Run gsa answer once (with the options `extra` added) -> {wall_s, sentence, state}."""
    environ = dict(os.environ)
    environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    if cache:
        environ["JAX_COMPILATION_CACHE_DIR"] = cache
    cmd = [sys.executable, "-m", "gsa_jax.answer", "--env", env, "--budget-minutes", str(budget), "--out", out, *extra]
    os.makedirs(out, exist_ok=True)
    t0, timed = time.monotonic(), []
    with subprocess.Popen(cmd, cwd=root, env=environ, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc:
        for line in proc.stdout:  # each line with the seconds since the start: when the answer so far was first printed
            timed.append((time.monotonic() - t0, line.rstrip("\n")))
    wall = time.monotonic() - t0
    with open(os.path.join(out, "command.log"), "w") as f:
        f.write("".join(f"{t:8.1f}  {line}\n" for t, line in timed))
    if proc.returncode != 0:
        raise SystemExit(f"gsa answer failed ({proc.returncode}); see {out}/command.log")
    with open(os.path.join(out, "answer.json")) as f:
        state = json.load(f)
    first_s, first = first_answer(timed)
    return {"wall_s": wall, "sentence": final_answer(timed), "state": state, "first_answer_s": first_s if first else wall,
            "first_answer": first or final_answer(timed)}


SO_FAR = "answer so far"  # gsa answer's header of the answer printed before a further round trains
BEFORE_VERIFY = "answer (its exported"  # its header of the ended answer printed before its controller's gsa verify


def first_answer(timed: list) -> tuple:
    """(seconds, the answer's lines) of the first answer gsa answer printed (so far, before a further round; or ended,
    before its controller's verification); (None, '') where it printed none: its lines are those after the header up
    to the next progress line."""
    for i, (t, line) in enumerate(timed):
        if line.startswith((SO_FAR, BEFORE_VERIFY)):
            block = []
            for _, later in timed[i + 1:]:
                if later.startswith(("answer:", "wrote ", "next: ")):
                    break
                block.append(later)
            return t, " ".join(block)
    return None, ""


def final_answer(timed: list) -> str:
    """The answer's closing lines: those after the last 'wrote' or 'next:' line."""
    last = max((i for i, (_, line) in enumerate(timed) if line.startswith(("wrote ", "next: "))), default=-1)
    return " ".join(line for _, line in timed[last + 1:])


def log_compiles(out: str, name: str) -> float:
    """The slowest worker's program compile or load seconds of sweep `name`, from its log (answers written before
    they recorded it keep only the workers' sum)."""
    times = []
    path = os.path.join(out, "logs", name + ".log")
    if os.path.exists(path):
        times = [float(m.group(1)) for m in re.finditer(r"program .*? \(([\d.]+)s\)", open(path).read())]
    return max(times, default=0.0)


def sweep_rows(kind: str, state: dict, out: str) -> list:
    """One row per sweep of an answer: its name, seconds, compile or load seconds and estimate."""
    sweeps = [(c["name"], c["sweep"]) for c in state.get("steps", {}).get("calibration", [])]
    sweeps += [(n if "policy" in s else f"round{r['round']}-{n}", s) for r in state["rounds"] for n, s in r["sweeps"].items()]
    return [{"cache": kind, "sweep": n, "policy": s.get("policy", n), "steps": s.get("steps", ""), "runs": s.get("runs", ""),
             "seconds": s["seconds"], "compile_or_load_s": s.get("compile_wall_s", log_compiles(out, n.replace("mlp", "flat_ppo"))),
             "estimated_s": s.get("eta_s") if s.get("eta_s") is not None else ""} for n, s in sweeps]


def trained_env_steps(answer_dir: str) -> int:
    """Env steps an answer trained, summed over its runs (each run's last env_steps in its sweep's tidy metrics): every
    calibration sweep and every round's sweep, the chosen calibration's copy in results/ counted once."""
    total = 0
    sweeps = glob.glob(os.path.join(answer_dir, "calibration", "*"))
    sweeps += [d for d in glob.glob(os.path.join(answer_dir, "results", "*")) if not os.path.basename(d).startswith("calibrate-")]
    for sweep in sorted(sweeps):
        last = {}
        for path in glob.glob(os.path.join(sweep, "metrics-process-*.csv.gz")):
            with gzip.open(path, "rt") as f:
                for row in csv.DictReader(f):
                    last[row["run"]] = max(last.get(row["run"], 0), int(row["env_steps"]))
        total += sum(last.values())
    return total


def recount() -> None:
    """results/trained_env_steps.csv: trained_env_steps of every committed answer (results/<dir>/<cold|warm>)."""
    rows = [{"answer": os.path.relpath(d, os.path.join(HERE, "results")), "env_steps": trained_env_steps(d)}
            for d in sorted(glob.glob(os.path.join(HERE, "results", "*", "cold")) + glob.glob(os.path.join(HERE, "results", "*", "warm")))]
    with open(os.path.join(HERE, "results", "trained_env_steps.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["answer", "env_steps"])
        w.writeheader()
        w.writerows(rows)
    print("\n".join(f"{r['answer']}: {r['env_steps']:,}" for r in rows))


def keep(out: str) -> None:
    """Drop what is training state or cache, keep the results."""
    for d in ("sweeps", "xla_cache", "specs"):
        shutil.rmtree(os.path.join(out, d), ignore_errors=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--env", default="dmc:cartpole-balance")
    p.add_argument("--budget-minutes", type=float, default=30.0)
    p.add_argument("--checkout", default=ROOT, help="the checkout whose code answers (default: this one)")
    p.add_argument("--cold-only", action="store_true")
    p.add_argument("--answer-args", default="", help="more options for gsa answer, e.g. '--futility 0'")
    p.add_argument("--recount", action="store_true", help="only write results/trained_env_steps.csv from the committed answers")
    args = p.parse_args()
    if args.recount:
        return recount()
    root, extra = os.path.abspath(args.checkout), tuple(shlex.split(args.answer_args))
    suffix = "".join("-" + re.sub(r"[^\w.]+", "", a) for a in extra)
    res = os.path.join(HERE, "results", f"{datetime.date.today()}-{commit(root)}-{args.env.replace(':', '_')}{suffix}")
    shutil.rmtree(res, ignore_errors=True)
    runs = [("cold", run_answer(args.env, os.path.join(res, "cold"), args.budget_minutes, None, root, extra))]
    if not args.cold_only:
        cache = os.path.join(res, "cache")
        shutil.copytree(os.path.join(res, "cold", "xla_cache"), cache)
        runs.append(("warm", run_answer(args.env, os.path.join(res, "warm"), args.budget_minutes, cache, root, extra)))
        shutil.rmtree(cache)
    rows, summary = [], []
    for kind, r in runs:
        mine = sweep_rows(kind, r["state"], os.path.join(res, kind))
        rows += mine
        comp = sum(float(x["compile_or_load_s"] or 0) for x in mine)
        summary.append({"env": args.env, "cache": kind, "wall_s": round(r["wall_s"], 1),
                        "first_answer_s": round(r["first_answer_s"], 1), "first_answer": r["first_answer"],
                        "compile_or_load_s": round(comp, 1), "compile_share": round(comp / r["wall_s"], 3),
                        "step_budget": r["state"].get("steps", {}).get("budget", r["state"]["setup"]["specs"]["mlp"]["steps"]),
                        "env_steps_trained": trained_env_steps(os.path.join(res, kind)),
                        "rounds": len(r["state"]["rounds"]), "stopped": r["state"]["stopped"], "answer": r["sentence"],
                        "commit": commit(root), "answer_args": args.answer_args,
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
