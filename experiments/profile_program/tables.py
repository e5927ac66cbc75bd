"""The profile's tables from its committed results: `.venv/bin/python experiments/profile_program/tables.py`.

Reads results/<task>/parts.json (written by `python -m gsa_jax.profile --envs <task> --out results/<task>`) and
writes results/profile.md (every profile's table, as gsa_jax.profile prints it) and results/summary.csv (one row
per task and policy: the figures experiments/profile_program/README.md quotes). The gradients' matrix products
in milliseconds are their share of the traced op time (a trace slows every op alike, roughly) times the
gradients part's untraced wall time.
"""

import glob
import json
import os

from gsa_jax.analysis.results import write_csv
from gsa_jax.profile import table

HERE = os.path.dirname(os.path.abspath(__file__))
FIELDS = ["key", "task", "policy", "iteration_ms", "ppo_program_ms", "ppo_share_of_iteration", "gradients_ms",
          "gradients_share_of_ppo", "matrix_products_share_of_gradients", "matrix_products_ms", "matrix_products_share_of_ppo", "gradients_of_matmul_rate",
          "optimizer_ms", "ppo_us_per_env_step", "mujoco_c_us_per_env_step"]


def summary_row(prof):
    """One profile's headline figures."""
    part = {r["part"]: r for r in prof["parts"]}
    ops = prof["gradients_ops_s"]
    mm_share = ops["matrix_products"] / (ops["matrix_products"] + ops["other_ops"])
    ppo, mm = prof["ppo_program_s"], mm_share * part["gradients"]["s_per_iteration"]
    steps = prof["env_steps_per_iteration"]
    return {"key": f"{prof['env']}_{prof['policy']}", "task": prof["env"], "policy": prof["policy"],
            "iteration_ms": f"{prof['iteration_s'] * 1e3:.1f}", "ppo_program_ms": f"{ppo * 1e3:.1f}",
            "ppo_share_of_iteration": f"{ppo / prof['iteration_s']:.3f}",
            "gradients_ms": f"{part['gradients']['s_per_iteration'] * 1e3:.1f}",
            "gradients_share_of_ppo": f"{part['gradients']['share_of_ppo']:.3f}",
            "matrix_products_share_of_gradients": f"{mm_share:.3f}",
            "matrix_products_ms": f"{mm * 1e3:.1f}", "matrix_products_share_of_ppo": f"{mm / ppo:.3f}",
            "gradients_of_matmul_rate": f"{part['gradients']['of_matmul_rate']:.2f}",
            "optimizer_ms": f"{part['optimizer']['s_per_iteration'] * 1e3:.1f}",
            "ppo_us_per_env_step": f"{1e6 * ppo / steps:.2f}",
            "mujoco_c_us_per_env_step": f"{part['mujoco_c']['us_per_env_step']:.2f}"}


def main():
    reports = [json.load(open(p)) for p in sorted(glob.glob(os.path.join(HERE, "results", "*", "parts.json")))]
    profiles = [prof for r in reports for prof in r["profiles"]]
    with open(os.path.join(HERE, "results", "profile.md"), "w") as f:
        f.write("\n".join(table(prof) for prof in profiles))
    write_csv(os.path.join(HERE, "results", "summary.csv"), [summary_row(prof) for prof in profiles], FIELDS)
    print(open(os.path.join(HERE, "results", "summary.csv")).read())


if __name__ == "__main__":
    main()
