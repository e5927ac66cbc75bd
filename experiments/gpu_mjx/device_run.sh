#!/usr/bin/env bash
# The MJX path on one accelerator, in one call (experiments/gpu_mjx/README.md): the benchmark at 256-4096 runs,
# one Figure-1 cell (gpu_fig1_hopper_K6.toml), the tests that apply. Uses the machine's own jax (with its CUDA
# plugin) and the wheels in .whl/ for what the machine lacks (mujoco, mujoco-mjx, brax, gymnasium, ...).
#   OUT=dir bash experiments/gpu_mjx/device_run.sh          (TINY=1: the same steps at toy sizes, for a dry run)
source experiments/gpu_mjx/device_env.sh || exit 1
if [ -n "${TINY:-}" ]; then
  SIZES=2,4; RAW=64; STEPS=20000; T_BENCH=600; T_CELL=600; T_TEST=600
else
  SIZES=256,1024,4096; RAW=4096,65536; STEPS=1000000; T_BENCH=250; T_CELL=190; T_TEST=80
fi
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; nproc; date -u) | tee "$OUT/device.txt"
$PY -c "import jax, jaxlib, mujoco, mujoco.mjx, brax; print('jax', jax.__version__, 'jaxlib', jaxlib.__version__, 'mujoco', mujoco.__version__, 'brax', brax.__version__, jax.devices())" 2>&1 | tee -a "$OUT/device.txt"
t0=$(date +%s)
timeout $T_BENCH $PY -m gsa_jax.bench --env hopper --physics mjx --sizes $SIZES --processes 1 --policies mixture \
  --raw-batches $RAW --run-batch 0 --solver-variant none --repeats 2 --out "$OUT/bench" > "$OUT/bench.log" 2>&1
echo "bench rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
t0=$(date +%s)
sed "s/^steps = .*/steps = $STEPS/" experiments/gpu_mjx/gpu_fig1_hopper_K6.toml > /tmp/cell.toml
rm -rf /tmp/cell
timeout $T_CELL $PY -m gsa_jax.sweep /tmp/cell.toml --out /tmp/cell --local-processes 1 --run-batch 0 --no-watchdog \
  --no-tensorboard > "$OUT/cell.log" 2>&1
echo "cell rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
tar czf "$OUT/cell.tar.gz" -C /tmp --exclude='*.state*' --exclude='*checkpoint*' --exclude=xla_cache cell
t0=$(date +%s)
timeout $T_TEST $PY -m pytest -q -p no:cacheprovider -m "not benchmark" tests/test_policies.py tests/test_math.py \
  tests/test_mujoco_c.py > "$OUT/tests.log" 2>&1
echo "tests rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
