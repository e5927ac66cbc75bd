#!/usr/bin/env bash
# The paper's "needs six" case answered with hundreds of seeds per cell: gsa_jax.answer on gymnasium's Hopper-v5 with
# MJX physics on one accelerator (experiments/verdicts/gpu_hopper/README.md). Looks at 100, 200, 400 seeds per cell,
# K = 2, 3, 6 against flat PPO, 1M env steps per run; every run's controller scored in MuJoCo C as every answer's is.
# The answer resumes, so a call cut short by the device's time limit is continued by the same command.
#   OUT=dir bash experiments/verdicts/gpu_hopper/device_answer.sh           (on a machine with a GPU and jax[cuda])
#   TINY=1 OUT=dir bash experiments/verdicts/gpu_hopper/device_answer.sh    (the same steps at toy sizes, on a CPU)
source experiments/gpu_mjx/device_env.sh || exit 1
if [ -n "${TINY:-}" ]; then
  LOOKS=10; STEPS=20480; CLUSTERS=2; BUDGET=60; LIMIT=3000
  CONFIG='{"num_envs": 16, "unroll_length": 64, "num_minibatches": 8, "num_epochs": 2}'
else
  LOOKS=100,200,400; STEPS=1000000; CLUSTERS=2,3,6; BUDGET=540; LIMIT=570
  CONFIG='{}'
fi
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; nproc; date -u) | tee "$OUT/device.txt"
$PY -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())" 2>&1 | tee -a "$OUT/device.txt"
t0=$(date +%s)
timeout $LIMIT $PY -m gsa_jax.answer --env Hopper-v5 --physics mjx --looks $LOOKS --steps $STEPS --clusters $CLUSTERS \
  --budget-minutes $BUDGET --config "$CONFIG" --out "$OUT/answer" > "$OUT/answer.log" 2>&1
echo "answer rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
tail -5 "$OUT/answer.log"
