"""Where a run's first compile goes: Python tracing, lowering and XLA's compile of each program of `gsa train`.

    .venv/bin/python experiments/compile_time/measure.py --label before [--round 1] [--cases demo_mjx_mixture,...]

Per case (a `gsa train` command line, CASES), two fresh processes, so nothing is compiled or cached before:
- the split: the run's programs as gsa_jax.running.programs.compile_single builds them (init, the training chunk
  run_chunk, the deterministic evaluation), one after another, each traced (jax.jit(...).trace), lowered and
  compiled by XLA, timed apart, with the process's CPU seconds over the three stages (XLA compiles on several
  threads) and the program's size: jaxpr equations (nested ones counted), StableHLO ops and the optimized HLO's
  instructions; 'setup' is make_train (the task, its physics model and the policy, in Python);
- the command: `gsa train` with the case's arguments, stopped after its first chunk, with JAX_LOG_COMPILES=1:
  total_s is the compile it reports (config.json's timing.compile_s: from the start of the run to the first chunk,
  the initial state's computation included); trace_s, lower_s and compile_s sum what JAX logs for every program it
  traces, lowers and compiles (programs compiled at once overlap, so their sum can exceed total_s); xla_compiles
  counts the compiles, the small eager ops' included.
No persistent compilation cache is used (JAX_COMPILATION_CACHE_DIR is unset, and `gsa train`'s own cache, under
XDG_CACHE_HOME, is a fresh empty folder). Rows go to results/compile_time.csv
(one per label, round, case and program; earlier rows of the same label, round and case are replaced), with the
commit, the machine and its load average before and after beside every row: the machine may be shared, so compare
labels measured alike (interleaved rounds).
"""

import argparse
import csv
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
RESULTS = os.path.join(HERE, "results", "compile_time.csv")
CASES = {
    "demo_mjx_mixture": "--env inverted_double_pendulum --policy mixture --clusters 4 --steps 400000",
    "mjx_mlp": "--env inverted_double_pendulum --policy mlp --steps 400000",
    "c_mixture_hopper": "--env hopper --physics c --policy mixture --clusters 4 --steps 20000",
    "c_mlp_hopper": "--env hopper --physics c --policy mlp --steps 20000",
}
COLUMNS = ("label", "round", "case", "program", "trace_s", "lower_s", "compile_s", "total_s", "cpu_s", "jaxpr_eqns",
           "stablehlo_ops", "hlo_instructions", "xla_compiles", "commit", "machine", "load_before", "load_after")


def jaxpr_eqns(jaxpr) -> int:
    """Equations of a jaxpr, those of the jaxprs nested in its equations' parameters included."""
    from jax._src import core

    return sum(1 + sum(jaxpr_eqns(sub) for sub in core.jaxprs_in_params(e.params)) for e in jaxpr.eqns)


def split(name: str, jitted, *args) -> tuple:
    """(row, compiled) of one program: trace, lower and compile seconds and its sizes."""
    t0, c0 = time.perf_counter(), time.process_time()
    traced = jitted.trace(*args)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    compiled = lowered.compile()
    t3, c3 = time.perf_counter(), time.process_time()
    hlo = compiled.as_text() or ""
    row = {"program": name, "trace_s": t1 - t0, "lower_s": t2 - t1, "compile_s": t3 - t2, "total_s": t3 - t0,
           "cpu_s": c3 - c0, "jaxpr_eqns": jaxpr_eqns(traced.jaxpr.jaxpr),
           "stablehlo_ops": sum(" = " in ln for ln in lowered.as_text().splitlines()),
           "hlo_instructions": len(re.findall(r"^\s*(?:ROOT )?%?[\w.-]+ = ", hlo, re.M))}
    return row, compiled


def program_rows(argv: list) -> list:
    """The split of the case's programs in compile_single's order: init and the evaluation each with its own reset,
    as compile_single built them before one reset program served both (the rows' commits: 631b605, ca935ab)."""
    import jax

    from gsa_jax.algorithm.config import make_hparams
    from gsa_jax.commands.train import build_parser, resolve
    from gsa_jax.running import xla_cache
    from gsa_jax.running.tasks import trainer_for

    plan = resolve(build_parser().parse_args(argv))
    t0 = time.perf_counter()
    trainer = trainer_for(plan.cfg, plan.task)
    rows = [{"program": "setup", "total_s": time.perf_counter() - t0}]
    hp, key = make_hparams(**plan.hp), jax.random.PRNGKey(0)
    once = xla_cache.once_options()  # as compile_single compiles init and the evaluation
    row, _ = split("init", jax.jit(trainer.init, compiler_options=once), key, hp)
    rows.append(row)
    state = jax.eval_shape(trainer.init, key, hp)
    run_chunk = jax.jit(trainer.run_chunk, static_argnums=2, donate_argnums=0)
    rows.append(split("run_chunk", run_chunk, state, hp, plan.chunk)[0])
    rows.append(split("evaluate", jax.jit(trainer.evaluate, compiler_options=once), state.params, state.obs_stats, hp,
                      key)[0])
    return rows


