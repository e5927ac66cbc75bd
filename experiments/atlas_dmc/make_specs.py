"""Writes the atlas's experiment files: `.venv/bin/python experiments/atlas_dmc/make_specs.py`.

For every DeepMind Control Suite task of envs/dmc: specs/<task>_flat_ppo.toml (flat 64x64 PPO) and
specs/<task>_mixture.toml (K = ceil(m d_a), m in {0.5, 1, 2, 4}; K in {1, 2, 4} where d_a = 1), 10 seeds x 1M env
steps, backend 'c', every episode from a new draw of the task's start law (reset_mode 'fresh', as dm_control
resets). Each class trains with the configuration the tuning study chose for it across Walker2d-v5, Hopper-v5
and HalfCheetah-v5 (experiments/tuning/results/cross_task.csv, `best` = 1: flat_ppo for flat PPO, mixture_d_a for
the mixture at every K), none of them a task of this suite.
"""

import math
import os

import envs
from gsa_jax import read_csv

HERE = os.path.dirname(os.path.abspath(__file__))
CROSS_TASK = os.path.join(HERE, "..", "tuning", "results", "cross_task.csv")
SEEDS, STEPS, MULTIPLIERS = 10, 1_000_000, (0.5, 1, 2, 4)


def knobs(cls):
    """{name: value} of the tuning study's chosen configuration of a class."""
    row = next(r for r in read_csv(CROSS_TASK) if r["class"] == cls and r["best"] == "1")
    return {k: float(v) for k, v in (kv.split("=") for kv in row["knobs"].split())}, row["hparam_set"]


def clusters(d_a):
    """K of the atlas: ceil(m d_a) for m in MULTIPLIERS ({1, 2, 4} where d_a = 1)."""
    return [1, 2, 4] if d_a == 1 else sorted({math.ceil(m * d_a) for m in MULTIPLIERS})


def spec(task, name, cls, policy, d_a):
    """The experiment file of one task and class (name: flat_ppo or mixture) as text."""
    values, chosen = knobs(cls)
    short = task.removeprefix("dmc:")
    lines = [f"# atlas_dmc: {task}, {'flat 64x64 PPO' if policy == 'mlp' else 'mixtures'} with the tuning study's "
             f"configuration {chosen} of class {cls} (written by make_specs.py)",
             f'name = "atlas_{short}_{name}"', f'envs = ["{task}"]', f'policies = ["{policy}"]']
    if policy == "mixture":
        lines.append(f"clusters = {clusters(d_a)}")
    lines += [f"seeds = {SEEDS}", f"steps = {STEPS}", "[hparams]"] + [f"{k} = {v}" for k, v in values.items()]
    lines += ["[config]", 'backend = "c"', 'reset_mode = "fresh"']
    return "\n".join(lines) + "\n"


def main():
    os.makedirs(os.path.join(HERE, "specs"), exist_ok=True)
    for task in envs.DMC_TASKS:
        d_a = envs.action_size(task)
        for name, cls, policy in (("flat_ppo", "flat_ppo", "mlp"), ("mixture", "mixture_d_a", "mixture")):
            path = os.path.join(HERE, "specs", f"{task.removeprefix('dmc:')}_{name}.toml")
            with open(path, "w") as f:
                f.write(spec(task, name, cls, policy, d_a))
            print(path)


if __name__ == "__main__":
    main()
