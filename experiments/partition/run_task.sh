#!/usr/bin/env bash
# One task of the partition experiment end to end: the three sweeps (linear partition, MLP partition, flat PPO),
# their results (sweep.json, tidy metrics, every controller), every controller scored in MuJoCo C (gsa score), the
# merged figures and verdicts against flat PPO (gsa plot), and the linear partition judged against the MLP partition (compare.py). Run from the repository root:
#   bash experiments/partition/run_task.sh pendulum-swingup
set -euo pipefail
task=$1
gsa="${PYTHON:-.venv/bin/python} -m gsa_jax"
out=experiments/partition/results/$task
for arm in linear mlp flat_ppo; do
  name=partition_${task}$([ "$arm" = linear ] || echo "_$arm")
  $gsa sweep experiments/partition/specs/${task}_${arm}.toml --no-tensorboard
  rm -rf "$out/$arm"
  $gsa extract runs/sweeps/$name --results "$out/$arm"
done
$gsa score "$out"
$gsa plot "$out/flat_ppo" "$out/mlp" "$out/linear" --out "$out"
done_tasks=$(ls -d experiments/partition/results/*/ | while read d; do [ -f "$d/per_run_scores.csv" ] && echo "$d"; done)
${PYTHON:-.venv/bin/python} experiments/partition/compare.py $done_tasks
