"""XLA's compile of a sweep worker's programs (init, the training chunk, the evaluation) in one or more checkouts.

    .venv/bin/python experiments/compile_time/sweep_worker_compile.py --checkout one_draw=. --checkout per_layer=/tmp/wt
    [--rounds 3] [--spec ../time_to_answer/results/2026-12-02-6cb32c8-examples.reacher_Reacher/cold/calibration/calibrate-flat_ppo-61440/sweep.json]

Per round, checkout and policy (flat PPO as the spec says; the mixtures with K = 1, 2, 4, 8 and no evaluation, as the
answer's first round), a fresh process (this venv's Python, in the checkout's directory so its gsa_jax is imported)
builds the group program of one worker's 5 runs of the spec (`gsa answer`'s calibration sweep on examples.reacher,
MuJoCo C in the program) as gsa_jax.running.programs.compile_group does, with no XLA_FLAGS and no persistent cache, and
times lowering and XLA's compile of each program. A row per program goes to results/sweep_worker_compile.csv: label,
round, commit, policy, program, lower_s, compile_s, and the load average before the process.
"""

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from demo_compile import append, commit_of  # noqa: E402

RESULTS = os.path.join(HERE, "results", "sweep_worker_compile.csv")
SPEC = os.path.join(HERE, "..", "time_to_answer", "results", "2026-12-02-6cb32c8-examples.reacher_Reacher", "cold",
                    "calibration", "calibrate-flat_ppo-61440", "sweep.json")
COLUMNS = ("label", "round", "commit", "policy", "program", "lower_s", "compile_s", "load_before")
CHILD = r"""
import json, sys, time
import jax
from gsa_jax.running import programs
from gsa_jax.running.spec import build_grid, check_spec, default_chunk, group_config, group_iterations

raw, policy = json.load(open(sys.argv[1]))["spec"], sys.argv[2]
if policy == "mixture":
    raw = {k: v for k, v in raw.items() if k != "eval_at"}
    raw.update(policies=["mixture"], clusters=[1, 2, 4, 8], eval_every=0, config={**raw["config"], "k_max": 8})
spec = check_spec(raw, source=sys.argv[1])
group = build_grid(spec)[0]
cfg = group_config(spec, group)
chunk = default_chunk(spec, cfg)
runs = programs.GroupRuns(programs.pad_runs(group.runs[:5], 1), spec.run_hparam_names(), group_iterations(spec, cfg, chunk))
shape = programs.GroupShape(cfg, chunk, tuple(jax.devices()))
_, init, run, place = programs.make_group_program(cfg, chunk, list(shape.devices))
keys, hps = programs.stacked_inputs(runs, place)

def timed(name, lower):
    t0 = time.perf_counter()
    lowered = lower()
    t1 = time.perf_counter()
    compiled = lowered.compile()
    print(json.dumps({"program": name, "lower_s": round(t1 - t0, 3), "compile_s": round(time.perf_counter() - t1, 3)}),
          flush=True)
    return compiled

states = timed("init", lambda: init.lower(keys, hps))(keys, hps)
timed("chunk", lambda: run.lower(states, hps))
if spec.eval_at or spec.eval_every:
    evaluate = programs.make_group_evaluate(cfg, shape.run_batch)
    timed("evaluate", lambda: evaluate.lower(states.params, states.obs_stats, hps, keys))
"""


def measure(label: str, path: str, rnd: int, policy: str, spec: str) -> list:
    """One fresh process in checkout `path` -> its rows."""
    env = dict(os.environ)
    for name in ("XLA_FLAGS", "JAX_COMPILATION_CACHE_DIR"):
        env.pop(name, None)
    load = round(os.getloadavg()[0], 2)
    out = subprocess.run([sys.executable, "-c", CHILD, spec, policy], cwd=path, env=env, check=True,
                         capture_output=True, text=True).stdout
    base = {"label": label, "round": rnd, "commit": commit_of(path, RESULTS), "policy": policy, "load_before": load}
    return [dict(base, **json.loads(line)) for line in out.splitlines() if line.startswith("{")]


def main() -> None:
    """Each checkout and policy in turn, --rounds times; rows appended to RESULTS."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", action="append", required=True, help="LABEL=PATH of a checkout")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--spec", default=SPEC, help="a sweep.json whose spec the worker trains")
    args = ap.parse_args()
    for rnd in range(1, args.rounds + 1):
        for policy in ("mlp", "mixture"):
            for label, path in (c.split("=", 1) for c in args.checkout):
                rows = measure(label, os.path.abspath(path), rnd, policy, os.path.abspath(args.spec))
                append(rows, RESULTS, COLUMNS)
                print("\n".join(json.dumps(r) for r in rows), flush=True)


if __name__ == "__main__":
    main()
