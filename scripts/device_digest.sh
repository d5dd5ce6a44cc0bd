#!/usr/bin/env bash
# Does a GPU machine play this CPU's episodes? One device call: scripts/platform_digest.py on the machine's
# CPU backend and on its GPU, each compared with docs/results/platform_digest_cpu.json, then (with
# KX_RUNS_LIMIT=SECONDS) `kx.bench runs` at R = 16 (docs/benchmarks.md, "On a GPU"). Wheels travel in .whl/ as for
# scripts/device_bench.sh.
#
#   bash scripts/device_digest.sh [OUT]     # logs to OUT (default $OUT, else /tmp/kx-device)
set -u
source "$(dirname "$0")/device_env.sh" "$@"
REF=docs/results/platform_digest_cpu.json
t0=$SECONDS
JAX_PLATFORMS=cpu timeout 120 python3 scripts/platform_digest.py --compare "$REF" --out "$OUT/digest_cpu.json" \
  >"$OUT/digest_cpu.log" 2>&1
echo "== digest on the machine's CPU: exit $? after $((SECONDS - t0)) s" | tee -a "$OUT/digest_cpu.log"
cat "$OUT/digest_cpu.log" | grep -v Warning | tail -n 12
t0=$SECONDS
timeout "${KX_DIGEST_LIMIT:-200}" python3 scripts/platform_digest.py --compare "$REF" --out "$OUT/digest_gpu.json" \
  >"$OUT/digest_gpu.log" 2>&1
echo "== digest on the GPU: exit $? after $((SECONDS - t0)) s" | tee -a "$OUT/digest_gpu.log"
cat "$OUT/digest_gpu.log" | grep -v Warning | tail -n 12
if [ -n "${KX_RUNS_LIMIT:-}" ]; then
  t0=$SECONDS
  timeout "$KX_RUNS_LIMIT" python3 -m kx.bench runs --generations 10 --group-sizes 16 >"$OUT/runs.log" 2>&1
  echo "== kx.bench runs R=16: exit $? after $((SECONDS - t0)) s" | tee -a "$OUT/runs.log"
  tail -n 8 "$OUT/runs.log"
fi
