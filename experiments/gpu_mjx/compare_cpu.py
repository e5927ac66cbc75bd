"""The accelerator's results beside the CPU's: `.venv/bin/python experiments/gpu_mjx/compare_cpu.py`.

Writes results/compare_cpu.csv: (1) the Figure-1 cell (hopper, mixture K = 6, 10 seeds, 1M steps) trained on the
accelerator against the same cell of experiments/fig1 trained on 2 CPU cores: each side's IQM of the deterministic
scores with its 95% stratified-bootstrap interval, and P(accelerator run > CPU run) with its interval (rliable);
the two programs are the same spec and seeds, run by different XLA backends (and jax versions), so equal
returns are not expected, an equal distribution is; (2) the benchmark's throughputs on the accelerator
(results/bench.json) beside the newest committed 2-core CPU benchmark of the same task (experiments/bench_hopper).
Also writes results/dmc/dmc_accelerator.csv: the DeepMind Control Suite tasks' throughputs on the accelerator.
"""

import glob
import json
import os
import subprocess

import numpy as np

from gsa_jax import improvement_probability, iqm_ci, read_csv, write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
GPU_CELL = os.path.join(HERE, "results", "fig1_hopper_K6", "per_run_scores.csv")
CPU_CELL = os.path.join(ROOT, "experiments", "fig1", "results", "fig1_hopper", "per_run_scores.csv")


def cell_scores(path):
    """Deterministic final scores [runs] of hopper's mixture K = 6 runs in a per_run_scores.csv."""
    rows = [r for r in read_csv(path) if r["policy"] == "mixture" and r["K"] == "6"]
    return np.array([float(r["final_score"]) for r in sorted(rows, key=lambda r: int(r["seed"]))])


def cell_rows():
    gpu, cpu = cell_scores(GPU_CELL), cell_scores(CPU_CELL)
    ci = iqm_ci({"accelerator": gpu[:, None], "cpu": cpu[:, None]})
    p = improvement_probability({"a>c": (gpu[:, None], cpu[:, None])})["a>c"]
    return [{"key": f"cell_{name}", "what": f"fig1 hopper mixture K=6 deterministic score ({name})", "n": len(x), "value": f"{ci[name][0]:.1f}",
             "low": f"{ci[name][1]:.1f}", "high": f"{ci[name][2]:.1f}", "source": os.path.relpath(src, ROOT)}
            for name, x, src in (("accelerator", gpu, GPU_CELL), ("cpu", cpu, CPU_CELL))] + [
        {"key": "p_accelerator_gt_cpu", "what": "P(accelerator run > CPU run)", "n": len(gpu), "value": f"{p[0]:.2f}", "low": f"{p[1]:.2f}",
         "high": f"{p[2]:.2f}", "source": "rliable probability_of_improvement"}]


def newest_cpu_bench():
    """The newest committed experiments/bench_hopper/results/<commit>/bench.json (by commit date)."""
    paths = glob.glob(os.path.join(ROOT, "experiments", "bench_hopper", "results", "*", "bench.json"))
    date = lambda p: subprocess.run(["git", "log", "-1", "--format=%ct", os.path.basename(os.path.dirname(p))],
                                    capture_output=True, text=True, cwd=ROOT).stdout.strip() or "0"
    return max(paths, key=lambda p: int(date(p)))


def file_rows(path, label, tag=""):
    """A bench.json's MuJoCo C, raw MJX and mixture training throughputs as rows keyed <what>_<label>[_<tag>]."""
    b = json.load(open(path))
    src, env = os.path.relpath(path, ROOT), b["env"]
    suffix = f"{label}_{tag}" if tag else label
    rows = [{"key": f"mujoco_c_{suffix}", "what": f"{env}: MuJoCo C rollout, {b['mujoco_c']['threads']} threads ({label} machine)",
             "n": 1, "value": f"{b['mujoco_c']['env_steps_per_s']:.0f}", "source": src}]
    for r in b["raw"]:
        if "error" not in r and "solver" not in r:
            rows.append({"key": f"raw_{suffix}_b{r['batch']}_p{r['processes']}", "n": 1, "value": f"{r['env_steps_per_s']:.0f}",
                         "what": f"{env}: raw MJX stepping, batch {r['batch']}, {r['processes']} process(es) ({label})", "source": src})
    for r in b["sweeps"]:
        if "error" not in r and "solver" not in r and r["policy"] == "mixture":
            rows.append({"key": f"train_{suffix}_r{r['runs']}_p{r['processes']}", "n": 1, "value": f"{r['env_steps_per_s']:.0f}",
                         "what": f"{env}: training, mixture, {r['runs']} runs, {r['processes']} process(es) ({label})", "source": src})
    return rows


def bench_rows():
    return file_rows(os.path.join(HERE, "results", "bench.json"), "accelerator") + file_rows(newest_cpu_bench(), "cpu")


def dmc_rows():
    """The DeepMind Control Suite tasks on the accelerator (results/dmc/, device_run_dmc.sh and the walker-walk
    256-run rerun)."""
    found = [("cartpole", "bench_cartpole-swingup/bench.json"), ("walker", "bench_walker-walk/bench.json"),
             ("walker_rerun", "walker256/bench_walker-walk_256/bench.json")]
    return [row for tag, rel in found for row in file_rows(os.path.join(HERE, "results", "dmc", rel), "accelerator", tag)]


def main():
    out = os.path.join(HERE, "results", "compare_cpu.csv")
    write_csv(out, cell_rows() + bench_rows(), ["key", "what", "n", "value", "low", "high", "source"])
    dmc = os.path.join(HERE, "results", "dmc", "dmc_accelerator.csv")
    write_csv(dmc, dmc_rows(), ["key", "what", "n", "value", "source"])
    print(open(out).read() + open(dmc).read())


if __name__ == "__main__":
    main()