def command_rows(argv: list) -> list:
    """`gsa train` stopped after its first chunk, in a fresh process: its compile seconds and its XLA compiles."""
    from gsa_jax.commands.train import build_parser, resolve

    chunk = resolve(build_parser().parse_args(argv)).chunk
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["JAX_LOG_COMPILES"] = "1"
    with tempfile.TemporaryDirectory() as tmp:
        env["XDG_CACHE_HOME"] = os.path.join(tmp, "cache")  # gsa train's own cache (xla_cache.user_dir()): empty
        out = os.path.join(tmp, "run")
        cmd = [sys.executable, "-m", "gsa_jax", "train", *argv, "--out", out, "--stop-after", str(chunk),
               "--no-tensorboard", "--quiet"]
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"gsa train failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        with open(os.path.join(out, "config.json")) as f:
            compile_s = json.load(f)["timing"]["compile_s"]
    log = proc.stdout + proc.stderr
    seconds = [float(s) for s in re.findall(r"Finished XLA compilation of \S+ in ([\d.e-]+) sec", log)]
    traced = [float(s) for s in re.findall(r"Finished tracing \S+ for jit in ([\d.e-]+) sec", log)]
    lowered = [float(s) for s in re.findall(r"Finished jaxpr to MLIR module conversion \S+ in ([\d.e-]+) sec", log)]
    return [{"program": "command", "total_s": compile_s, "trace_s": sum(traced), "lower_s": sum(lowered),
             "compile_s": sum(seconds), "xla_compiles": len(seconds)}]


def machine() -> str:
    """The CPU model and the cores this process may use."""
    model = platform.processor() or platform.machine()
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), model)
    return f"{model}, {len(os.sched_getaffinity(0))} cores"


def commit() -> str:
    """The short commit, '+dirty' where the tracked files, this experiment's results aside, differ from it."""
    git = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.strip()  # noqa: E731
    dirty = git("status", "--porcelain", "-uno", "--", ".", ":!experiments/compile_time/results")  # not its own rows
    return git("rev-parse", "--short", "HEAD") + ("+dirty" if dirty else "")


def run_case(case: str, part: str) -> list:
    """One part ('programs' or 'command') of a case, in a fresh process; its rows."""
    cmd = [sys.executable, os.path.abspath(__file__), "--one", case, "--part", part]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{case} {part} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def write_rows(path: str, label: str, rnd: int, cases: list, rows: list) -> None:
    """Replace the label's and round's rows of these cases in the CSV at `path` by `rows`."""
    kept = []
    if os.path.exists(path):
        with open(path, newline="") as f:
            kept = [r for r in csv.DictReader(f)
                    if not (r["label"] == label and r["round"] == str(rnd) and r["case"] in cases)]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(kept + rows)


def fmt_row(row: dict) -> dict:
    return {k: (f"{v:.3f}" if isinstance(v, float) else v) for k, v in row.items()}


def summarize(path: str) -> str:
    """results/summary.csv beside the CSV at `path`: per case, program and label, the median over rounds of each
    time and the compiles, and the after/before ratio of total_s where both labels are measured. Its path."""
    import statistics

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    groups = {}
    for r in rows:
        groups.setdefault((r["case"], r["program"], r["label"]), []).append(r)
    out = []
    for (case, program, label), rs in sorted(groups.items()):
        med = lambda c: (statistics.median(float(r[c]) for r in rs) if all(r[c] for r in rs) else "")  # noqa: E731
        out.append({"case": case, "program": program, "label": label, "rounds": len(rs), "commit": rs[0]["commit"],
                    **{c: med(c) for c in ("trace_s", "lower_s", "compile_s", "total_s", "xla_compiles")}})
    for row in out:
        before = [b for b in out if (b["case"], b["program"], b["label"]) == (row["case"], row["program"], "before")]
        row["ratio_to_before"] = row["total_s"] / before[0]["total_s"] if before and before[0]["total_s"] else ""
    target = os.path.join(os.path.dirname(path), "summary.csv")
    with open(target, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(out[0]))
        w.writeheader()
        w.writerows(fmt_row(r) for r in out)
    return target


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--label", default="current", help="what the rows are called (e.g. before, after)")
    ap.add_argument("--round", type=int, default=1, help="which round of measurements of this label (default 1)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of: {', '.join(CASES)}")
    ap.add_argument("--out", default=RESULTS)
    ap.add_argument("--summarize", action="store_true", help="only write results/summary.csv from the CSV")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--part", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:  # inside a fresh process: one part of one case
        sys.path.insert(0, ROOT)
        argv = CASES[args.one].split()
        print(json.dumps(program_rows(argv) if args.part == "programs" else command_rows(argv)))
        return
    if args.summarize:
        print(summarize(args.out))
        return
    cases, rows = args.cases.split(","), []
    noted = {"label": args.label, "round": args.round, "commit": commit(), "machine": machine()}
    for case in cases:
        for part in ("programs", "command"):
            before = os.getloadavg()[0]
            for row in run_case(case, part):
                rows.append(fmt_row({**row, **noted, "case": case, "load_before": f"{before:.2f}",
                                     "load_after": f"{os.getloadavg()[0]:.2f}"}))
                print(", ".join(f"{k}={v}" for k, v in rows[-1].items() if k not in ("machine", "commit")), flush=True)
    write_rows(args.out, args.label, args.round, cases, rows)
    print("summary:", summarize(args.out))


if __name__ == "__main__":
    main()
