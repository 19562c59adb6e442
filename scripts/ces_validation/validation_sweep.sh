#!/bin/bash
# The validation runs of docs/CES.md ("Validation: published experiments"): scenes/ces_validation_pcb.json (the
# default machine, a crushed-PCB feed of ~27% metal) at the voltages and roll speeds of settings.csv, 3 seeds each,
# fed 0.5 g/s for 0.3 s and run 1.5 s of machine time (the scene's own duration_s and feed.duration_s), into
# OUT_DIR/main; the slow drum (30 rpm, -30 kV) needs 3 s to clear the drum and the brush: OUT_DIR/slow.
#   scripts/ces_validation/validation_sweep.sh DVISIM OUT_DIR [JOBS] [BACKEND]
set -eu
BIN=$1
OUT=$2
JOBS=${3:-2}
BACKEND=${4:-cpu}
HERE=$(cd "$(dirname "$0")" && pwd)
SCENE="$HERE/../../scenes/ces_validation_pcb.json"
"$BIN" sweep "$SCENE" --list "$HERE/settings.csv" --seeds "${SEEDS:-3}" --backend "$BACKEND" --jobs "$JOBS" \
  --threads 1 --no-plots --out "$OUT/main"
"$BIN" sweep "$SCENE" --grid drum.rpm=30 --set electrode.voltage_kV=-30 --set duration_s=3 --seeds "${SEEDS:-3}" \
  --backend "$BACKEND" --jobs "$JOBS" --threads 1 --no-plots --out "$OUT/slow"
python3 "$HERE/table.py" "$OUT/main" | tee "$OUT/validation_table.md"
python3 "$HERE/table.py" "$OUT/slow" | tail -n 1 | tee -a "$OUT/validation_table.md"
