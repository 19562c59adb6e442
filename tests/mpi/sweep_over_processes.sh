#!/usr/bin/env bash
# `mpirun -np 2 dvisim sweep ...` against the same sweep on one process: every case run once, by the process that
# owns it (case i on process i mod 2), and runs.csv, summary.csv and paired.csv the one-process sweep's up to the
# timing columns; a second mpirun of the same sweep finds every case finished and runs none. Another subcommand
# under mpirun is still refused with exit code 2.
# Usage: sweep_over_processes.sh MPIEXEC DVISIM SOURCE_DIR WORK_DIR
set -euo pipefail
mpiexec=$1 dvisim=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
mpirun=("$mpiexec" -np 2 --oversubscribe --allow-run-as-root)
args=("$src/scenes/pile.json" --grid settings.dt=0.001,0.002 --seeds 2 --seed-key bodies.5.generator.seed
      --steps 40 --no-plots)
"${mpirun[@]}" "$dvisim" sweep "${args[@]}" --out "$work/many" > "$work/many.log"
"$dvisim" sweep "${args[@]}" --out "$work/one" > "$work/one.log"
"${mpirun[@]}" "$dvisim" sweep "${args[@]}" --out "$work/many" > "$work/again.log"
python3 - "$work" <<'PY'
import csv, re, sys
work = sys.argv[1]
timing = re.compile(r"^(wall_s|wall_time_s|ms_per_step|stage_seconds|checkpoint_seconds)\b")
def table(name, d):
    with open("%s/%s/%s" % (work, d, name)) as f:
        rows = list(csv.DictReader(f))
    return [{k: v for k, v in r.items() if not timing.match(k)} for r in rows]
for name in ("runs.csv", "summary.csv", "paired.csv"):
    a, b = table(name, "many"), table(name, "one")
    assert a == b, (name, a, b)
log = open(work + "/many.log").read()
ran = re.findall(r"^process (\d) of 2: \[\d/\d\] (\d{3})-seed(\d): ok", log, re.M)
cases = sorted((s, seed) for _, s, seed in ran)
assert cases == [("000", "1"), ("000", "2"), ("001", "1"), ("001", "2")], ran
for proc, s, seed in ran:  # case index = setting * seeds + (seed - 1), on process index mod 2
    assert int(proc) == (int(s) * 2 + int(seed) - 1) % 2, ran
again = open(work + "/again.log").read()
assert again.count("2 already finished, 0 to run") == 2, again
print("sweep over 2 processes: 4 cases, each once, on its process; tables equal the one-process sweep's; rerun: none")
PY
set +e
"${mpirun[@]}" "$dvisim" bench accuracy --quick --out "$work/refused" > "$work/refused.log" 2>&1
rc=$?
set -e
[ "$rc" -eq 2 ] || { echo "bench accuracy under mpirun: exit code $rc, expected 2"; exit 1; }
echo "sweep over processes: ok"
