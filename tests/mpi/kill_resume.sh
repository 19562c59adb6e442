#!/usr/bin/env bash
# SIGKILL to one process of `mpirun -np 2 dvisim run SCENE --checkpoint-every 10`: mpirun ends without results, the
# periodic checkpoints beside --out (complete sets of pieces, the newest two) remain, and `--resume OUT` continues
# from the newest: on 2 processes into OUT, and on one process without mpirun, both ending where the uninterrupted
# run ends (to rounding: a resumed run bisects anew, so its sums go in another order), having lost at most the 10
# steps since that checkpoint.
# Arguments: MPIEXEC DVISIM SOURCE_DIR WORK_DIR.
set -uo pipefail
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
scene="$src/scenes/pile.json"
run() { local np=$1; shift; timeout 300 "$mpiexec" -np "$np" --oversubscribe --allow-run-as-root "$dvisim" run "$scene" "$@"; }
run 2 --steps 100000 --checkpoint-every 10 --out killed > killed.log 2>&1 &
launcher=$!
for _ in $(seq 1 1500); do  # until two periodic checkpoints are there, at most 300 s
  [ "$(ls -d .killed.tmp-*/checkpoints/step_* 2>/dev/null | wc -l)" -ge 2 ] && break
  sleep 0.2
done
rank=$(pgrep -f -- "--out killed" | while read -r p; do [ "$(ps -o comm= -p "$p")" = dvisim ] && echo "$p"; done | tail -n 1)
[ -n "$rank" ] || { echo "no dvisim process found"; cat killed.log; exit 1; }
kill -KILL "$rank"
wait "$launcher"
rc=$?
[ "$rc" -ne 0 ] && [ ! -e killed ] || { echo "mpirun exit $rc (expected a failure) or killed/ exists"; cat killed.log; exit 1; }
sets=$(ls -d .killed.tmp-*/checkpoints/step_* | sort)
[ "$(echo "$sets" | wc -l)" -le 2 ] || { echo "more than two periodic checkpoints: $sets"; exit 1; }
last=$(echo "$sets" | tail -n 1)
[ -f "$last/piece_p0.bin" ] && [ -f "$last/piece_p1.bin" ] && [ -f "$last/manifest.json" ] ||
  { echo "incomplete set $last"; ls "$last"; exit 1; }
step=$(python3 -c "import json, sys; print(json.load(open(sys.argv[1] + '/manifest.json'))['step'])" "$last")
target=$((step + 20))
echo "killed after the checkpoint of step $step; resuming to step $target"
run 2 --steps "$target" --out whole > whole.log 2>&1 || { cat whole.log; exit 1; }
timeout 300 "$dvisim" run "$scene" --backend cpu --steps "$target" --resume killed --out one > one.log 2>&1 ||
  { cat one.log; exit 1; }
run 2 --steps "$target" --resume killed --out killed > two.log 2>&1 || { cat two.log; exit 1; }
grep -q "resuming from .killed.tmp-" two.log || { echo "not resumed from the killed run's checkpoint"; cat two.log; exit 1; }
[ -z "$(ls -d .killed.tmp-* 2>/dev/null)" ] || { echo "the killed run's folder is still there"; exit 1; }
python3 - "$work" "$step" "$target" <<'PY' || exit 1
import csv, json, sys
w, step, target = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
def load(d):
    return [(float(r["x"]), float(r["y"]), float(r["z"])) for r in csv.DictReader(open(w + "/" + d + "/bodies.csv"))]
ref = load("whole")
for d in ("one", "killed"):
    s = json.load(open(w + "/" + d + "/summary.json"))
    assert s["steps"] == target and s["resumed_from_step"] == step, s
    got = load(d)
    assert len(got) == len(ref) == 1005
    diff = max(abs(a - b) for p, q in zip(ref, got) for a, b in zip(p, q))
    print("%s: resumed from step %d, largest position difference to the uninterrupted run %.3e m" % (d, step, diff))
    assert diff < 1e-9, diff
PY
echo "kill_resume: ok"
