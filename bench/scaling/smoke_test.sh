#!/usr/bin/env bash
# CTest smoke test of `dvisim bench scaling --quick` (tests/CMakeLists.txt: bench_scaling_quick):
# the CSV has the expected columns and one row per engine x scene x N, measured rows have sane values
# (times > 0, contacts > 0, finite penetration), the Bullet 3 OpenCL rows are measured or say why not (never an
# error), and bad input ends with a one-line error and exit code 2.
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

# One CPU thread: the test machine's cores are shared with the other tests (an oversubscribed OpenMP team
# can be 100x slower), and the smoke test checks the outputs, not the speed.
run_bench scaling --quick --threads 1
csv="$work/out/scaling.csv"

expected="engine,scene,n,bodies,threads,warmup_steps,timed_steps,pairs_kept_steps,setup_s,ms_per_step,ms_broad,ms_narrow,ms_solve,ms_integrate,ms_other,contacts,iterations,max_penetration_rel,ref_length_m,device_mib,solve_model_gbps,copy_gbps,solve_pct_of_copy,device,status"
expect_header "$csv" "$expected"

# Every engine x scene x N planned: gpu (measured or skipped), cpu and bullet (measured), bullet3_opencl
# (measured, or not run where the build has no peer or no OpenCL GPU exists).
for scene in pile mix; do
  for n in 1000 4000; do
    for engine in gpu cpu bullet bullet3_opencl; do
      c=$(awk -F, -v e=$engine -v s=$scene -v n=$n '$1==e && $2==s && $3==n' "$csv" | wc -l)
      [ "$c" -eq 1 ] || fail "expected one row $engine $scene $n, got $c"
    done
  done
done

# Field checks (columns by name).
check_rows() {
awk -F, '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
{
  st = $col["status"]; e = $1
  if (st ~ /^error/) { print "row " NR ": " e " " $2 " " $3 ": " st; bad = 1; next }
  if (st != "ok") {
    if (e == "cpu" || e == "bullet") { print "row " NR ": " e " did not run: " st; bad = 1 }
    next
  }
  if (!($col["ms_per_step"] > 0)) { print "row " NR ": ms_per_step " $col["ms_per_step"]; bad = 1 }
  if (!($col["contacts"] > 0)) { print "row " NR ": contacts " $col["contacts"]; bad = 1 }
  if (!($col["bodies"] >= $col["n"])) { print "row " NR ": bodies " $col["bodies"] " < n"; bad = 1 }
  if (!($col["timed_steps"] >= 1)) { print "row " NR ": timed_steps " $col["timed_steps"]; bad = 1 }
  p = $col["max_penetration_rel"]
  if (p == "" || !(p >= 0 && p < 1)) { print "row " NR ": max_penetration_rel " p; bad = 1 }
  if (e != "bullet" && e != "bullet3_opencl") {
    if ($col["iterations"] != 50) { print "row " NR ": iterations " $col["iterations"]; bad = 1 }
    s = $col["ms_broad"] + $col["ms_narrow"] + $col["ms_solve"] + $col["ms_integrate"]
    if (!(s > 0 && s <= 1.01 * $col["ms_per_step"] + 0.01)) { print "row " NR ": stages " s " vs step " $col["ms_per_step"]; bad = 1 }
    if (!($col["solve_model_gbps"] > 0)) { print "row " NR ": solve_model_gbps " $col["solve_model_gbps"]; bad = 1 }
  }
  if (e == "gpu" && !($col["device_mib"] > 0)) { print "row " NR ": device_mib " $col["device_mib"]; bad = 1 }
}
END { exit bad }' "$1" || fail "bad values in $1"
}
check_rows "$csv"
grep -q "Goals, from this run" "$work/stdout.txt" || fail "no goals table on stdout"

# The Bullet 3 peer on an OpenCL CPU device (pocl), where one exists: its rows measured through the worker
# process, or "not run: ..." where this build has no peer or the machine no OpenCL CPU device (CI).
"$cli" bench scaling --quick --threads 1 --engines bullet3_opencl --bullet3-device cpu --sizes 1k \
  --out "$work/b3" > "$work/b3_stdout.txt" 2>&1 || { cat "$work/b3_stdout.txt"; fail "bench scaling --bullet3-device cpu failed"; }
b3csv="$work/b3/scaling.csv"
[ "$(awk -F, '$1 == "bullet3_opencl"' "$b3csv" | wc -l)" -eq 2 ] || fail "expected 2 bullet3_opencl rows in $b3csv"
check_rows "$b3csv"
grep -q "bullet3_opencl,pile,1000,.*,ok$" "$b3csv" && echo "bullet3_opencl on the OpenCL CPU device: measured" \
  || echo "bullet3_opencl on the OpenCL CPU device: $(awk -F, '$1 == "bullet3_opencl" {print $NF; exit}' "$b3csv")"

# Bad input: one line on stderr, exit code 2, and nothing else.
expect2 bench scaling --quick --out "$work/e1" --sizes 10k,abc
expect2 bench scaling --quick --out "$work/e2" --sizes 0
expect2 bench scaling --quick --out "$work/e4" --scenes pile,sand
expect2 bench scaling --quick --out "$work/e5" --engines bullet4
expect2 bench scaling --quick --out "$work/e6" --bullet3-device fpga
expect2 bench
expect_basic_refusals scaling
echo "bench_scaling_quick: OK"
