#!/usr/bin/env python3
"""Sums an ncu --csv --metrics gpu__time_duration.sum log per kernel (device time, no launch gaps).

usage: ncu_summary.py LOG [STEPS]   STEPS divides the totals (per-step figures)."""
import csv
import re
import sys
from collections import defaultdict


def short(name):
    name = re.sub(r"\(anonymous namespace\)::", "", name)
    name = re.sub(r"dvi::(gpu::|kern::)?", "", name)
    m = re.match(r"void ([A-Za-z_0-9:<>, ]+?)\(", name)
    base = m.group(1) if m else name
    f = re.search(r"(mapKernel|reduceKernel)<[^>]*?([A-Za-z_0-9]+F|[A-Z][A-Za-z]+)\b", name)
    if f:
        base = f.group(1) + "<" + f.group(2) + ">"
    return base[:70]


def main():
    rows = [r for r in csv.reader(l for l in open(sys.argv[1]) if l.startswith('"'))]
    head, data = rows[0], rows[1:]
    ik, iv, iu = head.index("Kernel Name"), head.index("Metric Value"), head.index("Metric Unit")
    steps = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    tot, cnt = defaultdict(float), defaultdict(int)
    for r in data:
        v = float(r[iv].replace(",", ""))
        scale = {"ns": 1e-3, "usecond": 1.0, "us": 1.0, "msecond": 1e3, "ms": 1e3, "nsecond": 1e-3}.get(r[iu], 1.0)
        k = short(r[ik])
        tot[k] += v * scale
        cnt[k] += 1
    all_us = sum(tot.values())
    print(f"{len(data)} launches, {all_us / 1e3 / steps:.3f} ms of kernel time per step (/{steps:g})")
    for k, v in sorted(tot.items(), key=lambda x: -x[1])[:40]:
        print(f"{v / steps:10.1f} us {cnt[k] / steps:8.1f} x {v / cnt[k]:8.2f} us  {k}")


main()
