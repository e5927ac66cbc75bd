"""Write the partition experiment's specs (specs/<task>_{linear,mlp,flat_ppo}.toml) from the specs the project's own
results were trained with, changing only what the experiment varies:

- dm_control tasks: the atlas's (../atlas_dmc/specs/<task>_{mixture,flat_ppo}.toml: the tuning study's configuration 23
  for mixtures, 16 for flat PPO, backend 'c', fresh resets); gymnasium's v5 tasks: Figure 1's
  (../fig1_v5/fig1_v5_<task>.toml: the PPO paper's settings, backend 'c').
- The mixtures: the partition class (one spec per class, the same settings otherwise), the K of the task (K = 1 is
  left out: one cluster, no partition), and lr_scale_partition at the spec's value and 3x it (a linear partition has
  fewer parameters, so the step size tuned for the MLP may not suit it; both classes get both).

    .venv/bin/python experiments/partition/make_specs.py
"""

import os
import re

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
TASKS = {  # task -> (its source spec's family, K of the experiment)
    "pendulum-swingup": ("dmc", (2, 4)),
    "cartpole-balance": ("dmc", (2, 4)),
    "cartpole-swingup": ("dmc", (2, 4)),
    "InvertedDoublePendulum-v5": ("v5", (2, 4)),
    "Hopper-v5": ("v5", (3,)),
    "walker-walk": ("dmc", (6,)),
    "HalfCheetah-v5": ("v5", (6,)),
    "Walker2d-v5": ("v5", (6,)),
    "Ant-v5": ("v5", (8,)),
}
LR_FACTOR = 3.0
DEFAULT_LR_SCALE_PARTITION = 1.0  # gsa_jax.algorithm.config's default, where a spec sets none


def read(path: str) -> str:
    with open(os.path.join(ROOT, path)) as f:
        return f.read()


def source_specs(task: str, family: str) -> tuple:
    """(mixture spec text, flat PPO spec text, where they come from) without their comment lines and names."""
    if family == "dmc":
        paths = f"experiments/atlas_dmc/specs/{task}_mixture.toml", f"experiments/atlas_dmc/specs/{task}_flat_ppo.toml"
        texts = [read(p) for p in paths]
    else:
        whole_file = f"experiments/fig1_v5/fig1_v5_{task}.toml"
        if not os.path.exists(os.path.join(ROOT, whole_file)):  # a task Figure 1 ran in two halves of 5 seeds
            whole_file = f"experiments/fig1_v5/fig1_v5_{task}_seeds_0_4.toml"
        whole = re.sub(r"(?m)^seeds = .*$", "seeds = 10", read(whole_file))
        paths = (whole_file + ("" if whole_file.endswith(f"{task}.toml") else " at seeds 0-9"),) * 2
        texts = [whole.replace('policies = ["mlp", "mixture"]', f'policies = ["{p}"]') for p in ("mixture", "mlp")]
    strip = [re.sub(r"(?m)^#.*\n|^name = .*\n|^cluster_multipliers = .*\n|^clusters = .*\n", "", t) for t in texts]
    return strip[0], strip[1], paths


def with_hparam(text: str, name: str, value: str) -> str:
    """The spec with [hparams] name = value (replaced, or added; an [hparams] table made where there is none)."""
    if re.search(rf"(?m)^{name} = ", text):
        return re.sub(rf"(?m)^{name} = .*$", f"{name} = {value}", text)
    if "[hparams]" in text:
        return text.replace("[hparams]\n", f"[hparams]\n{name} = {value}\n")
    return text.replace("[config]", f"[hparams]\n{name} = {value}\n[config]")


def mixture_spec(task: str, text: str, source: str, partition: str, ks: tuple) -> str:
    found = re.search(r"(?m)^lr_scale_partition = ([0-9.e-]+)$", text)
    lr = float(found.group(1)) if found else DEFAULT_LR_SCALE_PARTITION
    body = with_hparam(text, "lr_scale_partition", f"[{lr:g}, {round(LR_FACTOR * lr, 4):g}]")
    body = body.replace('policies = ["mixture"]\n',
                        f'policies = ["mixture"]\npartitions = ["{partition}"]\nclusters = {list(ks)}\n')
    head = (f"# The {partition} partition on {task}: {source} with the partition class, K and lr_scale_partition the only\n"
            f"# changes (written by make_specs.py)\nname = \"{run_name(task, partition)}\"\n")
    return head + body


def run_name(task: str, arm: str) -> str:
    return f"partition_{task}" + ("" if arm == "linear" else f"_{arm}")


def write_specs() -> list:
    out = []
    os.makedirs(os.path.join(HERE, "specs"), exist_ok=True)
    for task, (family, ks) in TASKS.items():
        mixture, flat, (mix_src, flat_src) = source_specs(task, family)
        texts = {p: mixture_spec(task, mixture, mix_src, p, ks) for p in ("linear", "mlp")}
        texts["flat_ppo"] = (f"# Flat PPO on {task}: {flat_src} (written by make_specs.py)\n"
                             f"name = \"{run_name(task, 'flat_ppo')}\"\n" + flat)
        for arm, text in texts.items():
            path = os.path.join(HERE, "specs", f"{task}_{arm}.toml")
            with open(path, "w") as f:
                f.write(text)
            out.append(path)
    return out


if __name__ == "__main__":
    for p in write_specs():
        print(p)
