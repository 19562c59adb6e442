#!/usr/bin/env bash
# SIGTERM to one process of `mpirun -np 2 dvisim run SCENE`: every process stops after the same step, process 0
# writes the results so far (summary.json status "interrupted", steps < planned, bodies.csv of every body with
# finite positions) and the run exits with code 4, as one process's run does.
# Usage: interrupt.sh MPIEXEC DVISIM SOURCE_DIR WORK_DIR
set -uo pipefail
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
out="$work/interrupted-run"
timeout 300 "$mpiexec" -np 2 --oversubscribe --allow-run-as-root "$dvisim" run "$src/scenes/pile.json" \
  --steps 1000000 --out "$out" > "$work/run.log" 2>&1 &
launcher=$!
for _ in $(seq 1 100); do  # until the run has its results directory (made before the first step), at most 20 s
  compgen -G "$work/.interrupted-run.tmp-*" > /dev/null && break
  sleep 0.2
done
sleep 1
rank=$(pgrep -f -- "--out $out" | while read -r p; do [ "$(ps -o comm= -p "$p")" = dvisim ] && echo "$p"; done | tail -n 1)
[ -n "$rank" ] || { echo "no dvisim process found"; cat "$work/run.log"; exit 1; }
kill -TERM "$rank"
wait "$launcher"
rc=$?
[ "$rc" -eq 4 ] || { echo "exit code $rc, expected 4"; cat "$work/run.log"; exit 1; }
python3 - "$out" <<'PY'
import csv, json, math, sys
d = sys.argv[1]
s = json.load(open(d + "/summary.json"))
rows = list(csv.DictReader(open(d + "/bodies.csv")))
print("interrupted run: status %s after %d of %d steps, %d bodies" % (s["status"], s["steps"], s["steps_planned"], len(rows)))
assert s["status"] == "interrupted" and 0 < s["steps"] < s["steps_planned"] and s["processes"] == 2, s
assert len(rows) == 1005 and all(math.isfinite(float(r[k])) for r in rows for k in ("x", "y", "z"))
PY
