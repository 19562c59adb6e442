#!/usr/bin/env python3
"""Tables of a CES validation or feed-rate sweep (docs/CES.md, "Validation" and "Feed rate").

Reads DIR/sweep.json and DIR/runs/*/summary.json of a `dvisim sweep` and prints, per setting, the mean over the
seeds and the half-width of its 95% confidence interval (Student's t, n - 1 degrees of freedom) of the quantities
the published experiments report: product grades and recoveries at the configured (fixed) and at the optimised
splitters, the metal content of the middling product, the product masses, pinning, hold-up and what is still in
flight. Usage: table.py DIR [--feed-scale F] (F multiplies feed_g_s for the full-width equivalent).
"""
import json
import math
import os
import sys

T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}


def mean_ci(xs):
    xs = [x for x in xs if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not xs:
        return None, None
    m = sum(xs) / len(xs)
    if len(xs) < 2:
        return m, float("nan")
    s = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))
    return m, T975.get(len(xs) - 1, 1.96) * s / math.sqrt(len(xs))


def bin_share(bins, name, kind):
    b = bins[name]
    tot = b["metal_kg"] + b["plastic_kg"] + b["middling_kg"]
    return b[kind] / tot if tot > 0 else None


def plastic_pinned_by_size(run_dir, r_split=0.375e-3):
    """Mass share of the collected plastic (kind plastic) that the brush threw off (x' < 0: it rode the drum
    pinned), for volume-equivalent radii below and above r_split (the middle of the 0.5-1 mm feed)."""
    p = os.path.join(run_dir, "ces_particles.csv")
    if not os.path.exists(p):
        return None, None
    tot, neg = [0.0, 0.0], [0.0, 0.0]
    with open(p) as f:
        head = f.readline().strip().split(",")
        ix = {k: i for i, k in enumerate(head)}
        for line in f:
            v = line.strip().split(",")
            if v[ix["kind"]] != "plastic" or v[ix["status"]] != "collected":
                continue
            big = 1 if float(v[ix["radius_m"]]) >= r_split else 0
            m = float(v[ix["mass_kg"]])
            tot[big] += m
            if float(v[ix["x"]]) < 0:
                neg[big] += m
    return tuple(neg[i] / tot[i] if tot[i] > 0 else None for i in (0, 1))


def run_row(summary, run_dir):
    small, big = plastic_pinned_by_size(run_dir)
    c = summary["ces"]
    mt = c["metrics"]
    fed = c["fed_mass_kg"]
    fixed, best = c["at_splitters"], c["best"]

    def mass(cell, name):
        b = cell["bins"][name]
        return (b["metal_kg"] + b["plastic_kg"] + b["middling_kg"]) / fed

    return {
        "cond grade (fixed)": fixed["grade_metal"],
        "metal rec. (fixed)": fixed["recovery_metal"],
        "noncond grade (fixed)": fixed["grade_plastic"],
        "plastic rec. (fixed)": fixed["recovery_plastic"],
        "middling mass (fixed)": mass(fixed, "middling"),
        "middling metal (fixed)": bin_share(fixed["bins"], "middling", "metal_kg"),
        "cond grade (best)": best["grade_metal"],
        "metal rec. (best)": best["recovery_metal"],
        "middling mass (best)": mass(best, "middling"),
        "middling metal (best)": bin_share(best["bins"], "middling", "metal_kg"),
        "cond. product mass (fixed)": mass(fixed, "conductor"),
        "plastic pinned": next((v for k, v in mt.items() if k.startswith("pinned.") and k not in
                                ("pinned.copper", "pinned.composite")), None),
        "plastic thrown by the brush, d < 0.75 mm": small,
        "plastic thrown by the brush, d >= 0.75 mm": big,
        "held up": mt.get("holdup.mass_fraction"),
        "in flight": mt.get("in_flight.mass_fraction"),
        "coverage": mt.get("feed.coverage"),
        "sparkover margin": mt.get("sparkover.margin"),
    }


def main():
    if len(sys.argv) < 2:
        sys.exit("usage: table.py SWEEP_DIR [--feed-scale F]")
    d = sys.argv[1]
    scale = float(sys.argv[sys.argv.index("--feed-scale") + 1]) if "--feed-scale" in sys.argv else 1.0
    sweep = json.load(open(os.path.join(d, "sweep.json")))
    settings = {}
    for case in sweep["cases"]:
        p = os.path.join(d, "runs", case["id"], "summary.json")
        # Only finished runs (the sweep's marker): an interrupted run also writes a summary.
        if not os.path.exists(p) or not os.path.exists(os.path.join(d, "runs", case["id"], "sweep_done.json")):
            continue
        settings.setdefault(case["setting"], []).append(run_row(json.load(open(p)), os.path.dirname(p)))
    keys = sweep["keys"]
    cols = None
    for s in sorted(settings, key=int):
        rows = settings[s]
        cols = cols or list(rows[0].keys())
        if s == sorted(settings, key=int)[0]:
            print("| " + " | ".join(keys + ["n"] + cols) + " |")
            print("|" + " --- |" * (len(keys) + 1 + len(cols)))
        level = sweep["settings"][int(s)] if isinstance(sweep["settings"], list) else sweep["settings"][str(s)]
        vals = []
        for k in keys:
            v = level.get(k, "") if isinstance(level, dict) else ""
            if k == "feed.mass_flow_g_s" and scale != 1.0:
                v = "%g (%g)" % (float(v), float(v) * scale)
            vals.append(str(v))
        cells = []
        for c in cols:
            m, h = mean_ci([r[c] for r in rows])
            cells.append("–" if m is None else "%.3f ± %.3f" % (m, h))
        print("| " + " | ".join(vals + [str(len(rows))] + cells) + " |")


if __name__ == "__main__":
    main()
