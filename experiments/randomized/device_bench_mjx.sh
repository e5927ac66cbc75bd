#!/usr/bin/env bash
# Training throughput under domain randomization against nominal on MJX, on one accelerator, in one call: the
# benchmark's sweeps of Hopper-v5 mixtures at 16 and 256 runs, each nominal and then with the experiment's
# randomization (randomized_Hopper-v5.toml), on the same warm machine. Uses the wheels in .whl/ (see
# experiments/gpu_mjx/device_env.sh).   OUT=dir bash experiments/randomized/device_bench_mjx.sh
source experiments/gpu_mjx/device_env.sh || exit 1
R="mass=0.9:1.125, friction=0.75:1.25, gear=0.9:1.1, delay=1, push=0.125"
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; nproc; date -u) | tee "$OUT/device.txt"
$PY -c "import jax, mujoco, brax; print('jax', jax.__version__, 'mujoco', mujoco.__version__, 'brax', brax.__version__, jax.devices())" 2>&1 | tail -1 | tee -a "$OUT/device.txt"
t0=$(date +%s)
timeout ${T_BENCH:-500} $PY -m gsa_jax.bench --env Hopper-v5 --physics mjx --sizes ${SIZES:-16,256} --processes 1 \
  --policies mixture --raw-batches 256 --run-batch 0 --solver-variant none --repeats 3 --randomize "$R" \
  --out "$OUT/bench_mjx" > "$OUT/bench_mjx.log" 2>&1
echo "bench rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
