#!/usr/bin/env bash
# kx's benchmarks on a GPU machine, in one call: what a device session runs (docs/benchmarks.md, "On a GPU").
#
#   bash scripts/device_bench.sh [OUT]      # logs go to OUT (default $OUT, else /tmp/kx-device)
#   KX_DEVICE_BENCHES="policies runs" KX_RUNS_SIZES=16 bash scripts/device_bench.sh   # a second call's share
#
# The machine's own python3, jax and CUDA plugin are used (kx's CPU pins do not apply there); packages it
# lacks travel as wheels in .whl/ (ml-collections, evosax, dotmap) and are installed under /tmp/site; on this
# machine, before the call (.whl/ is listed in .git/info/exclude so that it travels but is not committed):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux2014_x86_64 -d .whl ml-collections==1.1.0 evosax==0.3.2 dotmap==1.3.30
# Each benchmark is bounded by its own time limit (KX_DEVICE_LIMITS, seconds: sim policies hyperneat runs), so
# that one slow benchmark cannot eat the others' time; a benchmark cut off leaves what it printed.
# KX_DEVICE_BENCHES names the benchmarks to run (default all four), KX_RUNS_SIZES the runs benchmark's R.
# On the H200 of 2026-12-04 compilation dominated (a NEAT generation's first evaluation 50 s against 0.05-0.1 s
# warm; docs/benchmarks.md, "On a GPU"): 15 minutes of device time did not cover these four at these sizes.
set -u
source "$(dirname "$0")/device_env.sh" "$@"
read -r T_SIM T_POL T_HN T_RUNS <<<"${KX_DEVICE_LIMITS:-60 100 100 150}"
{
  date -u
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1
  python3 -c "import jax, jaxlib; print('jax', jax.__version__, 'jaxlib', jaxlib.__version__, jax.devices())"
} 2>&1 | tee "$OUT/machine.log"

bench() {  # NAME LIMIT ARGS...: one benchmark, its output in OUT/NAME.log, its wall time and exit status after it
  local name=$1 limit=$2
  shift 2
  case " ${KX_DEVICE_BENCHES:-sim policies hyperneat runs} " in *" $name "*) ;; *) return 0 ;; esac
  local t0=$SECONDS
  timeout "$limit" python3 -m kx.bench "$name" "$@" >"$OUT/$name.log" 2>&1
  local rc=$?
  echo "== kx.bench $name $*: exit $rc after $((SECONDS - t0)) s (limit $limit s)" | tee -a "$OUT/$name.log"
  tail -n 4 "$OUT/$name.log"
}

bench sim "$T_SIM" --repeats 3 --sample-seconds 1 --reference-seconds 3
bench policies "$T_POL" --repeats 3 --sample-seconds 1
bench hyperneat "$T_HN" --generations 12 --skip 4
bench runs "$T_RUNS" --generations 10 --group-sizes "${KX_RUNS_SIZES:-1,16}"
