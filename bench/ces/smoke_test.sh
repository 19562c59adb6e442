#!/usr/bin/env bash
# CTest smoke test of `dvisim bench ces --quick` (tests/CMakeLists.txt: bench_ces_quick): ces_bench.json and
# ces_bench.md exist, the JSON has every field with sane values, the mass balance closes exactly and nothing is
# lost, a run cut by --wall-limit says so, and bad input ends with a one-line error and exit code 2. (Collection is
# not reached in 0.02 s of machine time; the Catch2 test "CES machine: the mass balance closes exactly" covers it.)
#   bash smoke_test.sh DVISIM_BINARY WORK_DIR
source "$(dirname "$0")/../smoke_common.sh" "$@"

run_bench ces --quick --threads 2
json="$work/out/ces_bench.json"
md="$work/out/ces_bench.md"
expect_files "$json" "$md"
grep -q "do not edit by hand" "$md" || fail "no header in $md"
grep -q "^mass balance: .*closes exactly" "$work/stdout.txt" || fail "no closing mass balance on stdout"
grep -q "no verdict: --duration" "$work/stdout.txt" || fail "no goal line (no verdict) on stdout"
python3 - "$json" <<'PY' || fail "bad fields in $json"
import json, sys
j = json.load(open(sys.argv[1]))
need = ["device", "backend", "commit", "date", "machine", "target", "reached", "wall_s", "setup_s", "ms_per_step_mean",
        "ms_per_step_last10pct", "fed_particles", "fed_particles_per_s", "fed_mass_flow_g_s", "bodies_in_flight_max",
        "bodies_in_flight_final", "contacts_per_step_mean", "contacts_per_step_max", "stages", "stage_seconds",
        "mass_balance", "goal", "progress"]
missing = [k for k in need if k not in j]
assert not missing, "missing %s" % missing
assert j["backend"] == "cpu" and j["quick"] is True and j["device"] and j["commit"] and j["date"].endswith("Z")
m = j["machine"]
assert m["dt"] > 0 and m["solver"] and m["iterations"] > 0 and m["diameter_mm"] == [0.5, 1.0], m
t, r = j["target"], j["reached"]
assert t["duration_s"] == 0.02 and t["rate_particles_per_s"] == 5000 and t["mass_flow_g_s"] > 0, t
assert r["stopped_by"] == "duration" and r["steps"] == t["steps"] and abs(r["sim_time_s"] - 0.02) < 1e-9, r
assert j["ms_per_step_mean"] > 0 and j["ms_per_step_last10pct"] > 0 and j["wall_s"] > 0
# 0.02 s at 5,000/s: ~100 particles (the count of a fixed mass flow scatters; 25% is generous)
assert 75 <= j["fed_particles"] <= 125, j["fed_particles"]
assert abs(j["fed_particles_per_s"] - j["fed_particles"] / 0.02) < 1e-6 * j["fed_particles_per_s"]
assert abs(j["fed_mass_flow_g_s"] / t["mass_flow_g_s"] - 1) < 0.2
assert j["bodies_in_flight_max"] >= j["bodies_in_flight_final"] > 0
assert j["contacts_per_step_max"] >= j["contacts_per_step_mean"] >= 0
assert len(j["stages"]) > 0 and all(s in j["stage_seconds"] for s in j["stages"])
assert all(v >= 0 for v in j["stage_seconds"].values())
b = j["mass_balance"]
assert b["balance_closes"] is True and b["in_flight_count_agrees"] is True, b
assert b["fed_particles"] == j["fed_particles"] == b["collected_particles"] + b["in_flight_particles"] + b["lost_particles"]
assert b["lost_particles"] == 0 and b["lost_mass_kg"] == 0, b
assert b["in_flight_particles"] == j["bodies_in_flight_final"]
g = j["goal"]
assert g["valid"] is False and g["met"] is None and g["verdict"].startswith("no verdict:"), g
assert len(j["progress"]) >= 9, len(j["progress"])
PY

# A run cut by the wall limit reports the machine time it reached.
"$cli" bench ces --quick --duration 5 --wall-limit 0.3 --out "$work/cut" > "$work/cut.txt" 2>&1
rc=$?
[ $rc -eq 0 ] || { cat "$work/cut.txt"; fail "bench ces --wall-limit exited with $rc"; }
python3 - "$work/cut/ces_bench.json" <<'PY' || fail "the wall-limited run"
import json, sys
j = json.load(open(sys.argv[1]))
r = j["reached"]
assert r["stopped_by"] == "wall_limit" and r["steps"] < j["target"]["steps"] and r["sim_time_s"] < 5, r
assert j["mass_balance"]["balance_closes"] is True
PY

expect2 bench ces --quick --out "$work/e" --backend bogus
expect2 bench ces --quick --out "$work/e" --backend bullet
expect2 bench ces --quick --out "$work/e" --rate -5
expect2 bench ces --quick --out "$work/e" --duration -1
expect2 bench ces --quick --out "$work/e" --duration abc
expect2 bench ces --quick --out "$work/e" --wall-limit 0
expect2 bench ces --quick --out "$work/e" --set drum.rpm=fast
expect2 bench ces --quick --out "$work/e" --set no_such_key=1
expect2 bench ces --quick --out "$work/e" --set feed.mass_flow_g_s=3
expect2 bench ces --quick --out "$work/e" --set output.frames=5
expect_basic_refusals ces
echo "bench_ces_quick: OK"
