"""Throughput before and after, on one machine: `gsa bench` JSON files of the same command at two commits ->
results/throughput_check/throughput.csv (per commit, round, physics, policy and run count: env-steps/s, compile
seconds, MuJoCo C's rollout rate in that invocation, and the ratio to the `--before` commit's figure).

    .venv/bin/python experiments/bench_your_task/throughput_check.py --before bench_28fbf09.json \
        bench_3172a00_round1.json bench_3172a00_round2.json
"""

import argparse
import json
import os
import re

from gsa_jax import write_csv

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "throughput_check")


def rows_of(name: str) -> list:
    """One row per sweep configuration of a bench.json in HERE."""
    with open(os.path.join(HERE, name)) as f:
        bench = json.load(f)
    found = re.search(r"round(\d+)", name)
    return [{"commit": bench["git_commit"][:7], "round": int(found.group(1)) if found else 1,
             "physics": s["backend"], "policy": s["policy"], "runs": s["runs"], "processes": s["processes"],
             "env_steps_per_s": round(s["env_steps_per_s"], 1), "compile_s": round(s["compile_s"], 1),
             "mujoco_c_rollout_env_steps_per_s": round(bench["mujoco_c"]["env_steps_per_s"], 1)}
            for s in bench["sweeps"]]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", required=True, help="the earlier commit's bench.json (in results/throughput_check/)")
    p.add_argument("after", nargs="+", help="the later commit's bench.json files, one per round")
    args = p.parse_args()
    before = {(r["physics"], r["policy"], r["runs"]): r["env_steps_per_s"] for r in rows_of(args.before)}
    rows = rows_of(args.before) + [r for name in args.after for r in rows_of(name)]
    for r in rows:
        r["ratio_to_before"] = round(r["env_steps_per_s"] / before[(r["physics"], r["policy"], r["runs"])], 3)
    write_csv(os.path.join(HERE, "throughput.csv"), rows)


if __name__ == "__main__":
    main()
