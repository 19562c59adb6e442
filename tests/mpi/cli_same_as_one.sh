#!/usr/bin/env bash
# `mpirun -np 2 dvisim run SCENE` against `dvisim run SCENE --backend cpu` (one process): the same bodies.csv up to
# the order of summation (every position within 1e-6 of the smallest radius, 1e-8 m for scenes/pile.json), a
# summary.json that says 2 processes, and a refused option and the CES machine (exit code 2 on every process).
# Usage: cli_same_as_one.sh MPIEXEC DVISIM SOURCE_DIR WORK_DIR
set -euo pipefail
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
mpirun=("$mpiexec" -np 2 --oversubscribe --allow-run-as-root)
scene="$src/scenes/pile.json"
"${mpirun[@]}" "$dvisim" run "$scene" --steps 150 --out "$work/many" > "$work/many.log"
"$dvisim" run "$scene" --backend cpu --steps 150 --out "$work/one" > "$work/one.log"
python3 - "$work/many" "$work/one" <<'PY'
import csv, json, sys
many, one = sys.argv[1], sys.argv[2]
def rows(d):
    with open(d + "/bodies.csv") as f:
        return list(csv.DictReader(f))
a, b = rows(many), rows(one)
assert len(a) == len(b) == 1005, (len(a), len(b))
worst = max(max(abs(float(x[k]) - float(y[k])) for k in ("x", "y", "z")) for x, y in zip(a, b))
s = json.load(open(many + "/summary.json"))
s1 = json.load(open(one + "/summary.json"))
print("cli: max position difference %.3e m over %d bodies, processes %d, migrations %d, contacts_mean %.1f (one process %.1f)"
      % (worst, len(a), s["processes"], s["migrations"], s["contacts_mean"], s1["contacts_mean"]))
assert worst < 1e-8, worst
assert s["processes"] == 2 and s["status"] == "done" and s["migrations"] > 0
assert abs(s["contacts_mean"] - s1["contacts_mean"]) <= 1e-9 * max(1.0, s1["contacts_mean"])
PY
set +e
"${mpirun[@]}" "$dvisim" run "$scene" --steps 2 --solver gs --out "$work/refused" > "$work/refused.log" 2>&1
rc=$?
set -e
grep -q "Gauss-Seidel is sequential and does not run over several processes" "$work/refused.log" || { cat "$work/refused.log"; exit 1; }
[ "$rc" -ne 0 ] || { echo "a refused option exited 0"; exit 1; }
echo "cli: --solver gs refused (exit $rc)"
set +e
"${mpirun[@]}" "$dvisim" run --steps 2 --out "$work/ces" > "$work/ces.log" 2>&1
rc=$?
set -e
grep -q "a CES machine does not run over several processes" "$work/ces.log" || { cat "$work/ces.log"; exit 1; }
[ "$rc" -ne 0 ] && [ ! -e "$work/ces" ] || { echo "the CES machine under mpirun: exit $rc"; exit 1; }
echo "cli: the CES machine refused under mpirun (exit $rc)"
