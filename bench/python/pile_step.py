"""Milliseconds per step of the 100k-sphere pile (scenes/pile_100k.json) from Python against the CLI.

    PYTHONPATH=build/python python3 bench/python/pile_step.py [--cli build/bin/dvisim] [--steps 10] [--rounds 3]
                                                            [--threads 1] [--scene scenes/pile_100k.json]

Each round runs the CLI (`dvisim run SCENE --backend cpu --steps N --threads T`, its summary.json ms_per_step,
the time inside the steps) and then Python on the same scene and settings, twice: step(N) in one call, and step(1)
N times from a Python loop; Python's time is the wall time around the calls (perf_counter), so it includes
everything the binding adds. Rounds alternate so that load on the machine hits all alike; the medians are
compared; the order within a round alternates. Prints one line per round and the ratios Python / CLI (docs/PYTHON.md "Speed").
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import dvisim


def cli_ms(cli, scene, steps, threads):
    with tempfile.TemporaryDirectory() as d:
        subprocess.run([cli, "run", scene, "--backend", "cpu", "--steps", str(steps), "--threads", str(threads),
                        "--out", d + "/o"], check=True, capture_output=True)
        with open(d + "/o/summary.json") as f:
            return json.load(f)["ms_per_step"]


def python_ms(scene, steps, threads, one_call):
    sim = dvisim.load_scene(scene, {"settings.threads": threads}, backend="cpu")
    t0 = time.perf_counter()
    if one_call:
        sim.step(steps)
    else:
        for _ in range(steps):
            sim.step(1)
    wall = time.perf_counter() - t0
    return 1000.0 * wall / steps


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(os.path.dirname(here))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cli", default=os.path.join(root, "build", "bin", "dvisim"))
    ap.add_argument("--scene", default=os.path.join(root, "scenes", "pile_100k.json"))
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    rows = []
    for r in range(a.rounds):
        if r % 2 == 0:  # the order alternates, so that a drift in the machine's load favours neither
            c = cli_ms(a.cli, a.scene, a.steps, a.threads)
        p1 = python_ms(a.scene, a.steps, a.threads, True)
        pn = python_ms(a.scene, a.steps, a.threads, False)
        if r % 2 == 1:
            c = cli_ms(a.cli, a.scene, a.steps, a.threads)
        rows.append((c, p1, pn))
        print(f"round {r + 1}: cli {c:.2f} ms/step, python step({a.steps}) {p1:.2f}, python step(1) x{a.steps} "
              f"{pn:.2f}", flush=True)
    c, p1, pn = (statistics.median(x) for x in zip(*rows))
    print(f"median over {a.rounds} rounds of {a.steps} steps ({a.threads} thread(s)): cli {c:.2f} ms/step, "
          f"python {p1:.2f} (ratio {p1 / c:.3f}), python loop {pn:.2f} (ratio {pn / c:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
