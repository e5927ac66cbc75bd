#!/usr/bin/env bash
# The atlas task by task (cheapest physics first), committing each task's results as it completes.
# Run from the repository root:  bash experiments/atlas_dmc/run_all.sh [task ...]
set -uo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(cartpole-balance cartpole-swingup pendulum-swingup acrobot-swingup point_mass-easy \
  reacher-easy reacher-hard ball_in_cup-catch finger-spin cheetah-run hopper-stand hopper-hop walker-stand walker-walk \
  walker-run fish-swim quadruped-walk)
for task in "${tasks[@]}"; do
  start=$(date +%s)
  if bash experiments/atlas_dmc/run_task.sh "$task"; then
    git add experiments/atlas_dmc/results/$task
    git commit -q -m "atlas_dmc: $task (10 seeds x flat PPO and the mixtures, 1M steps; $(( ($(date +%s) - start) / 60 )) min)" \
      -- experiments/atlas_dmc/results/$task && echo "committed $task"
  else
    echo "FAILED $task"
  fi
done
