#!/usr/bin/env bash
# `mpirun -np 2 dvisim run scenes/pile.json --steps 60` writes checkpoint/ (a piece a process and manifest.json);
# resumed to step 100 on 3 processes and on 1, the bodies end where the uninterrupted 100 steps on 2 processes end
# (to rounding: the resumed runs bisect anew, so their sums go in another order). A damaged piece, another dt and a
# --steps already reached are refused with exit code 2 and no results directory.
# Arguments: MPIEXEC DVISIM SOURCE_DIR WORK_DIR.
set -u
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
scene="$src/scenes/pile.json"
run() { local np=$1; shift; timeout 300 "$mpiexec" -np "$np" --oversubscribe --allow-run-as-root "$dvisim" run "$scene" "$@"; }
run 2 --steps 100 --out whole > whole.log 2>&1 || { cat whole.log; exit 1; }
run 2 --steps 60 --out first > first.log 2>&1 || { cat first.log; exit 1; }
[ -f first/checkpoint/manifest.json ] && [ -f first/checkpoint/piece_p0.bin ] && [ -f first/checkpoint/piece_p1.bin ] ||
  { echo "no checkpoint/ after the run"; ls -R first; exit 1; }
run 3 --steps 100 --resume first --out three > three.log 2>&1 || { cat three.log; exit 1; }
run 1 --steps 100 --resume first --out one > one.log 2>&1 || { cat one.log; exit 1; }
python3 - "$work" <<'PY' || exit 1
import csv, json, sys
w = sys.argv[1]
def load(d):
    return [(float(r["x"]), float(r["y"]), float(r["z"])) for r in csv.DictReader(open(w + "/" + d + "/bodies.csv"))]
ref = load("whole")
for d, np in (("three", 3), ("one", 1)):
    s = json.load(open(w + "/" + d + "/summary.json"))
    assert s["steps"] == 100 and s["resumed_from_step"] == 60 and s["processes"] == np, s
    got = load(d)
    assert len(got) == len(ref) == 1005
    diff = max(abs(a - b) for p, q in zip(ref, got) for a, b in zip(p, q))
    print("resumed on %d process(es): largest position difference to the uninterrupted run %.3e m" % (np, diff))
    assert diff < 1e-9, diff
PY
# Refusals: exit code 2, a one-line reason, nothing written.
cp -r first damaged
python3 -c "
import sys; p = sys.argv[1] + '/damaged/checkpoint/piece_p1.bin'
b = bytearray(open(p, 'rb').read()); b[100] ^= 1; open(p, 'wb').write(b)" "$work"
refuse() {
  local name=$1 pattern=$2; shift 2
  run 2 "$@" --out "$name" > "$name.log" 2>&1
  local rc=$?
  [ "$rc" -eq 2 ] && grep -q "$pattern" "$name.log" && [ ! -e "$name" ] ||
    { echo "$name: exit $rc, expected 2 with '$pattern' and no $name/"; cat "$name.log"; exit 1; }
  echo "refused ($name): $(grep -m1 'error' "$name.log")"
}
refuse bad_piece "checksum mismatch" --steps 100 --resume damaged
refuse bad_dt "give the same --dt" --steps 100 --dt 0.002 --resume first
refuse reached "is at step 60 already" --steps 50 --resume first
echo "resume: ok"
