#!/usr/bin/env bash
# One task of the atlas end to end: both sweeps, their results (sweep.json, tidy metrics, every controller), the
# merged figure and tables. Run from the repository root:  bash experiments/atlas_dmc/run_task.sh walker-walk
set -euo pipefail
task=$1
py=.venv/bin/python
out=experiments/atlas_dmc/results/$task
for cls in flat_ppo mixture; do
  $py -m gsa_jax.sweep experiments/atlas_dmc/specs/${task}_${cls}.toml --no-tensorboard
  rm -rf "$out/$cls"
  $py -m gsa_jax.extract runs/sweeps/atlas_${task}_$cls --results "$out/$cls"
done
$py -m gsa_jax.plot "$out/flat_ppo" "$out/mixture" --out "$out"
