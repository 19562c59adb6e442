#!/bin/bash
# The feed-rate sweep of docs/CES.md ("Feed rate and crowding"): the default machine on a 30 mm slice of the drum
# (drum.width_mm = 30, end walls at +-15 mm, feed.width_mm = 28), so that a feed per metre of roll that would
# need 10x the particles on the full 300 mm drum costs the slice's; the full-width equivalent of a slice feed is
# 10x it (280 / 28). Each setting is fed for 0.3 s and run for 1.5 s of machine time, 3 seeds.
#   scripts/ces_validation/feed_sweep.sh DVISIM BACKEND OUT_DIR [RATES_G_S] [JOBS]
# RATES_G_S are the slice's feeds (default 20,14,8,4,2,0.8,0.2,0.05 g/s = 200 ... 0.5 g/s full width, the largest
# and costliest first, so that a sweep stopped by a time limit has them; the
# monolayer of the default feed is 13.8 g/s on the slice, 138 g/s full width: summary metric feed.monolayer_g_s).
# The low-rate part on the CPU:   scripts/ces_validation/feed_sweep.sh build/bin/dvisim cpu /tmp/feed_cpu 0.05,0.2 2
# The whole sweep on one GPU:     scripts/ces_validation/feed_sweep.sh build-dev/bin/dvisim gpu "$OUT/feed" "" 4
set -eu
BIN=$1
BACKEND=$2
OUT=$3
RATES=${4:-20,14,8,4,2,0.8,0.2,0.05}
[ -n "$RATES" ] || RATES=20,14,8,4,2,0.8,0.2,0.05
JOBS=${5:-2}
HERE=$(cd "$(dirname "$0")" && pwd)
# TIMEOUT_S (default 0: none) stops the sweep with SIGTERM after that many seconds; a sweep stopped so (exit 4 or
# 124) or with a failed run (exit 1) still writes its tables, and the same command again resumes it (docs/SWEEP.md).
rc=0
LIMIT=()
[ "${TIMEOUT_S:-0}" != 0 ] && LIMIT=(timeout -s TERM "$TIMEOUT_S")
mkdir -p "$OUT"
# Provenance beside the tables: commit (DVISIM_COMMIT, else the source tree's HEAD), device, date, command.
{
  echo "- commit: ${DVISIM_COMMIT:-$(git -C "$HERE" rev-parse --short HEAD 2>/dev/null || echo unknown)}"
  if [ "$BACKEND" = gpu ] && command -v nvidia-smi > /dev/null; then
    echo "- device: $(nvidia-smi --query-gpu=name --format=csv,noheader | head -1)"
  else
    echo "- device: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores"
  fi
  echo "- date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  echo "- command: feed_sweep.sh $BIN $BACKEND $OUT $RATES $JOBS (SEEDS=${SEEDS:-3}, TIMEOUT_S=${TIMEOUT_S:-0})"
} >> "$OUT/provenance.md"  # a resumed sweep adds its lines
"${LIMIT[@]}" "$BIN" sweep --grid feed.mass_flow_g_s="$RATES" --seeds "${SEEDS:-3}" --backend "$BACKEND" --jobs "$JOBS" \
  --set drum.width_mm=30 --set feed.width_mm=28 --set feed.duration_s=0.3 --set duration_s=1.5 --no-plots \
  --out "$OUT" || rc=$?
python3 "$HERE/table.py" "$OUT" --feed-scale 10 | tee "$OUT/feed_table.md"
exit $rc
