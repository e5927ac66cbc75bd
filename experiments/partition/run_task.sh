#!/usr/bin/env bash
# One task of the partition experiment end to end: the three sweeps (linear partition, MLP partition, flat PPO),
# their results (sweep.json, tidy metrics, every controller), every controller scored in MuJoCo C (gsa score), the
# merged figures and verdicts against flat PPO (gsa plot), and the linear partition judged against the MLP partition
# (compare.py). An arm whose results are already in results/<task>/<arm> (committed by an earlier part of the
# experiment) is not trained again; the task is scored and judged once all three are there. Run from the repository
# root:
#   bash experiments/partition/run_task.sh pendulum-swingup [ARM ...]   (default: linear mlp flat_ppo)
set -euo pipefail
task=$1
shift
arms=${*:-linear mlp flat_ppo}
gsa="${PYTHON:-.venv/bin/python} -m gsa_jax"
out=experiments/partition/results/$task
for arm in $arms; do
  [ -f "$out/$arm/sweep.json" ] && { echo "$task $arm: results already in $out/$arm"; continue; }
  name=partition_${task}$([ "$arm" = linear ] || echo "_$arm")
  $gsa sweep experiments/partition/specs/${task}_${arm}.toml --no-tensorboard
  rm -rf "$out/$arm"
  $gsa extract runs/sweeps/$name --results "$out/$arm"
done
for arm in linear mlp flat_ppo; do
  [ -f "$out/$arm/sweep.json" ] || { echo "$task: $arm not trained yet; scored and judged once all three arms are"; exit 0; }
done
$gsa score "$out"
$gsa plot "$out/flat_ppo" "$out/mlp" "$out/linear" --out "$out"
done_tasks=$(ls -d experiments/partition/results/*/ | while read d; do [ -f "$d/per_run_scores.csv" ] && echo "$d"; done)
${PYTHON:-.venv/bin/python} experiments/partition/compare.py $done_tasks
