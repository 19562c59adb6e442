#!/bin/bash
# The default CES machine's trend points on the CPU, seeds 1-3, one thread per run, in parallel (the device
# machine's 16 cores): -20 / -45 kV at 44.8 rpm and 30 / 60 rpm at -35 kV, printed beside each other to compare
# with the table in docs/CES.md ("Trends of the default machine").
#   bash scripts/device/ces_trend_check.sh BUILD_DIR [JOBS]
set -u
B=$1
J=${2:-16}
W=${WORK:-/tmp/ces_trend}
rm -rf "$W" && mkdir -p "$W"
$B/bin/dvisim sweep --grid electrode.voltage_kV=-20,-45 --seeds 3 --jobs "$J" --threads 1 --out "$W/U" > "$W/U.log" 2>&1
echo "sweep voltage rc=$?"
$B/bin/dvisim sweep --grid drum.rpm=30,60 --seeds 3 --jobs "$J" --threads 1 --out "$W/rpm" > "$W/rpm.log" 2>&1
echo "sweep rpm rc=$?"
python3 - "$W" <<'PY'
import csv, sys
want = ["copper.mean_landing_mm", "copper.positive_charge_fraction", "pinned.plastic", "fixed.nonconductor.grade",
        "holdup.mass_fraction", "lost.mass_fraction"]
for d in ("U", "rpm"):
    rows = list(csv.DictReader(open(sys.argv[1] + "/" + d + "/runs.csv")))
    key = "electrode.voltage_kV" if d == "U" else "drum.rpm"
    for r in rows:
        print(key, r[key], "seed", r["seed"], r["status"], " ".join("%s=%s" % (w, r.get(w, "?")) for w in want))
PY
