#!/usr/bin/env bash
# DeepMind Control Suite tasks on the MJX path on one accelerator, in one call (experiments/gpu_mjx/README.md):
# the benchmark at 256 and 4096 runs on a cheap task (dmc:cartpole-swingup) and a contact-rich one
# (dmc:walker-walk), then tests/test_dmc.py. As device_run.sh: the machine's own jax, the wheels in .whl/, and
# dm_control's MJCFs from .dmc_mjcf/ (dm_control/suite/*.xml copied from dm_control 1.0.50; the tasks read only
# those files, never import dm_control).
#   OUT=dir bash experiments/gpu_mjx/device_run_dmc.sh          (TINY=1: the same steps at toy sizes, for a dry run)
source experiments/gpu_mjx/device_env.sh || exit 1
[ -d .dmc_mjcf ] && export PYTHONPATH=${PYTHONPATH:-$PWD}:$PWD/.dmc_mjcf
if [ -n "${TINY:-}" ]; then
  SIZES=2,4; RAW=64; T_BENCH=900; T_TEST=900; TESTS="-k mjx"
else
  SIZES=256,4096; RAW=4096,65536; T_BENCH=190; T_TEST=110; TESTS=""
fi
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1; nproc; date -u) | tee "$OUT/device.txt"
$PY -c "import jax, jaxlib, mujoco, mujoco.mjx, brax; print('jax', jax.__version__, 'jaxlib', jaxlib.__version__, 'mujoco', mujoco.__version__, 'brax', brax.__version__, jax.devices())" 2>&1 | tee -a "$OUT/device.txt"
for task in cartpole-swingup walker-walk; do
  t0=$(date +%s)
  timeout $T_BENCH $PY -m gsa_jax.bench --env dmc:$task --physics mjx --sizes $SIZES --processes 1 --policies mixture \
    --raw-batches $RAW --run-batch 0 --solver-variant none --repeats 2 --out "$OUT/bench_$task" > "$OUT/bench_$task.log" 2>&1
  echo "bench $task rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
done
t0=$(date +%s)
JAX_DEFAULT_MATMUL_PRECISION=highest timeout $T_TEST $PY -m pytest -q -p no:cacheprovider -m "not benchmark" $TESTS \
  tests/test_dmc.py > "$OUT/tests_dmc.log" 2>&1
echo "tests rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
