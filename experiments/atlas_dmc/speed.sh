#!/usr/bin/env bash
# The speed table of experiments/atlas_dmc/README.md, on an otherwise idle machine, from the repository root:
#   bash experiments/atlas_dmc/speed.sh [task ...]        (default: cartpole-swingup walker-walk quadruped-walk)
# gsa_jax.bench with MuJoCo C in the program (backend 'c'): MuJoCo C's rollout, raw 'c' stepping at batch 256 and
# mixture sweeps of 16 and 256 runs on 2 worker processes; then dm_control's own Python stepping of one
# environment in its reference environment (experiments/dmc_reference/README.md: /tmp/dmcref).
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(cartpole-swingup walker-walk quadruped-walk)
out=experiments/atlas_dmc/results/speed
for task in "${tasks[@]}"; do
  .venv/bin/python -m gsa_jax.bench --env "dmc:$task" --physics c --sizes 16,256 --processes 2 --raw-batches 256 \
    --solver-variant none --policies mixture --out "$out/$task"
done
${DMC_PYTHON:-/tmp/dmcref/bin/python} experiments/atlas_dmc/dm_control_speed.py "${tasks[@]}" --out "$out/dm_control_stepping.json"
