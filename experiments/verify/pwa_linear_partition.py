"""The certificates of the committed linear-partition mixtures, handed to the field's verifiers (`gsa verify --pwa`):
for each controller of experiments/partition/ that certified_regions.csv lists as certified, `gsa verify --certify
--quick` (its certificate, margins and plant test), then `gsa verify --pwa` (the piecewise-affine model, ONNX +
VNN-LIB, the mixed-integer bound of E's bounding box, each checked on the same points).

    .venv/bin/python experiments/verify/pwa_linear_partition.py [TASK ...]

writes results/pwa/<task>/<controller>/ (verify.json, report.md, verify.png, pwa/) and results/pwa/summary.csv, one
row per controller (resumes: a controller whose pwa/checks.json exists is read, not re-run).
"""

import csv
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
PARTITION = os.path.join(ROOT, "experiments", "partition", "results")
OUT = os.path.join(HERE, "results", "pwa")
TASKS = {"cartpole-balance": "dmc.cartpole-balance", "InvertedDoublePendulum-v5": "InvertedDoublePendulum-v5",
         "pendulum-swingup": "dmc.pendulum-swingup"}
COLUMNS = ("task", "controller", "K", "seed", "piece", "k", "level", "counted", "gain_lower", "gain_upper",
           "delay_steps", "same_piece", "action_max_abs_diff", "onnx_max_rel_diff", "decrease_counterexamples",
           "cells_counterexamples", "box_image_milp", "milp_programs", "refused")


def certified(task: str) -> list:
    """[(K, lr_scale_partition, seed)] of the linear partition's certified rows of certified_regions.csv."""
    with open(os.path.join(PARTITION, task, "certified_regions.csv")) as f:
        return [(r["K"], r["lr_scale_partition"], r["seed"]) for r in csv.DictReader(f)
                if r["partition"] == "linear" and r["certified"] == "True"]


def controller_path(task: str, k: str, lr: str, seed: str) -> str:
    name = f"{TASKS[task]}-mixture-K{k}-partition=linear-lr_scale_partition={lr}-s{seed}.npz"
    return os.path.join(PARTITION, task, "linear", "controllers", name)


def run_one(task: str, path: str) -> str:
    """The controller's output folder, certified and exported (each step skipped where its files exist)."""
    out = os.path.join(OUT, task, os.path.basename(path)[:-4])
    gsa = [sys.executable, "-m", "gsa_jax", "verify", path, "--out", out]
    if not os.path.exists(os.path.join(out, "verify.json")):
        subprocess.run(gsa + ["--quick", "--certify"], check=True)
    if not os.path.exists(os.path.join(out, "pwa", "checks.json")):
        subprocess.run(gsa + ["--pwa", os.path.join(out, "verify.json")], check=False)  # refused: no pwa/
    return out


def row(task: str, out: str, k: str, seed: str) -> dict:
    cert = json.load(open(os.path.join(out, "verify.json"))).get("certificate") or {}
    if not os.path.exists(os.path.join(out, "pwa", "checks.json")):  # re-certified here, not certified on the plant
        return {"task": task, "controller": os.path.basename(out), "K": k, "seed": seed,
                "refused": "not certified on the plant at this commit" if cert else "no certificate"}
    check = json.load(open(os.path.join(out, "pwa", "checks.json")))
    m = cert.get("margins") or {}
    return {"task": task, "controller": os.path.basename(out), "K": k, "seed": seed, "piece": cert["piece"],
            "k": cert["k"], "level": cert["level"], "counted": cert.get("counted"), "gain_lower": m.get("gain_lower"),
            "gain_upper": m.get("gain_upper"), "delay_steps": m.get("delay_steps"),
            "same_piece": check["controller"]["same_piece"],
            "action_max_abs_diff": check["controller"]["action_max_abs_diff"],
            "onnx_max_rel_diff": check["onnx_max_rel_diff"],
            "decrease_counterexamples": check["counterexamples"].get("decrease.vnnlib"),
            "cells_counterexamples": check["counterexamples"].get("cells.vnnlib", ""),
            "box_image_milp": check["box_image_milp"]["value"], "milp_programs": check["box_image_milp"]["programs"]}


def main(tasks: list) -> int:
    rows = []
    for task in tasks or list(TASKS):
        for k, lr, seed in certified(task):
            rows.append(row(task, run_one(task, controller_path(task, k, lr, seed)), k, seed))
            print(rows[-1], flush=True)
    with open(os.path.join(OUT, "summary.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {os.path.join(OUT, 'summary.csv')} ({len(rows)} controllers)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
