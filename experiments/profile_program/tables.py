"""The profile's tables from its committed results: `.venv/bin/python experiments/profile_program/tables.py`.

Reads results/<task>/parts.json (written by `gsa profile --envs <task> --out results/<task>`) and
writes results/profile.md (every profile's table, as gsa profile prints it) and results/summary.csv (one row
per task and policy: the figures experiments/profile_program/README.md quotes), every figure derived again from
what was timed by today's gsa_jax.benchmark.parts.summarize.
"""

import glob
import json
import os

from gsa_jax import write_csv
from gsa_jax.benchmark.parts import summarize
from gsa_jax.commands.profile_parts import table

HERE = os.path.dirname(os.path.abspath(__file__))
FIELDS = ["key", "task", "policy", "iteration_ms", "ppo_program_ms", "ppo_share_of_iteration", "update_ms",
          "update_share_of_ppo", "parts_alone_over_update", "gradients_ms", "gradients_share_of_ppo",
          "matrix_products_share_of_gradients", "matrix_products_ms", "matrix_products_share_of_ppo",
          "gradients_of_matmul_rate", "optimizer_ms", "optimizer_share_of_ppo", "ppo_us_per_env_step",
          "mujoco_c_us_per_env_step"]


def summary_row(prof):
    """One profile's headline figures (shares of the PPO program; the parts' alone-timed shares are upper bounds)."""
    part = {r["part"]: r for r in prof["parts"]}
    ppo, mm, steps = prof["ppo_program_s"], prof["matrix_products_s"], prof["env_steps_per_iteration"]
    update = sum(part[k]["s_per_iteration"] for k in ("shuffle_gather", "gradients", "optimizer", "update_loop"))
    ops = prof["gradients_ops_s"]
    return {"key": f"{prof['env']}_{prof['policy']}", "task": prof["env"], "policy": prof["policy"],
            "iteration_ms": f"{prof['iteration_s'] * 1e3:.1f}", "ppo_program_ms": f"{ppo * 1e3:.1f}",
            "ppo_share_of_iteration": f"{ppo / prof['iteration_s']:.3f}",
            "update_ms": f"{update * 1e3:.1f}", "update_share_of_ppo": f"{update / ppo:.3f}",
            "parts_alone_over_update": f"{(update - part['update_loop']['s_per_iteration']) / update:.3f}",
            "gradients_ms": f"{part['gradients']['s_per_iteration'] * 1e3:.1f}",
            "gradients_share_of_ppo": f"{part['gradients']['share_of_ppo']:.3f}",
            "matrix_products_share_of_gradients": f"{ops['matrix_products'] / (ops['matrix_products'] + ops['other_ops']):.3f}",
            "matrix_products_ms": f"{mm * 1e3:.1f}", "matrix_products_share_of_ppo": f"{mm / ppo:.3f}",
            "gradients_of_matmul_rate": f"{part['gradients']['of_matmul_rate']:.2f}",
            "optimizer_ms": f"{part['optimizer']['s_per_iteration'] * 1e3:.1f}",
            "optimizer_share_of_ppo": f"{part['optimizer']['share_of_ppo']:.3f}",
            "ppo_us_per_env_step": f"{1e6 * ppo / steps:.2f}",
            "mujoco_c_us_per_env_step": f"{part['mujoco_c']['us_per_env_step']:.2f}"}


def main():
    """Write results/profile.md and results/summary.csv."""
    reports = [json.load(open(p)) for p in sorted(glob.glob(os.path.join(HERE, "results", "*", "parts.json")))]
    profiles = [{**prof, **summarize(prof)} for r in reports for prof in r["profiles"]]  # with today's derived figures
    with open(os.path.join(HERE, "results", "profile.md"), "w") as f:
        f.write("\n".join(table(prof) for prof in profiles))
    write_csv(os.path.join(HERE, "results", "summary.csv"), [summary_row(prof) for prof in profiles], FIELDS)
    print(open(os.path.join(HERE, "results", "summary.csv")).read())


if __name__ == "__main__":
    main()
