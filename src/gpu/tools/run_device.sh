#!/bin/bash
# One device-machine session for the GPU backend. Run from the repository root on the device machine
# (carry .deps); each mode appends its log under $OUT (default ./out-device):
#   DVISIM_COMMIT=<sha> bash src/gpu/tools/run_device.sh build tests sanitize ces scaling ...
# Modes:
#   build      configure + build dvisim_cli and dvisim_tests in build-dev (sm_90, Release; ~5 min, 16 cores)
#   tests      every [gpu] test
#   sanitize   compute-sanitizer memcheck and racecheck on the multi-solver and constraint-row [gpu] tests
#   ces        the default CES machine on the GPU (dvisim run --backend gpu), outputs under $OUT/ces_default
#   scaling    dvisim bench scaling --record (pile and mix, 10k..4M)
#   accuracy | stability | pruning | cesbench   the other benches, full mode, --record
# Results written with --record land in bench/results/ of this copy and are copied to $OUT/results.
set -u
OUT=${OUT:-$PWD/out-device}
mkdir -p "$OUT"
source .deps/env.sh
export DVISIM_COMMIT=${DVISIM_COMMIT:-unknown}
# Benchmarks find scripts and bench/results through the source directory compiled into the binaries.
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$OUT/gpu.txt"
B=build-dev
BIN=$B/bin/dvisim
TESTS=$B/tests/dvisim_tests
for m in "$@"; do
  T0=$(date +%s)
  echo "== $m (commit $DVISIM_COMMIT)"
  case $m in
    build)
      cmake -S . -B $B -DCMAKE_CUDA_ARCHITECTURES=90 -DCMAKE_BUILD_TYPE=Release -DDVISIM_BUILD_DEMOS=OFF \
        > "$OUT/configure.log" 2>&1 || { tail -30 "$OUT/configure.log"; exit 1; }
      cmake --build $B -j16 --target dvisim_cli dvisim_tests > "$OUT/build.log" 2>&1 ||
        { grep -E "error" "$OUT/build.log" | head -30; exit 1; } ;;
    tests) $TESTS "[gpu]" -d yes 2>&1 | tee "$OUT/tests.log" | grep -E "passed|failed|FAILED|with message|^  [a-z]|s: " ;;
    sanitize)
      for tool in memcheck racecheck; do
        timeout 240 compute-sanitizer --tool $tool --error-exitcode 9 $TESTS \
          "GPU system runs every solver*,constraint rows on the GPU*" > "$OUT/$tool.log" 2>&1
        echo "$tool rc=$?"; tail -3 "$OUT/$tool.log"
      done ;;
    ces) $BIN run --backend gpu --out "$OUT/ces_default" 2>&1 | tail -25 ;;
    scaling) $BIN bench scaling --out "$OUT/scaling" --record --budget 5 2>&1 | tail -45 ;;
    accuracy) $BIN bench accuracy --out "$OUT/accuracy" --record 2>&1 | tail -30 ;;
    stability) $BIN bench stability --out "$OUT/stability" --record 2>&1 | tail -30 ;;
    pruning) $BIN bench pruning --out "$OUT/pruning" --backend gpu --record 2>&1 | tail -30 ;;
    cesbench) $BIN bench ces --out "$OUT/cesbench" --backend gpu --record 2>&1 | tail -30 ;;
    *) echo "unknown mode $m"; exit 2 ;;
  esac
  echo "== $m took $(( $(date +%s) - T0 )) s"
  if [ -d bench/results ]; then mkdir -p "$OUT/results" && cp -r bench/results/. "$OUT/results/"; fi
done
