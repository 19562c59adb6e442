#!/bin/bash
# One device-machine session for the GPU backend. Run from the repository root on the device machine
# (carry .deps); logs and bench outputs go to $LOGS, plots and recorded results to $OUT (default ./out-device):
#   DVISIM_COMMIT=<sha> bash scripts/device/run_device.sh build tests sanitize ces scaling ...
# Modes:
#   build      configure + build dvisim_cli and dvisim_tests in build-dev (sm_90, Release; ~5 min, 16 cores)
#   tests      every [gpu] test
#   sanitize   compute-sanitizer memcheck and racecheck on every [gpu] test (one process per test)
#   ces        the default CES machine on the GPU (dvisim run --backend gpu), outputs under $LOGS/ces_default
#   cesfeed    the CES feed-rate sweep (scripts/ces_validation/feed_sweep.sh on the GPU), its tables to $OUT/ces_feed
#   scaling    dvisim bench scaling --record (pile and mix, 10k..4M)
#   ncu        per-kernel device time of a GPU pile run (NCU_COUNT launches, NCU_STEPS divides)
#   probe      unrecorded GPU pile timings, float and double APGD storage (PROBE_SIZES, PROBE_SCENES)
#   ab         unrecorded GPU timings of option variants side by side (AB_VARIANTS, PROBE_SIZES, PROBE_SCENES)
#   settle     the 100k pile at the default solver stop and at fixed 50 iterations, statistics side by side
#   accuracy | stability | pruning | cesbench | dropin   the other benches, full mode, --record
#   mpitests   the domain decomposition's tests on MPI_NP (default 2) processes, one GPU each ([gpu], then the rest)
#   mpicli     dvisim run MPI_SCENE (default scenes/pile.json) --backend gpu MPI_RUN_ARGS on 1 and MPI_NP processes,
#              the bodies compared
#   mpiscaling `mpirun -np MPI_NP dvisim bench scaling --mpi --mpi-backend gpu --record` with MPI_ARGS
# BENCH_ARGS adds options to a bench (e.g. "--scenes pile --engines cpu,gpu"), BENCH_TIMEOUT stops it.
# Results written with --record land in bench/results/ of this copy; the new ones are copied to $OUT/results.
set -u
OUT=${OUT:-$PWD/out-device}
# The device machine returns only a few files from $OUT per call: logs stay in $LOGS and come back (as
# $OUT/<name>.log) only when a step fails; $OUT holds the recorded results and the plots.
LOGS=${LOGS:-/tmp/dvisim-device-logs}
mkdir -p "$OUT" "$LOGS"
source .deps/env.sh
export DVISIM_COMMIT=${DVISIM_COMMIT:-unknown}
# Benchmarks find scripts and bench/results through the source directory compiled into the binaries.
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$LOGS/gpu.txt"
# Open MPI: the machine's, or the one carried in .deps (relocated: its prefix and PMIx's follow /opt/deps; the
# Debian packages name their programs *.openmpi, the alternatives' links are made here). No CMA in containers.
if ! command -v mpirun > /dev/null && [ -x /opt/deps/usr/bin/mpiexec.openmpi ]; then
  for p in mpirun mpiexec mpicxx mpicc; do
    src=/opt/deps/usr/bin/$p.openmpi; [ $p = mpirun ] && src=/opt/deps/usr/bin/mpiexec.openmpi
    ln -sf "$src" /opt/deps/usr/bin/$p
  done
  export OPAL_PREFIX=/opt/deps/usr PMIX_INSTALL_PREFIX=/opt/deps/usr/lib/x86_64-linux-gnu/pmix2
