#!/usr/bin/env bash
# CTest smoke test of `dvisim bench pruning --quick` (tests/CMakeLists.txt: bench_pruning_quick): pruning.csv has
# the expected columns and one row per scene x prune with sane values, pruning.md and the goal line exist, and bad
# input ends with a one-line error and exit code 2. It checks the fields, not the speed.
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

run_bench pruning --quick --backend cpu --threads 1
csv="$work/out/pruning.csv"
expect_files "$work/out/pruning.md"
expected="scene,mu,prune,bodies,steps,ms_per_step,IntegrateForces_ms,ComputeAabbs_ms,BroadPhase_ms,NarrowPhase_ms,BuildRows_ms,WarmStart_ms,Solve_ms,IntegrateVelocities_ms,IntegratePositions_ms,contacts_mean,normal_only_steps,saving_pct,backend,threads,device,parts_ran"
expect_header "$csv" "$expected"
[ "$(tail -n +2 "$csv" | wc -l)" -eq 4 ] || fail "expected 4 rows"
awk -F, '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
{
  if (!($col["ms_per_step"] > 0)) { print "row " NR ": ms_per_step " $col["ms_per_step"]; bad = 1 }
  if (!($col["Solve_ms"] > 0)) { print "row " NR ": Solve_ms"; bad = 1 }
  if (!($col["contacts_mean"] > 100)) { print "row " NR ": contacts " $col["contacts_mean"]; bad = 1 }
  if (!($col["steps"] >= 1)) { print "row " NR ": steps"; bad = 1 }
  pr = $col["prune"]; mu = $col["mu"]; no = $col["normal_only_steps"]
  # only the pruned frictionless pile solves normal rows only, and it does so every step
  if (pr == "true" && mu == 0) { if (no != $col["steps"]) { print "row " NR ": normal-only steps " no; bad = 1 } }
  else if (no != 0) { print "row " NR ": normal-only steps " no; bad = 1 }
  if (pr == "true" && $col["saving_pct"] == "") { print "row " NR ": no saving"; bad = 1 }
  if (pr == "true" && mu == 0 && index($col["parts_ran"], "FrictionRows")) { print "row " NR ": friction rows ran"; bad = 1 }
  if (pr == "false" && !index($col["parts_ran"], "BuildRows.FrictionRows")) { print "row " NR ": friction rows did not run"; bad = 1 }
}
END { exit bad }' "$csv" || fail "bad values in $csv"
grep -q "Goal: pruning saves >= 30% on a frictionless all-sphere scene: " "$work/stdout.txt" || fail "no goal line"
grep -q "do not edit by hand" "$work/out/pruning.md" || fail "pruning.md header"

expect2 bench pruning --quick --out "$work/e2" --threads x
expect2 bench pruning --quick --out "$work/e3" --n 0
expect2 bench pruning --quick --out "$work/e4" --backend tpu
expect_basic_refusals pruning
echo "bench_pruning_quick: OK"
