#!/usr/bin/env bash
# CTest smoke test of `dvisim bench accuracy --quick` (tests/CMakeLists.txt: bench_accuracy_quick): accuracy.csv
# has the expected columns, rows for every scene x solver (and Bullet), sane values, the goal line, and bad input
# ends with a one-line error and exit code 2.
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

run_bench accuracy --quick --threads 1
csv="$work/out/accuracy.csv"
expected="scene,engine,solver,sweep,iterations,dt_s,steps,wall_s,ms_per_step,residual_mean,residual_last,max_penetration_rel,compl_violation_mps,observable,observable_ref,observable_err_rel,device,status,run_s,residual_abs_mean_mps,residual_abs_last_mps"
expect_header "$csv" "$expected"
for scene in pile mix stack; do
  for solver in jacobi gs apgd bb bullet-si; do
    c=$(awk -F, -v s=$scene -v v=$solver '$1==s && $3==v && $4=="iterations"' "$csv" | wc -l)
    [ "$c" -ge 3 ] || fail "expected >= 3 iteration-sweep rows for $scene $solver, got $c"
  done
  c=$(awk -F, -v s=$scene '$1==s && $4=="reference"' "$csv" | wc -l)
  [ "$c" -eq 1 ] || fail "expected one reference row for $scene"
done
# The CES machine: our solvers only (Bullet has no CES machine), 2 iteration counts in --quick.
for solver in jacobi gs apgd bb; do
  c=$(awk -F, -v v=$solver '$1=="ces" && $3==v && $4=="iterations"' "$csv" | wc -l)
  [ "$c" -ge 2 ] || fail "expected >= 2 iteration-sweep rows for ces $solver, got $c"
done
[ "$(awk -F, '$1=="ces" && $4=="reference"' "$csv" | wc -l)" -eq 1 ] || fail "expected one reference row for ces"
awk -F, '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
{
  if ($col["status"] != "ok") { print "row " NR ": status " $col["status"]; bad = 1; next }
  if (!($col["wall_s"] > 0)) { print "row " NR ": wall_s " $col["wall_s"]; bad = 1 }
  if (!($col["steps"] >= 1)) { print "row " NR ": steps"; bad = 1 }
  p = $col["max_penetration_rel"]; if (p == "" || !(p >= 0 && p < 100)) { print "row " NR ": penetration " p; bad = 1 }
  e = $col["observable_err_rel"]; if (e == "" || !(e >= 0 && e < 1000)) { print "row " NR ": observable error " e; bad = 1 }
  if ($col["engine"] != "bullet") {
    r = $col["residual_mean"]; if (r == "" || !(r >= 0)) { print "row " NR ": residual " r; bad = 1 }
    c = $col["compl_violation_mps"]; if (c == "" || !(c >= 0)) { print "row " NR ": complementarity " c; bad = 1 }
  }
}
END { exit bad }' "$csv" || fail "bad values in $csv"
grep -q "Goal: time" "$work/stdout.txt" || fail "no goal line on stdout"
grep -q "APGD .* Jacobi .* ratio" "$work/stdout.txt" || fail "no APGD/Jacobi ratio on stdout"

expect2 bench accuracy --quick --out "$work/e2" --threads x
expect_basic_refusals accuracy
echo "bench_accuracy_quick: OK"
