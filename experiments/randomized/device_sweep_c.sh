#!/usr/bin/env bash
# An experiment (SPEC) swept on the device machine's CPU cores (physics backend 'c' on JAX's CPU backend, one
# worker process per core), in one call: the sweep folder comes back as split tarballs (sweep.tgz.*) that
# `gsa_jax.sweep --resume` continues if the time limit stopped it, and `gsa_jax.extract` turns into results.
#   OUT=dir bash experiments/randomized/device_sweep_c.sh
source experiments/gpu_mjx/device_env.sh || exit 1
export JAX_PLATFORMS=cpu
SPEC=${SPEC:?set SPEC to the experiment file, e.g. experiments/randomized/randomized_Walker2d-v5_seeds_0_4.toml}
name=$(basename "$SPEC" .toml)
(nproc; grep -m1 'model name' /proc/cpuinfo; free -g | head -2; date -u) | tee "$OUT/device.txt"
$PY -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())" 2>&1 | tail -1 | tee -a "$OUT/device.txt"
t0=$(date +%s)
timeout -k 15 ${T_SWEEP:-470} $PY -m gsa_jax.sweep "$SPEC" --no-tensorboard --out "runs/sweeps/$name" > "$OUT/sweep.log" 2>&1
echo "sweep rc=$? $(( $(date +%s) - t0 )) s" | tee -a "$OUT/device.txt"
pkill -f gsa_jax.sweep; sleep 2
tar czf /tmp/sweep.tgz -C runs/sweeps "$name" && split -b 15M /tmp/sweep.tgz "$OUT/sweep.tgz."
ls -la "$OUT" | tee -a "$OUT/device.txt"
