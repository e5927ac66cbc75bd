#!/usr/bin/env bash
# The partition experiment task by task (cheapest first), committing each task's results as it completes, then the
# verdict table over every task done. Run from the repository root:  bash experiments/partition/run_all.sh [task ...]
set -uo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(pendulum-swingup cartpole-balance cartpole-swingup InvertedDoublePendulum-v5 Hopper-v5 \
  walker-walk HalfCheetah-v5 Walker2d-v5 Ant-v5)
for task in "${tasks[@]}"; do
  start=$(date +%s)
  if bash experiments/partition/run_task.sh "$task"; then
    git add experiments/partition/results/$task experiments/partition/results/verdicts.*
    git commit -q -m "partition: $task (10 seeds x linear and MLP partitions x 2 step sizes, flat PPO; 1M steps; $(( ($(date +%s) - start) / 60 )) min)" \
      -- experiments/partition/results && echo "committed $task"
  else
    echo "FAILED $task"
  fi
done
