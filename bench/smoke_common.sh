# Shared by the bench smoke tests (bench/*/smoke_test.sh, sourced): the arguments, a clean work directory and
# the checks every one of them makes.
#   source "$(dirname "$0")/../smoke_common.sh" "$@"     # $1 = dvisim binary, $2 = work directory
set -u
cli=$1
work=$2
rm -rf "$work"
mkdir -p "$work"
fail() { echo "FAIL: $*"; exit 1; }

# run_bench NAME ARGS...: `dvisim bench NAME ARGS... --out $work/out`, stdout to $work/stdout.txt (and shown),
# fails on a non-zero exit with the command's stderr.
run_bench() {
  local name=$1
  shift
  "$cli" bench "$name" "$@" --out "$work/out" > "$work/stdout.txt" 2> "$work/stderr.txt"
  local rc=$?
  cat "$work/stdout.txt"
  [ $rc -eq 0 ] || { cat "$work/stderr.txt"; fail "bench $name $* exited with $rc"; }
}

# expect_header CSV "a,b,c": the CSV exists and its first line is exactly the expected header.
expect_header() {
  [ -s "$1" ] || fail "no $1"
  [ "$(head -1 "$1")" = "$2" ] || fail "CSV header of $1: $(head -1 "$1")"
}

# expect_files FILE...: each file exists and is not empty.
expect_files() {
  local f
  for f in "$@"; do [ -s "$f" ] || fail "no $f"; done
}

# expect2 ARGS...: dvisim ARGS... is bad input: exit code 2 and one line "dvisim: error: ..." on stderr.
expect2() {
  "$cli" "$@" > /dev/null 2> "$work/err.txt"
  local rc=$?
  [ $rc -eq 2 ] || fail "'$*' exited with $rc, expected 2"
  [ "$(wc -l < "$work/err.txt")" -eq 1 ] || fail "'$*': expected a one-line error, got: $(cat "$work/err.txt")"
  grep -q "^dvisim: error: " "$work/err.txt" || fail "'$*': $(cat "$work/err.txt")"
}

# expect_basic_refusals NAME: the bad input every benchmark refuses (expect2): an unknown option, no --out, and an
# --out below a plain file.
expect_basic_refusals() {
  expect2 bench "$1" --quick --out "$work/e_bogus" --bogus
  expect2 bench "$1" --quick
  echo plain > "$work/a_file"
  expect2 bench "$1" --quick --out "$work/a_file/sub"
}
