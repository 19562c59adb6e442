#!/usr/bin/env bash
# `mpirun -np 2 dvisim run SCENE` against `dvisim run SCENE --backend cpu` (one process): the same bodies.csv up to
# the order of summation (every position within 1e-6 of the smallest radius, 1e-8 m for scenes/pile.json), a
# summary.json that says 2 processes, the same 3 frames (each a .pvtp in frames.pvd whose pieces hold every body
# once, at the one-process frame's positions within 1e-8 m; the last one at bodies.csv's), and a refused option and
# the CES machine (exit code 2 on every process).
# Usage: cli_same_as_one.sh MPIEXEC DVISIM SOURCE_DIR WORK_DIR
set -euo pipefail
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
mpirun=("$mpiexec" -np 2 --oversubscribe --allow-run-as-root)
scene="$src/scenes/pile.json"
"${mpirun[@]}" "$dvisim" run "$scene" --steps 150 --frames 3 --out "$work/many" > "$work/many.log"
"$dvisim" run "$scene" --backend cpu --steps 150 --frames 3 --out "$work/one" > "$work/one.log"
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
import os, xml.etree.ElementTree as ET
def datasets(d):
    return [(float(e.get("timestep")), e.get("file")) for e in ET.parse(d + "/frames.pvd").iter("DataSet")]
def points(path):  # {id: (x, y, z)} of one .vtp
    piece = ET.parse(path).find("PolyData/Piece")
    ids = [int(v) for v in piece.find("PointData/DataArray[@Name='id']").text.split()] if int(piece.get("NumberOfPoints")) else []
    xyz = [float(v) for v in (piece.find("Points/DataArray").text or "").split()]
    assert len(xyz) == 3 * len(ids), path
    return {i: tuple(xyz[3 * k:3 * k + 3]) for k, i in enumerate(ids)}
fm, fo = datasets(many), datasets(one)
assert [t for t, _ in fm] == [t for t, _ in fo] and len(fm) == 3 and s["frames"] == 3, (fm, fo)
frame_worst = 0.0
for (t, pvtp), (_, vtp) in zip(fm, fo):
    assert pvtp.endswith(".pvtp"), pvtp
    pieces = [e.get("Source") for e in ET.parse(many + "/" + pvtp).iter("Piece")]
    assert len(pieces) == 2, pieces
    seen = {}
    for p in pieces:
        got = points(many + "/" + p)
        assert not (set(got) & set(seen)), "a body in two pieces"
        seen.update(got)
    ref = points(one + "/" + vtp)
    assert sorted(seen) == sorted(ref) == list(range(1005)), (len(seen), len(ref))
    frame_worst = max(frame_worst, max(max(abs(a - b) for a, b in zip(seen[i], ref[i])) for i in ref))
last = seen
for i, r in enumerate(a):
    assert max(abs(last[i][k] - float(r[c])) for k, c in enumerate("xyz")) < 1e-12, i
print("cli: 3 parallel frames, every body once in the pieces, max difference to the one-process frames %.3e m" % frame_worst)
assert frame_worst < 1e-8, frame_worst
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
