"""dm_control's own Python stepping of one environment (what a CleanRL user's `dm_control` loop runs), for the
speed table of experiments/atlas_dmc/README.md beside `gsa_jax.bench --env dmc:<task> --physics c`.

    /tmp/dmcref/bin/python experiments/atlas_dmc/dm_control_speed.py cartpole-swingup walker-walk quadruped-walk \
        --out experiments/atlas_dmc/results/speed/dm_control_stepping.json

Runs in dm_control's reference environment (mujoco 3.17 + dm_control 1.0.50, experiments/dmc_reference/README.md).
Per task: `suite.load(domain, task)` and uniform random actions in the action spec, whole 1,000-step episodes
(reset included, as training loops step them), the median of 3 timed episodes after one untimed; with one
process, and with one process per core stepping together (machine-wide env-steps/s = their sum).
"""

import argparse
import json
import multiprocessing
import os
import platform
import statistics
import time

import numpy as np


def step_rate(name, episodes=3, seed=0):
    """Env-steps/s of one dm_control environment (median over whole timed episodes after a warm-up one)."""
    from dm_control import suite

    domain, task = name.split("-", 1)
    env = suite.load(domain, task, task_kwargs={"random": seed})
    spec = env.action_spec()
    rng = np.random.default_rng(seed)
    rates = []
    for i in range(episodes + 1):
        t0, n = time.perf_counter(), 0
        ts = env.reset()
        while not ts.last():
            ts = env.step(rng.uniform(spec.minimum, spec.maximum))
            n += 1
        if i:
            rates.append(n / (time.perf_counter() - t0))
    return statistics.median(rates)


def _worker(args):
    """One process of machine_wide: wait for the common start, then step_rate."""
    name, seed, start = args
    while time.time() < start:
        time.sleep(0.001)
    return step_rate(name, seed=seed)


def machine_wide(name, processes):
    """Summed env-steps/s of `processes` processes, each stepping its own environment, started together."""
    start = time.time() + 5.0
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        return sum(pool.map(_worker, [(name, seed, start) for seed in range(processes)]))


def main():
    """Measure every task named, write --out (JSON) and print a line per task."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tasks", nargs="+", help="domain-task names, e.g. walker-walk")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    from importlib.metadata import version

    cores = len(os.sched_getaffinity(0))
    rows = [{"task": f"dmc:{t}", "one_process": step_rate(t), "processes": cores, "machine_wide": machine_wide(t, cores)}
            for t in args.tasks]
    report = {"what": "dm_control's own Python stepping, env-steps/s", "rows": rows, "cores": cores,
              "versions": {"dm_control": version("dm_control"), "mujoco": version("mujoco")},
              "platform": platform.platform(), "started_at": time.strftime("%Y-%m-%dT%H:%M:%S")}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(report, f, indent=1)
    for r in rows:
        print(f"{r['task']}: {r['one_process']:,.0f} env-steps/s in one process, {r['machine_wide']:,.0f} on {cores} processes")


if __name__ == "__main__":
    main()
