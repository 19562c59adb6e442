"""The CES machine from Python against `dvisim sweep`: the same runs with the same seeds give the same numbers, bit
for bit (per-run metrics and final states), and the same 95% confidence intervals."""

import csv
import json
import math

import pytest

import dvisim
from conftest import run_cli

GRID = {"electrode.voltage_kV": [-20, -40]}
DURATION = 0.1  # s: about 120 particles fed, ~1 s of CPU a run


def fmt10(v):  # summary.csv's number format (bench_util.h: num, "%.10g"; empty for NaN)
    return "" if v is None or not math.isfinite(v) else "%.10g" % v


@pytest.fixture(scope="module")
def both(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("ces")
    run_cli(cli, "sweep", "--grid", "electrode.voltage_kV=-20,-40", "--seeds", "2", "--time", DURATION, "--backend",
            "cpu", "--threads", "1", "--jobs", "1", "--no-plots", "--out", d / "cli")
    py = dvisim.ces.sweep(GRID, seeds=2, duration=DURATION, backend="cpu", threads=1, out=d / "py")
    return d, py


def test_sweep_metrics_are_the_clis_bit_for_bit(both):
    d, py = both
    assert [c["id"] for c in py["cases"]] == ["000-seed1", "000-seed2", "001-seed1", "001-seed2"]
    for case in py["cases"]:
        cli_summary = json.loads((d / "cli" / "runs" / case["id"] / "summary.json").read_text())
        cli_metrics = cli_summary["ces"]["metrics"]
        assert len(cli_metrics) > 20
        assert case["metrics"] == cli_metrics, case["id"]  # every float equal, not close
        # the whole final state of the machine, byte for byte
        assert (d / "py" / "runs" / case["id"] / "bodies.csv").read_bytes() == \
            (d / "cli" / "runs" / case["id"] / "bodies.csv").read_bytes()
    # the seed and the voltage reached the machine: the runs differ from each other
    states = {(d / "py" / "runs" / c["id"] / "bodies.csv").read_bytes() for c in py["cases"]}
    assert len(states) == 4


def test_sweep_confidence_intervals_are_the_clis(both):
    d, py = both
    with open(d / "cli" / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(py["summary"]) == 2
    compared = 0
    for row, mine in zip(rows, py["summary"]):
        assert int(row["n"]) == mine["n"] == 2
        assert float(row["electrode.voltage_kV"]) == float(mine["values"]["electrode.voltage_kV"])
        for name, value in mine.items():
            if not isinstance(value, tuple):
                continue
            mean, half = value
            assert row[name + ".mean"] == fmt10(mean), name
            assert row[name + ".ci95"] == fmt10(half), name
            compared += 1
    assert compared > 20


def test_sweep_paired_differences_are_the_clis(both):
    d, py = both
    with open(d / "cli" / "paired.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(py["paired"]) == 1
    row, mine = rows[0], py["paired"][0]
    assert int(row["n"]) == mine["n"] == 2
    compared = 0
    for name, value in mine.items():
        if isinstance(value, tuple):
            assert row[name + ".diff"] == fmt10(value[0]) and row[name + ".ci95"] == fmt10(value[1]), name
            compared += 1
    assert compared > 20 and mine["voltage_kV"][0] == -20  # -40 kV against -20 kV, the same in both seeds


def test_mean_ci_is_students_t():
    # n = 3, s = 1: half-width t_{0.975,2} / sqrt(3) with t_{0.975,2} = 4.302652729 (tables)
    n, mean, half = dvisim.ces.mean_ci([1.0, 2.0, 3.0])
    assert n == 3 and mean == 2.0 and half == pytest.approx(4.302652729 / math.sqrt(3), rel=1e-9)


def test_run_returns_summary_tables_and_splitter_map(tmp_path):
    r = dvisim.ces.run({"electrode.voltage_kV": -30}, duration=0.02, backend="cpu", seed=3, out=tmp_path / "r")
    assert r.summary["status"] == "done" and r.summary["ces"]["balance_closes"] is True
    fed = r.summary["ces"]["fed_particles"]
    assert len(r.particles) == fed  # one row per particle fed
    assert r.splitters is not None and len(r.splitters) > 100 and "s1_mm" in r.splitters.dtype.names
    assert r.metrics["voltage_kV"] == -30 and r.out == str(tmp_path / "r")
