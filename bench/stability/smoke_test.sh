#!/usr/bin/env bash
# CTest smoke test of `dvisim bench stability --quick` (tests/CMakeLists.txt: bench_stability_quick): stability.csv
# and stability.md exist, the CSV has the expected columns, every case has a row per engine with the verdict column
# filled (PASS, FAIL or SKIP), measured rows have sane metrics, and bad input ends with exit code 2.
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

run_bench stability --quick --threads 1
csv="$work/out/stability.csv"
md="$work/out/stability.md"
expect_files "$md"
expected="case,engine,criterion,measured,verdict,max_penetration_rel,late_penetration_rel,energy_growth,max_speed_mps,nan,dt_s,steps,steps_done,bodies,wall_s,device,note"
expect_header "$csv" "$expected"
grep -q "| case | engine | criterion | measured | verdict |" "$md" || fail "no table in $md"
for c in stack_mass_ratio_1e+02 stack_mass_ratio_1e+06 particle_mass_ratio_1e+04 tall_stack_30 tall_stack_100 \
         size_range_0.1mm_10cm tiny_0.1mm_h1e-4 impact_10mps_thin_wall impact_100mps_thin_wall friction_mu_0 \
         friction_mu_2 initial_overlap thin_plates_needle pile_1e6; do
  n=$(awk -F, -v c=$c '$1==c' "$csv" | wc -l)
  [ "$n" -ge 1 ] || fail "no row for case $c"
  if [ "$c" != pile_1e6 ]; then
    for e in cpu bullet; do
      n=$(awk -F, -v c=$c -v e=$e '$1==c && $2==e' "$csv" | wc -l)
      [ "$n" -eq 1 ] || fail "expected one row $c $e, got $n"
    done
  fi
done
awk -F, '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
{
  v = $col["verdict"]
  if (v != "PASS" && v != "FAIL" && v != "SKIP") { print "row " NR ": verdict \"" v "\""; bad = 1 }
  if ($col["criterion"] == "" || $col["measured"] == "") { print "row " NR ": criterion/measured empty"; bad = 1 }
  if (v == "SKIP") next
  if ($col["nan"] == "0") {
    p = $col["max_penetration_rel"]; if (p == "" || !(p >= 0)) { print "row " NR ": penetration " p; bad = 1 }
    s = $col["max_speed_mps"]; if (s == "" || !(s >= 0)) { print "row " NR ": speed " s; bad = 1 }
    if ($col["steps_done"] != $col["steps"] && $col["measured"] !~ /error/) { print "row " NR ": steps_done"; bad = 1 }
  }
}
END { exit bad }' "$csv" || fail "bad values in $csv"
grep -q "^Summary: our engine passes" "$work/stdout.txt" || fail "no summary on stdout"
if grep -q ",cpu,.*,FAIL," "$csv"; then
  grep -q "FAILURES of our engine" "$work/stdout.txt" || fail "our failures are not listed in the summary"
fi

expect_basic_refusals stability
echo "bench_stability_quick: OK"
