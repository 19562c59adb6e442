#!/usr/bin/env python3
"""The CPU backend against the GPU backend on the same CES sweep (docs/CES.md, "Feed-rate sweep").

Reads runs.csv of two or more `dvisim sweep` folders (scripts/ces_validation/feed_sweep.sh writes them) and, for
every setting of the grid key that both sides ran, compares the per-seed results of the quantities the feed-rate
table shows. The two backends do not step bitwise alike (different summation orders in the solver), so seeds are
not paired: each side is a sample, and the difference of the means gets Welch's 95% interval (Welch 1947; the
t quantile at the Welch-Satterthwaite degrees of freedom, rounded down). "agree" means the interval holds 0.
Usage: compare_backends.py --key feed.mass_flow_g_s --a cpu=DIR[,DIR...] --b gpu=DIR[,DIR...] [--scale 10]
"""
import argparse
import csv
import math
import os
import sys

# Student's t, two-sided 95% (one-sided 0.975) for 1..30 degrees of freedom (any statistics table).
T975 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042]

METRICS = [
    ("fixed.conductor.grade", "conductor grade"),
    ("fixed.conductor.recovery", "metal recovery"),
    ("fixed.nonconductor.grade", "nonconductor grade"),
    ("fixed.nonconductor.recovery", "plastic recovery"),
    ("fixed.middling.mass_fraction", "middlings (of feed)"),
    ("pinned.plastic", "plastic pinned"),
]


def t975(df):
    if not df >= 1:
        return float("nan")
    return T975[min(int(df), len(T975)) - 1] if df < 31 else 1.96


def stats(xs):
    n = len(xs)
    m = sum(xs) / n
    var = sum((x - m) ** 2 for x in xs) / (n - 1) if n > 1 else float("nan")
    return n, m, var


def welch(a, b):
    """Difference of the means b - a and the half-width of its 95% interval (Welch)."""
    na, ma, va = stats(a)
    nb, mb, vb = stats(b)
    if na < 2 or nb < 2:
        return mb - ma, float("nan")
    sa, sb = va / na, vb / nb
    se2 = sa + sb
    if se2 == 0:
        return mb - ma, 0.0
    df = se2 * se2 / (sa * sa / (na - 1) + sb * sb / (nb - 1)) if sa + sb > 0 else na + nb - 2
    return mb - ma, t975(df) * math.sqrt(se2)


def read_runs(dirs, key):
    """{setting value: {metric: [per-seed values]}} over the finished runs of the folders."""
    out = {}
    for d in dirs:
        with open(os.path.join(d, "runs.csv")) as f:
            for row in csv.DictReader(f):
                if row.get("status") != "ok":
                    continue
                cell = out.setdefault(float(row[key]), {})
                for m, _ in METRICS:
                    v = row.get(m, "")
                    if v not in ("", "nan"):
                        cell.setdefault(m, []).append(float(v))
    return out


def side(spec):
    name, _, dirs = spec.partition("=")
    if not dirs:
        sys.exit("compare_backends.py: expected NAME=DIR[,DIR...], got " + spec)
    return name, dirs.split(",")


def fmt(xs):
    n, m, v = stats(xs)
    half = t975(n - 1) * math.sqrt(v / n) if n > 1 else float("nan")
    return "%.3f ± %.3f (%d)" % (m, half, n)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--key", default="feed.mass_flow_g_s")
    p.add_argument("--a", required=True, help="NAME=DIR[,DIR...], e.g. cpu=/tmp/feed_cpu")
    p.add_argument("--b", required=True)
    p.add_argument("--scale", type=float, default=1.0, help="printed beside the setting (full-width feed)")
    args = p.parse_args()
    (na, da), (nb, db) = side(args.a), side(args.b)
    a, b = read_runs(da, args.key), read_runs(db, args.key)
    common = sorted(set(a) & set(b))
    print("| %s | quantity | %s | %s | %s - %s (95%% interval) | verdict |" % (args.key, na, nb, nb, na))
    print("| --- | --- | --- | --- | --- | --- |")
    agree = total = 0
    for s in common:
        for m, label in METRICS:
            xa, xb = a[s].get(m, []), b[s].get(m, [])
            if not xa or not xb:
                continue
            d, half = welch(xa, xb)
            ok = not math.isnan(half) and abs(d) <= half
            agree += ok
            total += 1
            setting = "%g (%g)" % (s, s * args.scale) if args.scale != 1 else "%g" % s
            print("| %s | %s | %s | %s | %+.3f ± %.3f | %s |" % (setting, label, fmt(xa), fmt(xb), d, half,
                                                                 "agree" if ok else "DIFFER"))
    print("\n%d of %d comparisons agree (the 95%% interval of the difference holds 0); settings compared: %s" %
          (agree, total, ", ".join("%g" % s for s in common) or "none"))


if __name__ == "__main__":
    main()
