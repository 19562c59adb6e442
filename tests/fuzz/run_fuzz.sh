#!/usr/bin/env bash
# Bounded fuzzing under CTest (tests/fuzz/CMakeLists.txt, label fuzz; docs/HARDENING.md).
#   run_fuzz.sh build SRC TREE                  configure and build an instrumented tree (clang, DVISIM_FUZZ:
#                                                libFuzzer + ASan + UBSan) with only the fuzz targets
#   run_fuzz.sh run SRC TREE TARGET SECONDS      fuzz one target for SECONDS, starting from corpus/TARGET and
#                                                regressions/TARGET (new inputs go to a scratch directory); any
#                                                finding fails, its reproducer is kept in TREE/fuzz-artifacts/TARGET/
#   run_fuzz.sh large SRC TREE TARGET SECONDS    the same for a JSON target (scene_json, ces_config) with inputs
#                                                up to 1.5 MiB (the targets refuse more than 1 MiB): seeds made
#                                                here nest arrays and objects 100 to 400,000 levels deep under the
#                                                keys the loaders read, hold long arrays and strings, ask for a
#                                                million frames; json.dict gives the mutations JSON's tokens
# Exit 77 (CTest: skipped) where clang++ cannot link a libFuzzer program.
set -uo pipefail
mode=$1 src=$2 tree=$3
cxx=${DVISIM_FUZZ_CXX:-$(command -v clang++ || true)}
probe=$(mktemp -d)
trap 'rm -rf "$probe"' EXIT
echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' > "$probe/p.cpp"
if [ -z "$cxx" ] || ! "$cxx" -fsanitize=fuzzer,address,undefined "$probe/p.cpp" -o "$probe/p" 2>/dev/null; then
  echo "fuzz: no clang++ with libFuzzer: skipped (Debian packages clang libclang-rt-14-dev libomp-dev)"
  exit 77
fi
targets=(scene_json ces_config bullet_file ces_checkpoint mpi_checkpoint)
# The binary of fuzz target $target (bin) and a scratch corpus (work) holding a copy of SEED_DIR.
prepare_target() {  # SEED_DIR
  bin="$tree/tests/fuzz/fuzz_$target"
  [ -x "$bin" ] || { echo "fuzz: $bin is missing (did fuzz_build fail?)"; exit 1; }
  work="$probe/corpus"
  mkdir -p "$work"
  cp -r "$1/." "$work/"
}
# Runs the fuzzer command line "$@" (log in $probe/fuzz.log) and prints its summary; a finding (non-zero exit)
# prints the log's tail and "fuzz: LABEL: FINDING ..." with HINT after where the reproducer is, and exits 1.
fuzz_and_report() {  # LABEL HINT COMMAND...
  local label=$1 hint=$2 rc
  shift 2
  "$@" > "$probe/fuzz.log" 2>&1
  rc=$?
  grep -E "^#[0-9]+ +(DONE|INITED)|stat::|ERROR|FINDING|SUMMARY|Test unit written|^artifact_prefix" "$probe/fuzz.log" | tail -n 30
  if [ "$rc" -ne 0 ]; then
    tail -n 60 "$probe/fuzz.log"
    echo "fuzz: $label: FINDING (exit $rc); reproducer in $art/$hint"
    exit 1
  fi
  echo "fuzz: $label: ${secs} s, no finding"
}
case $mode in
build)
  launcher=()
  command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
  cmake -S "$src" -B "$tree" -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDVISIM_FUZZ=ON \
    -DDVISIM_ENABLE_CUDA=OFF -DDVISIM_ENABLE_MPI=OFF -DDVISIM_BUILD_TESTS=OFF -DDVISIM_BUILD_DEMOS=OFF -DDVISIM_BUILD_BENCH=OFF \
    "${launcher[@]}" > "$probe/configure.log" 2>&1 || { cat "$probe/configure.log"; exit 1; }
  start=$SECONDS
  cmake --build "$tree" -j"${DVISIM_FUZZ_JOBS:-2}" --target "${targets[@]/#/fuzz_}" 2>&1 | tail -n 20
  rc=${PIPESTATUS[0]}
  echo "fuzz: instrumented tree built in $((SECONDS - start)) s (rc $rc)"
  exit "$rc"
  ;;
run)
  target=$4 secs=$5
  prepare_target "$src/tests/fuzz/corpus/$target"
  art="$tree/fuzz-artifacts/$target"
  mkdir -p "$art"
  regressions="$src/tests/fuzz/regressions/$target"
  fuzz_and_report "$target" " - replay it with $bin FILE, fix, then add it to $regressions/" \
    "$bin" -max_total_time="$secs" -timeout=25 -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$art/" \
    "$work" "$regressions"
  ;;
large)
  target=$4 secs=$5
  prepare_target "$src/tests/fuzz/regressions/$target"
  # the generator: deep, long and wide inputs libFuzzer's mutations would not reach from small seeds
  python3 - "$work" "$target" <<'PY' || exit 1
import sys
work, target = sys.argv[1], sys.argv[2]
def put(name, text):
    open(work + "/gen_" + name, "w").write(text)
def arr(n, inner=""): return "[" * n + inner + "]" * n
def obj(n, inner="1"): return '{"a":' * n + inner + "}" * n
for n in (100, 10000, 400000):  # a 400,000-level input is 800 KB: within the targets' 1 MiB size limit
    if target == "ces_config":
        put("dt_%d.json" % n, '{"ces": {"duration_s": 0.01, "time_step_s": %s}}' % arr(n))
        put("key_%d.json" % n, '{"ces": {"duration_s": 0.01}, "extra": %s}' % obj(min(n, 150000)))
        put("set_%d.json" % n, "#set time_step_s=%s\n{\"ces\": {}}" % arr(min(n, 60000)))
    else:
        put("pos_%d.json" % n, '{"bodies": [{"shape": {"type": "sphere", "radius": 0.1}, "position": %s}]}' % arr(n))
        put("obj_%d.json" % n, '{"settings": %s, "bodies": []}' % obj(min(n, 150000)))
        put("frames_%d.json" % n, '{"settings": {"steps": 5, "frames": %d}, "bodies": [{"shape": {"type": "sphere", "radius": 0.1}}]}' % n)
wide = ", ".join('{"shape": {"type": "sphere", "radius": 0.01}, "position": [%d, 0, 0]}' % i for i in range(10000))
put("wide.json", '{"ces": {"feed": {"materials": [%s]}}}' % wide if target == "ces_config" else '{"bodies": [%s]}' % wide)
put("string.json", '{"name": "%s", "ces": {}}' % ("x" * 900000))
PY
  art="$tree/fuzz-artifacts/${target}_large"
  mkdir -p "$art"
  fuzz_and_report "$target (large inputs)" "" \
    "$bin" -max_total_time="$secs" -max_len=1572864 -len_control=0 -dict="$src/tests/fuzz/json.dict" -timeout=25 \
    -rss_limit_mb=4096 -print_final_stats=1 -artifact_prefix="$art/" "$work"
  ;;
*)
  echo "usage: run_fuzz.sh build SRC TREE | run|large SRC TREE TARGET SECONDS"
  exit 2
  ;;
esac
