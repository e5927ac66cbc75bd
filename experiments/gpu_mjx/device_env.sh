# What both device scripts share (sourced): the results folder, the Python, and the wheels in .whl/ for what the
# device lacks (installed into /tmp/site, put first on PYTHONPATH; not in a TINY dry run).
set -u
export PYTHONUNBUFFERED=1 MUJOCO_GL=disable
OUT=${OUT:?set OUT to the results folder}
PY=${PY:-python3}
if [ -d .whl ] && [ -z "${TINY:-}" ]; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
