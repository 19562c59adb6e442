#!/usr/bin/env bash
# CTest smoke test of `dvisim bench dropin --quick` (tests/CMakeLists.txt: bench_dropin_quick): dropin.csv has the
# expected columns and one row per scene x engine; Bullet and our CPU drop-in (at its defaults and at Bullet's solver effort) ran every scene with sane values; the
# pyramid rests on all (its top box moves less than 1 cm); dropin.md and the goal line exist; bad input ends with
# a one-line error and exit code 2. It checks the fields, not the speed.
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

run_bench dropin --quick --engines bullet,cpu,cpu-si --threads 1
csv="$work/out/dropin.csv"
expect_header "$csv" "scene,engine,bodies,constraints,steps,ms_per_step,ratio_to_bullet,contact_points,max_penetration_m,drift,status"
[ "$(tail -n +2 "$csv" | wc -l)" -eq 15 ] || fail "expected 15 rows (5 scenes x 3 engines)"
awk -F, '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
{
  if ($col["status"] != "ok") { print "row " NR ": status " $col["status"]; bad = 1 }
  if (!($col["ms_per_step"] > 0)) { print "row " NR ": ms_per_step"; bad = 1 }
  if (!($col["bodies"] > 50)) { print "row " NR ": bodies " $col["bodies"]; bad = 1 }
  if ($col["engine"] != "bullet" && !($col["ratio_to_bullet"] > 0)) { print "row " NR ": no ratio"; bad = 1 }
  if ($col["scene"] == "ragdolls" && !($col["constraints"] > 0)) { print "row " NR ": no joints"; bad = 1 }
  if ($col["scene"] == "pyramid") {
    d = $col["drift"]; if (d < 0) d = -d
    if (!(d < 0.01)) { print "row " NR ": pyramid top moved " $col["drift"]; bad = 1 }
    if (!($col["contact_points"] > 100)) { print "row " NR ": pyramid contact points " $col["contact_points"]; bad = 1 }
  }
}
END { exit bad }' "$csv" || fail "bad values in $csv"
grep -q "Goal: our CPU drop-in (cpu) at <= 1.0x Bullet's time on every scene: " "$work/stdout.txt" || fail "no goal line"
grep -q "Goal: our CPU drop-in (cpu-si) at <= 1.0x Bullet's time on every scene: " "$work/stdout.txt" || fail "no cpu-si goal line"
grep -q "do not edit by hand" "$work/out/dropin.md" || fail "dropin.md header"

expect2 bench dropin --quick --out "$work/e2" --engines tpu
expect2 bench dropin --quick --out "$work/e3" --scenes moon
expect2 bench dropin --quick --out "$work/e4" --steps 0
expect2 bench dropin --quick --out "$work/e5" --threads x
expect2 bench dropin --quick --out "$work/e6" --load -1
expect_basic_refusals dropin
echo "bench_dropin_quick: OK"
