"""The speed table from the committed benchmark results: `.venv/bin/python experiments/atlas_dmc/speed_table.py`.

Reads results/speed/<task>/bench.json (gsa_jax.bench --physics c, speed.sh) and results/speed/dm_control_stepping.json
(dm_control_speed.py) and writes results/speed/speed.csv: per task, machine-wide env-steps/s of MuJoCo C's
rollout, raw 'c' stepping, mixture sweeps of 16 and 256 runs (with each sweep's split and its fraction of its
in-run ceiling) and dm_control's own Python stepping (one process, and one per core).
"""

import glob
import json
import os

from gsa_jax import write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
SPEED = os.path.join(HERE, "results", "speed")
FIELDS = ["key", "task", "what", "runs", "env_steps_per_s", "ratio_vs_mujoco_c", "mujoco_c_share", "program_share",
          "of_in_run_ceiling", "of_ceiling_at_own_mujoco_c", "source"]


def bench_rows(path):
    """MuJoCo C, raw stepping and each mixture sweep of one bench.json."""
    b = json.load(open(path))
    task, src = b["env"], os.path.relpath(path, HERE)
    short = task.split(":")[-1]
    rows = [{"key": f"{short}_mujoco_c", "task": task, "what": f"MuJoCo C rollout ({b['mujoco_c']['threads']} threads)",
             "env_steps_per_s": f"{b['mujoco_c']['env_steps_per_s']:.0f}", "ratio_vs_mujoco_c": "1.000", "source": src}]
    for r in b["raw"]:
        rows.append({"key": f"{short}_raw", "task": task, "what": f"raw 'c' stepping, batch {r['batch']}, {r['processes']} processes",
                     "env_steps_per_s": f"{r['env_steps_per_s']:.0f}", "ratio_vs_mujoco_c": f"{r['ratio_vs_mujoco_c']:.3f}", "source": src})
    for r in b["sweeps"]:
        split = r.get("in_run", {})
        f = split.get("fractions", {})
        rows.append({"key": f"{short}_r{r['runs']}", "task": task, "runs": r["runs"],
                     "what": f"training, {r['policy']}, {r['runs']} runs, {r['processes']} processes",
                     "env_steps_per_s": f"{r['env_steps_per_s']:.0f}", "ratio_vs_mujoco_c": f"{r['ratio_vs_mujoco_c']:.3f}",
                     "mujoco_c_share": f"{f.get('mujoco_c', float('nan')):.3f}", "program_share": f"{f.get('program', float('nan')):.3f}",
                     "of_in_run_ceiling": f"{split.get('sweep_of_ceiling', float('nan')):.3f}",
                     "of_ceiling_at_own_mujoco_c": f"{split.get('sweep_of_ceiling_at_own_mujoco_c', float('nan')):.3f}", "source": src})
    return rows


def dm_control_rows(path):
    """dm_control's stepping rates (one process; one per core) of dm_control_stepping.json."""
    d = json.load(open(path))
    src = os.path.relpath(path, HERE)
    return [row for r in d["rows"] for row in (
        {"key": f"{r['task'].split(':')[-1]}_dm_control_1", "task": r["task"], "what": "dm_control's Python stepping, 1 process",
         "env_steps_per_s": f"{r['one_process']:.0f}", "source": src},
        {"key": f"{r['task'].split(':')[-1]}_dm_control_all", "task": r["task"],
         "what": f"dm_control's Python stepping, {r['processes']} processes", "env_steps_per_s": f"{r['machine_wide']:.0f}", "source": src})]


def main():
    """Write results/speed/speed.csv."""
    rows = [row for p in sorted(glob.glob(os.path.join(SPEED, "*", "bench.json"))) for row in bench_rows(p)]
    dmc = os.path.join(SPEED, "dm_control_stepping.json")
    if os.path.exists(dmc):
        rows += dm_control_rows(dmc)
    write_csv(os.path.join(SPEED, "speed.csv"), rows, FIELDS)
    print(open(os.path.join(SPEED, "speed.csv")).read())


if __name__ == "__main__":
    main()
