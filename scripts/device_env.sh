# Sourced by scripts/device_bench.sh and scripts/device_digest.sh on a GPU machine: OUT (the first argument,
# else $OUT, else /tmp/kx-device), the persistent compilation cache, and the packages the machine lacks
# installed from the wheels in .whl/ under /tmp/site (the machine's own python3, jax and CUDA plugin are used).
OUT=${1:-${OUT:-/tmp/kx-device}}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 KX_CACHE_DIR=${KX_CACHE_DIR:-/tmp/kx-jax-cache}
if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