fi
export OMPI_MCA_btl_vader_single_copy_mechanism=none
MPIRUN="mpirun --allow-run-as-root --bind-to none --oversubscribe"
B=${BUILD_DIR:-build-dev}
BIN=$B/bin/dvisim
TESTS=$B/tests/dvisim_tests
# bench NAME [ARGS]: dvisim bench NAME --record with $BENCH_ARGS, stopped after $BENCH_TIMEOUT s (default none);
# its stdout goes to $LOGS/NAME.log (tail shown); a run that recorded nothing returns its CSV as
# $OUT/NAME_partial.csv.
bench() {
  local name=$1; shift
  local dir="$LOGS/$name"; rm -rf "$dir"
  timeout ${BENCH_TIMEOUT:-86400} $BIN bench $name --out "$dir" --record "$@" ${BENCH_ARGS:-} > "$LOGS/$name.log" 2>&1
  echo "bench $name rc=$?"; tr '\r' '\n' < "$LOGS/$name.log" | grep -v '\.\.\.$' | tail -40
  grep -q "^recorded" "$LOGS/$name.log" || cp "$dir"/*.csv "$OUT/${name}_partial.csv" 2>/dev/null
}
for m in "$@"; do
  T0=$(date +%s)
  touch "$LOGS/.mark_$m"
  echo "== $m (commit $DVISIM_COMMIT)"
  case $m in
    build)
      cmake -S . -B $B -DCMAKE_CUDA_ARCHITECTURES=90 -DCMAKE_BUILD_TYPE=Release -DDVISIM_BUILD_DEMOS=OFF \
        > "$LOGS/configure.log" 2>&1 || { tail -30 "$LOGS/configure.log"; cp "$LOGS/configure.log" "$OUT/"; exit 1; }
      targets="dvisim_cli dvisim_tests"
      cmake --build $B --target help | grep -q dvisim_mpi_tests && targets="$targets dvisim_mpi_tests"
      cmake --build $B -j$(nproc) --target $targets > "$LOGS/build.log" 2>&1 ||
        { grep -E "error" "$LOGS/build.log" | head -30; cp "$LOGS/build.log" "$OUT/"; exit 1; } ;;
    mpitests)
      $MPIRUN -np ${MPI_NP:-2} $B/tests/mpi/dvisim_mpi_tests "[gpu]" 2>&1 | tee "$LOGS/mpitests.log" | grep -v "^$" | tail -25
      $MPIRUN -np ${MPI_NP:-2} $B/tests/mpi/dvisim_mpi_tests "[mpi]~[gpu]" 2>&1 | grep -E "passed|failed|FAILED" | tail -4 ;;
    mpicli)
      # The CLI under mpirun on the GPU backend (MPI_SCENE, default scenes/pile.json), against one process.
      for np in 1 ${MPI_NP:-2}; do
        rm -rf "$LOGS/mpicli_$np"
        $MPIRUN -np $np $BIN run ${MPI_SCENE:-scenes/pile.json} --backend gpu --out "$LOGS/mpicli_$np" ${MPI_RUN_ARGS:-} \
          > "$LOGS/mpicli_$np.log" 2>&1
        echo "mpicli np=$np rc=$?"; tail -6 "$LOGS/mpicli_$np.log"
      done
      python3 - "$LOGS/mpicli_1/bodies.csv" "$LOGS/mpicli_${MPI_NP:-2}/bodies.csv" <<'PY'
import csv, sys
a, b = ([r for r in csv.DictReader(open(f))] for f in sys.argv[1:3])
keys = [k for k in a[0] if k in ("x", "y", "z", "px", "py", "pz", "pos_x", "pos_y", "pos_z")]
d = max(abs(float(r[k]) - float(s[k])) for r, s in zip(a, b) for k in keys)
print(f"mpicli: {len(a)} vs {len(b)} bodies, columns {keys}, largest position difference {d:.3g} m")
PY
      ;;
    mpiscaling)
      rm -rf "$LOGS/mpiscaling"
      timeout ${BENCH_TIMEOUT:-86400} $MPIRUN -np ${MPI_NP:-2} $BIN bench scaling --mpi --mpi-backend gpu --record \
        --out "$LOGS/mpiscaling" ${MPI_ARGS:-} > "$LOGS/mpiscaling.log" 2>&1
      echo "mpiscaling rc=$?"; tail -30 "$LOGS/mpiscaling.log" ;;
    dropin) bench dropin ;;
    tests) $TESTS "[gpu]" -d yes 2>&1 | tee "$LOGS/tests.log" | grep -E "passed|failed|FAILED|with message|^  [a-z]|s: " ;;
    sanitize)
      # Every [gpu] test, one process per test (names from --list-test-names-only), under memcheck and
      # racecheck; DVISIM_SANITIZER_RUN=1 cuts the 1 s statistics test to 0.1 s (tests/test_gpu.cpp).
      # Per tool: one log ($LOGS/<tool>.log, copied to $OUT on a failure) and a line per test: rc (0 clean, 9 sanitizer errors, 124 timeout).
      # SAN_TOOLS (default "memcheck racecheck") and SAN_MATCH (an extended regex on the test names, default all)
      # narrow a run.
      $TESTS "[gpu]" --list-test-names-only | grep -v '^$' | grep -E "${SAN_MATCH:-.}" > "$LOGS/gpu_tests.txt"
      for tool in ${SAN_TOOLS:-memcheck racecheck}; do
        : > "$LOGS/$tool.log"
        while IFS= read -r t; do
          # Catch2 v2 reads ',' as "or" and '*' as a wildcard: match the name up to its first comma.
          pat="${t%%,*}"; [ "$pat" != "$t" ] && pat="$pat*"
          echo "### $t" >> "$LOGS/$tool.log"
          DVISIM_SANITIZER_RUN=1 timeout ${SAN_TIMEOUT:-150} compute-sanitizer --tool $tool --error-exitcode 9 \
            $TESTS "$pat" >> "$LOGS/$tool.log" 2>&1
          rc=$?
          echo "$tool rc=$rc  $t"
          grep -E "ERROR SUMMARY|RACECHECK SUMMARY" "$LOGS/$tool.log" | tail -1
          [ $rc -ne 0 ] && cp "$LOGS/$tool.log" "$OUT/"
        done < "$LOGS/gpu_tests.txt"
      done ;;
    ces) $BIN run --backend gpu --out "$LOGS/ces_default" 2>&1 | tail -25 ;;
    cesfeed)  # the feed-rate sweep of docs/CES.md (scripts/ces_validation/feed_sweep.sh; CES_FEED_RATES, CES_FEED_JOBS,
              # SEEDS) in $LOGS/ces_feed, stopped after CES_FEED_TIMEOUT s (default 420; the same call again resumes
              # it on a warm machine); its tables (feed_table.md, summary.csv, runs.csv, sweep.json, provenance.md) to $OUT/ces_feed
      mkdir -p "$OUT/ces_feed"
      TIMEOUT_S=${CES_FEED_TIMEOUT:-420} scripts/ces_validation/feed_sweep.sh $BIN gpu "$LOGS/ces_feed" \
        "${CES_FEED_RATES:-}" "${CES_FEED_JOBS:-4}" 2>&1 | tail -40
      cp "$LOGS"/ces_feed/{feed_table.md,summary.csv,runs.csv,sweep.json,provenance.md} "$OUT/ces_feed/" ;;
    scaling) bench scaling --budget 5 ;;
    probe)  # unrecorded GPU timings (PROBE_SIZES, default 10k,100k,1M; PROBE_SCENES, default pile) for each APGD
            # storage in PROBE_STORAGE (default "float real") and --gpu-persistent-max in PROBE_PERSISTENT
            # (default "1000000000 0": every solve in the persistent kernel, then none)
      for f in ${PROBE_STORAGE:-float real}; do
        for pe in ${PROBE_PERSISTENT:-1000000000 0}; do
          echo "-- storage $f, persistent APGD kernel up to $pe blocks"
          $BIN bench scaling --out "$LOGS/probe_${f}_$pe" --scenes ${PROBE_SCENES:-pile} --engines gpu \
            --sizes ${PROBE_SIZES:-10k,100k,1M} --budget 3 --storage $f --gpu-persistent-max $pe 2>&1 | tr '\r' '\n' |
            grep -E "^(gpu|engine) |copy|^  stages|^apgd phases"
        done
      done ;;
    ab)  # unrecorded GPU timings of option variants side by side, one process each, AB_ROUNDS (default 2) rounds
         # interleaved: AB_VARIANTS holds the variants' bench options separated by '|' (e.g. "--gpu-entry-gather
         # false|--gpu-entry-gather true"); PROBE_SIZES / PROBE_SCENES as for probe; AB_PHASES=1 stamps the
         # persistent kernel's phases in the first round (one more read-back per solve: that round's times are not
         # the ones to compare)
      IFS='|' read -r -a variants <<< "${AB_VARIANTS:-}"
      for round in $(seq 1 ${AB_ROUNDS:-2}); do
        for v in "${variants[@]}"; do
          echo "-- round $round: $v"
          if [ "${AB_PHASES:-0}" = 1 ] && [ $round = 1 ]; then export DVISIM_APGD_PHASES=1; else unset DVISIM_APGD_PHASES; fi
          $BIN bench scaling --out "$LOGS/ab" --scenes ${PROBE_SCENES:-pile} \
            --engines gpu --sizes ${PROBE_SIZES:-10k,100k,1M} --budget ${AB_BUDGET:-3} $v 2>&1 | tr '\r' '\n' |
            grep -E "^(gpu|engine) |^  stages|^apgd phases"
        done
      done ;;
    ncu)  # kernel durations (ncu, serialised, no launch gaps) of the first NCU_COUNT launches of a GPU pile run
      ncu --clock-control none --csv --metrics gpu__time_duration.sum --launch-count ${NCU_COUNT:-2000} \
        $BIN bench scaling --out "$LOGS/ncu" --scenes ${PROBE_SCENES:-pile} --engines gpu --sizes ${PROBE_SIZES:-100k} \
        --budget 0.01 > "$LOGS/ncu.csv" 2> "$LOGS/ncu.err"
      echo "ncu rc=$?"; tail -3 "$LOGS/ncu.err"
      python3 scripts/device/ncu_summary.py "$LOGS/ncu.csv" ${NCU_STEPS:-1} ;;
    settle)  # scenes/pile_100k.json on the GPU at the solver's default stop and at fixed 50 iterations, side by side
             # (SETTLE_TIME s of machine time, default 1); the table goes to $OUT/settle.md
      for v in fixed50 default; do
        a=""; [ $v = fixed50 ] && a="--iterations 50"
        $BIN run scenes/pile_100k.json --backend gpu --time ${SETTLE_TIME:-1} $a --out "$LOGS/settle_$v" > "$LOGS/settle_$v.log" 2>&1
        echo "settle $v rc=$?"; tail -2 "$LOGS/settle_$v.log"
      done
      python3 bench/settle/compare_runs.py --radius 0.01 --skip 5 fixed50="$LOGS/settle_fixed50" default="$LOGS/settle_default" \
        | tee "$OUT/settle.md" ;;
    accuracy|stability) bench $m ;;
    pruning) bench pruning --backend gpu ;;
    cesbench) bench ces --backend gpu ;;
    *) echo "unknown mode $m"; exit 2 ;;
  esac
  echo "== $m took $(( $(date +%s) - T0 )) s"
  # The mode's plots, and only the results it wrote, come back (the device returns a few files per call).
  find "$LOGS" -name "*.png" -newer "$LOGS/.mark_$m" -exec cp {} "$OUT/" \;
  # Only the results this mode wrote come back (the device returns a few files per call).
  if [ -d bench/results ]; then
    find bench/results -type f -newer "$LOGS/.mark_$m" | while read -r f; do
      mkdir -p "$OUT/results" && cp "$f" "$OUT/results/"; done
  fi
done
