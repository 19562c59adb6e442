#!/usr/bin/env python3
"""Settling statistics of `dvisim run` outputs side by side (for example a pile at the solver's default stop
and at a fixed iteration count): per run, the dynamic bodies' height distribution (mean, 10/50/90 % quantiles,
maximum), their mean speed, and from summary.json the deepest penetration, mean contacts, mean iterations,
steps that missed the tolerance and ms per step. The first run is the reference: the last column gives each
other run's mean height minus the reference's, in sphere radii when --radius is given.

usage: compare_runs.py [--radius R] [--skip N] LABEL=DIR [LABEL=DIR ...]   (--skip: the first N bodies are the
       static machine, e.g. 5 for scenes/pile_100k.json's ground and walls)
"""
import csv
import json
import math
import sys


def stats(d, skip):
    dyn = list(csv.DictReader(open(d + "/bodies.csv")))[skip:]
    ys = sorted(float(r["y"]) for r in dyn)
    sp = [math.sqrt(sum(float(r[k]) ** 2 for k in ("vx", "vy", "vz"))) for r in dyn]
    q = lambda p: ys[min(len(ys) - 1, int(p * len(ys)))]
    s = json.load(open(d + "/summary.json"))
    return {"n": len(ys), "mean_y": sum(ys) / len(ys), "y10": q(0.1), "y50": q(0.5), "y90": q(0.9), "ymax": ys[-1],
            "mean_speed": sum(sp) / len(sp), "pen": s.get("max_penetration"), "contacts": s.get("contacts_mean"),
            "iters": s.get("iterations_mean"), "missed": s.get("steps_not_converged"), "ms": s.get("ms_per_step"),
            "backend": s.get("backend"), "device": s.get("device"), "steps": s.get("steps")}


def main(argv):
    radius, skip = None, 0
    while len(argv) > 2 and argv[1] in ("--radius", "--skip"):
        if argv[1] == "--radius":
            radius = float(argv[2])
        else:
            skip = int(argv[2])
        argv = argv[:1] + argv[3:]
    if len(argv) < 2:
        print("usage: compare_runs.py [--radius R] [--skip N] LABEL=DIR [LABEL=DIR ...]", file=sys.stderr)
        return 2
    runs = [(a.split("=", 1)[0], stats(a.split("=", 1)[1], skip)) for a in argv[1:]]
    ref = runs[0][1]["mean_y"]
    unit = " (radii)" if radius else " (m)"
    print("| run | backend | bodies | steps | mean y (m) | y10 / y50 / y90 / max (m) | mean speed (m/s) | max pen (m) "
          "| contacts | iterations | missed | ms/step | mean y - first" + unit + " |")
    print("|---" * 13 + "|")
    for label, s in runs:
        dy = s["mean_y"] - ref
        print(f"| {label} | {s['backend']} {s['device'] or ''} | {s['n']} | {s['steps']} | {s['mean_y']:.5f} | "
              f"{s['y10']:.4f} / {s['y50']:.4f} / {s['y90']:.4f} / {s['ymax']:.4f} | {s['mean_speed']:.2e} | "
              f"{s['pen']:.2e} | {s['contacts']:.0f} | {s['iters']:.1f} | {s['missed']} | {s['ms']:.2f} | "
              f"{dy / radius if radius else dy:+.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
