#!/usr/bin/env bash
# `mpirun -np 2 dvisim bench scaling --mpi --quick`: four rows (weak and strong, one process and two); the strong
# rows step the same pile, so two processes must find the one process's contacts (each owned once: the same count
# per step within 0.5 %); the two-process rows move ghosts and velocity changes, the one-process rows nothing; the
# efficiencies are positive and finite. Another benchmark under mpirun is refused with exit code 2.
# Usage: bench_scaling_mpi.sh MPIEXEC DVISIM SOURCE_DIR WORK_DIR (SOURCE_DIR unused: the scene is built in)
set -euo pipefail
mpiexec=$1 dvisim=$2 work=$4
rm -rf "$work" && mkdir -p "$work"
mpirun=("$mpiexec" -np 2 --oversubscribe --allow-run-as-root)
"${mpirun[@]}" "$dvisim" bench scaling --mpi --quick --out "$work/out" > "$work/bench.log"
python3 - "$work/out/scaling_mpi.csv" <<'PY'
import csv, math, sys
rows = list(csv.DictReader(open(sys.argv[1])))
assert [(r["mode"], r["processes"]) for r in rows] == [("weak", "1"), ("weak", "2"), ("strong", "1"), ("strong", "2")], rows
s1, s2 = rows[2], rows[3]
c1, c2 = float(s1["contacts"]), float(s2["contacts"])
print("bench scaling --mpi: strong contacts per step %.1f (one process) and %.1f (two); efficiencies %s"
      % (c1, c2, ", ".join(r["efficiency"] for r in rows)))
assert c1 > 1000 and abs(c2 - c1) <= 0.005 * c1, (c1, c2)
for r in rows:
    e = float(r["efficiency"])
    assert math.isfinite(e) and e > 0, r
    moved = float(r["ghost_kib"]) + float(r["exchange_kib"])
    assert (moved > 0) == (r["processes"] == "2"), r
PY
set +e
"${mpirun[@]}" "$dvisim" bench dropin --quick --out "$work/refused" > "$work/refused.log" 2>&1
rc=$?
set -e
grep -q "bench scaling --mpi" "$work/refused.log"
[ "$rc" -eq 2 ] || { echo "bench dropin under mpirun: exit code $rc, expected 2"; exit 1; }
echo "bench scaling --mpi: ok"
