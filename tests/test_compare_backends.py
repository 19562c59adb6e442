#!/usr/bin/env python3
"""scripts/ces_validation/compare_backends.py against Welch's interval worked by hand.

Two sweeps of one setting, seeds [1, 2, 3] against [2, 3, 4] (difference 1) and [11, 12, 13] (difference 10):
s^2 = 1 each, se^2 = 1/3 + 1/3, Welch-Satterthwaite df = (2/3)^2 / (2 (1/3)^2 / 2) = 4, t(0.975, 4) = 2.776,
half-width 2.776 sqrt(2/3) = 2.2666. So the first agrees and the second differs.
"""
import csv
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "scripts", "ces_validation", "compare_backends.py")


def sweep(root, name, values):
    d = os.path.join(root, name)
    os.makedirs(d)
    with open(os.path.join(d, "runs.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "feed.mass_flow_g_s", "seed", "status", "fixed.conductor.grade"])
        for i, v in enumerate(values):
            w.writerow(["000-seed%d" % (i + 1), "2", str(i + 1), "ok", repr(v)])
        w.writerow(["000-seed9", "2", "9", "failed", "99"])  # an unfinished run is left out
    return d


def compare(a, b):
    out = subprocess.run([sys.executable, SCRIPT, "--a", "cpu=" + a, "--b", "gpu=" + b], check=True,
                         capture_output=True, text=True).stdout
    rows = [line for line in out.splitlines() if line.startswith("| 2 |")]
    assert len(rows) == 1, out
    return rows[0], out


def main():
    with tempfile.TemporaryDirectory() as root:
        a = sweep(root, "a", [1.0, 2.0, 3.0])
        row, out = compare(a, sweep(root, "b", [2.0, 3.0, 4.0]))
        assert "+1.000 ± 2.267" in row and "| agree |" in row, row
        assert "2.000 ± 2.484 (3)" in row, row  # mean ± t(0.975, 2) s / sqrt(3) = 4.303 / sqrt(3)
        assert "1 of 1 comparisons agree" in out, out
        row, out = compare(a, sweep(root, "c", [11.0, 12.0, 13.0]))
        assert "+10.000 ± 2.267" in row and "| DIFFER |" in row, row
        assert "0 of 1 comparisons agree" in out, out
    print("compare_backends: Welch's interval as worked by hand")


if __name__ == "__main__":
    main()
